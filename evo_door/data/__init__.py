"""Measured and simulated trials: formats, importers, preprocessing and the virtual rig.

- :mod:`.trial`: the in-memory :class:`Trial` (SI, the project's sign conventions);
- :mod:`.io`: :func:`read_trials` / :func:`write_trials` for HDF5, CSV and NI TDMS,
  with column mapping and unit conversion (:mod:`.units`, :mod:`.columns`);
- :mod:`.preprocess`: zero-phase filtering, resampling, angle from rate, trimming,
  unlock / lock force peaks;
- :mod:`.rig`: the virtual test rig (human-like force profiles, sensors).
"""

from evo_door.data.io import read_trial, read_trials, write_trials
from evo_door.data.trial import Trial

__all__ = ["Trial", "read_trial", "read_trials", "write_trials"]
