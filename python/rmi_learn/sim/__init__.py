"""Simulation from Python: one scripted trial written to disk (:mod:`.trial`); replaying a
stored run to a chosen moment (:mod:`.replay`), executing force-setpoint chunks from there
(:mod:`.execute`) and fingerprinting the physical state (:mod:`.fingerprint`); the Gymnasium
environment (:mod:`.env`) with its water goal (:mod:`.goal`) and side-view frames
(:mod:`.render`); the VTK/ParaView frame writer (:mod:`.vtk`) and rerun recordings
(:mod:`.rerun_view`)."""
