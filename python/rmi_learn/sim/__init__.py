"""Simulation from Python: one scripted trial written to disk (:mod:`.trial`), the Gymnasium
environment (:mod:`.env`) with its water goal (:mod:`.goal`) and side-view frames
(:mod:`.render`), and the VTK/ParaView frame writer (:mod:`.vtk`)."""
