"""Data: the channel schema (:mod:`.schema`), run files (:mod:`.runs`), sweeps of the run
grid (:mod:`.sweep`, grid presets in ``grids/``), the learning dataset (:mod:`.dataset`) and
synthetic runs for tests (:mod:`.synthetic`). The layout is described in
``docs/data-contract.md``."""
