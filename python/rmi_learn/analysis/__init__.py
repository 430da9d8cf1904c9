"""Analysis: the physical analysis of a run grid (:mod:`.physical`, ``rmi analyze``, built on
:mod:`.run_table`, :mod:`.statistics` and :mod:`.figures`), the paper's printed numbers
(:mod:`.paper`) and the report of a pipeline directory beside them (:mod:`.report`,
``rmi report``)."""
