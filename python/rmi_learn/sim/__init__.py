"""Simulation from Python: one scripted trial written to disk (:mod:`.trial`), the Gymnasium
environment (:mod:`.env`) and the VTK/ParaView frame writer (:mod:`.vtk`)."""
