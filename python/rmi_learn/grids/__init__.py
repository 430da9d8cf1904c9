"""Sweep grid presets (JSON): tiny, quick, paper. Read with rmi_learn.sweep.load_grid."""
