"""Sweep grid presets (JSON): tiny, quick, paper. Read with rmi_learn.data.sweep.load_grid."""
