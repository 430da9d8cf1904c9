"""The report of a pipeline directory: every table of the paper with our numbers beside the
paper's, every figure, the run-grid summary, the physical validation, versions and config.

The report is assembled as a list of blocks (headings, paragraphs, tables, figures) and
rendered twice, to ``report.md`` (figures as files beside it) and to a self-contained
``report.html`` (the same figures embedded as data URIs: the one file can be mailed or
archived on its own), so the two never disagree. Inputs are the files the stages wrote (see
:mod:`rmi_learn.pipeline`); a stage that has not run yet leaves a note in its section instead
of breaking the report. The paper's numbers come from ``paper_reference.json``
(:mod:`rmi_learn.analysis.paper`).

Layout: :mod:`.document` (the block model and its two renderings), :mod:`.build` (the
driver), one module per group of sections (:mod:`.grid`, :mod:`.physics`,
:mod:`.world_models`, :mod:`.policies`, :mod:`.training`, :mod:`.execution`,
:mod:`.validation`, :mod:`.provenance`) and their shared parts (:mod:`.inputs`,
:mod:`.cells`, :mod:`.figure_files`).
"""

from rmi_learn.analysis.report.build import build_report, write_report
from rmi_learn.analysis.report.document import Doc
from rmi_learn.analysis.report.training import training_figure, training_runs

__all__ = ["Doc", "build_report", "training_figure", "training_runs", "write_report"]
