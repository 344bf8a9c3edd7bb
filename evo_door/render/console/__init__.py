"""The operator's web console: a page to tune a running renderer's feel.

A separate process (``evo-door console``, :mod:`evo_door.render.console.server`) serves
the page in ``static/`` and a WebSocket, and talks to the renderer only through its
control port (:mod:`evo_door.render.control`), so the servo loop carries none of it.
"""
