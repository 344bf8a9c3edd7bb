"""Haptic rendering: the haptic model on a force-feedback device (issue 14).

``device`` (the small :class:`~evo_door.render.device.Device` interface, a simulated
admittance device and scripted virtual users), ``loop`` (the servo loop), ``safety``
(force limit, non-finite guard, passivity check, watchdog), ``log`` (the 1 kHz HDF5
log, readable as a trial file). Modules are imported where used: nothing heavy here.
"""
