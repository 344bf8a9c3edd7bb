"""Haptic rendering: the haptic model on a force-feedback device.

``device`` (the small :class:`~evo_door.render.device.Device` interface, a simulated
admittance device and scripted virtual users), ``loop`` (the servo loop; one cycle's
compiled force in ``kernels``, its thread's pacing in ``priority``, its timing
statistics in ``timing``), ``safety`` (force limit, non-finite guard, passivity check,
watchdog), ``log`` (the 1 kHz log in memory, its rows' ``columns``; ``spill`` its side
file, ``log_file`` the final HDF5 file, readable as a trial file, ``session`` the web
console's session record), ``check`` (a log against the model's response to its
force). Modules are imported where used: nothing heavy here.
"""
