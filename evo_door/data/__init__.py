"""Measured and simulated trials: formats, importers, preprocessing and the virtual rig."""
