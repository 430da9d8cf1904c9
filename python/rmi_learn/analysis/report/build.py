"""Assembling and writing the report: :func:`build_report` runs the sections in order,
:func:`write_report` renders ``report.md`` and ``report.html``."""

from __future__ import annotations

import os
import time
from pathlib import Path

from rmi_learn.analysis.paper import paper_reference
from rmi_learn.analysis.report.control_protocol import section_control_protocol
from rmi_learn.analysis.report.document import Doc
from rmi_learn.analysis.report.execution import section_closed_loop, section_control
from rmi_learn.analysis.report.figure_files import FIG_SUBDIR
from rmi_learn.analysis.report.grid import section_grid
from rmi_learn.analysis.report.inputs import read_json
from rmi_learn.analysis.report.physics import section_physics
from rmi_learn.analysis.report.policies import section_policies
from rmi_learn.analysis.report.provenance import section_config
from rmi_learn.analysis.report.training import section_training
from rmi_learn.analysis.report.validation import section_validation
from rmi_learn.analysis.report.world_models import section_world_models
from rmi_learn.data.runs import atomic_write_bytes

REPORT_SUBDIR = "report"


def build_report(out_dir: str | os.PathLike[str], validation: Path | None = None) -> Doc:
    """Assemble the report of the pipeline directory ``out_dir`` (figures are written to
    ``out_dir/report/figures``)."""
    out = Path(out_dir)
    figs = out / REPORT_SUBDIR / FIG_SUBDIR
    paper = paper_reference()
    cfg = read_json(out / "pipeline.json") or {}
    doc = Doc()
    doc.h(1, f"rmi report: {cfg.get('name', out.name)}")
    doc.p(
        f"Generated {time.strftime('%Y-%m-%d %H:%M:%S')} from `{out}`. "
        + str(cfg.get("description", ""))
        + " Our numbers come first; rows starting with 'paper:' are the paper's printed "
        "numbers for the same cell. Small presets train on few runs for a few epochs, so "
        "their learning numbers show that the chain works, not the paper's accuracy."
    )
    section_grid(doc, out)
    section_physics(doc, out, figs, paper)
    section_world_models(doc, out, figs, paper)
    section_policies(doc, out, figs, paper)
    section_training(doc, out, figs)
    section_closed_loop(doc, out)
    section_control_protocol(doc, out)
    section_control(doc, out, figs)
    section_validation(doc, out, validation)
    section_config(doc, out)
    return doc


def write_report(
    out_dir: str | os.PathLike[str], validation: Path | None = None
) -> tuple[Path, Path]:
    """Write ``report/report.md`` and ``report/report.html`` under ``out_dir``; returns both
    paths."""
    out = Path(out_dir)
    if not out.is_dir():
        raise FileNotFoundError(f"{out} is not a pipeline output directory")
    doc = build_report(out, validation)
    rdir = out / REPORT_SUBDIR
    rdir.mkdir(parents=True, exist_ok=True)
    md, page = rdir / "report.md", rdir / "report.html"
    title = next((v for k, v in doc.blocks if k == "h1"), "rmi report")
    atomic_write_bytes(md, lambda f: f.write(doc.markdown().encode("utf-8")))
    page_text = doc.html(title, embed_from=rdir)
    atomic_write_bytes(page, lambda f: f.write(page_text.encode("utf-8")))
    # Stale figures of an older layout would confuse a reader browsing the folder.
    keep = {v[0].split("/")[-1] for k, v in doc.blocks if k == "img"}
    for old in (rdir / FIG_SUBDIR).glob("*.png") if (rdir / FIG_SUBDIR).exists() else []:
        if old.name not in keep:
            old.unlink()
    return md, page
