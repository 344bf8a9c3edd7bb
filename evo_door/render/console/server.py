"""The web console's server: the page, its API and WebSocket, one control-port client.

The console runs in its own process (``evo-door console``) and reaches the renderer
only through its control port (:mod:`evo_door.render.control`), over one persistent
TCP connection, one request (or one batch of pipelined requests) at a time. A
background task asks for the new log rows, the state and the loop's health about 30
times a second while a page is open and sends them to every page as a ``tick``;
another asks for the set in force 4 times a second and tells the pages when it
changed (``source`` ``"push"`` when no page caused it, ``evo-door push`` for one).

Every change a page asks for is checked here first (names a page may change, finite
numbers within their bounds), then sent as a control-port ``set``, which the renderer
checks again (bounds, passivity, the hands-off speed) and applies between two cycles,
or refuses: the page then gets ``refused`` with the reason and nothing changes. The
undo stack (the whole sets in force before each accepted change), the A/B slots and
the participant live here; each session step goes to the renderer's log as an ``event``.

Security: the server binds 127.0.0.1 unless told otherwise, and any other address
requires a token. With a token, every request needs it, in the query (``?token=T``)
or in the cookie that ``GET /?token=T`` sets (HttpOnly, SameSite=Strict). The
WebSocket and any request other than GET / HEAD are refused (403) when their
``Origin`` header is present and is not the server's own; on a loopback bind a
request whose ``Host`` is not a loopback name of the server is refused too (DNS
rebinding). Responses carry a Content-Security-Policy that allows only the page's
own origin and socket, and no CORS headers.

The HTTP and WebSocket API (every number in SI units)::

    GET /, /static/NAME          the page
    GET /api/declaration         the parameters a page may change (the haptic model's
                                 sensations, a mechanism's specification and numerics:
                                 sensations.py): unit, bounds, step, two keys each;
                                 and the model: name, title, the handle's unit, range
    GET /api/curve               quasi-static force-angle curve of the set in force,
                                 against the handle's coordinate (theta, unit)
    GET /ws                      WebSocket, JSON messages:
        server -> page: hello, tick (~30/s), params (source slider, key, undo, reset,
                        ab, jnd or push), refused, saved, ab, participant, chosen,
                        jnd (a JND session: settings, track, fit), jnd_phase, error;
                        hello and tick carry ``health`` (the control port's health
                        answer: status, rate_hz, cycles, missed_cycles,
                        on_time_fraction, lateness_p99_s, faults, saturated_cycles,
                        watchdog: "" or why it tripped) and ``state``
        page -> server: set {values, source}, undo, reset, save {name},
                        participant {id}, ab_store / ab_switch / ab_choice {slot},
                        ab_blind {blind}, choose, jnd_start {param, reference,
                        method, trials, seed, interval_s, pause_s, blind},
                        jnd_answer {answer: 1 or 2}, jnd_stop

Limits: a page's messages are read by the control port's rules
(:func:`~evo_door.render.messages.parse_message`: size, values, nesting, bounded
numbers) and rate-limited per page and per message type, and all pages' actions
together (:data:`~evo_door.render.console.session.ACTIONS_PER_S`); a refusal is an ``error`` (a ``refused`` for a
``set``) with ``"ok": false`` and the reason, and the socket goes on. At most
:data:`~evo_door.render.console.app.MAX_PAGES` pages at once: one more is told why and closed (1013, try again
later). A frame over :data:`~evo_door.render.console.app.MAX_FRAME` bytes is not read at all: the socket is closed
(1009, message too big).

The console's modules, each answering one question:

=============  ======================================================================
``server``     how is the console started and stopped? (:class:`ConsoleServer`)
``app``        what does it serve? the routes, the static files, each page's WebSocket
``security``   who may use it? the Host, Origin and token checks, the headers
``page``       what is a page sent, and how? the messages and one page's queue
``session``    what do the pages share? the state, the polling of the loop, changes
``actions``    what does each page message do?
``ab``         A/B comparison and blind mode
``jnd_mode``   JND sessions: 2IFC trials played on the renderer, answered on the page
``saving``     Save: the set in force as a parameter file
``sensations`` what may a page change? the declaration, a change checked, the curve
``client``     how does it reach the renderer? one control-port connection
``process``    how does ``render --console`` start and end it? (no aiohttp needed)
=============  ======================================================================
"""

from __future__ import annotations

from aiohttp import web

from evo_door.errors import UserError
from evo_door.render.console.app import make_app
from evo_door.render.console.client import ControlClient
from evo_door.render.console.security import host_port
from evo_door.render.console.session import CONNECT_WAIT, Console
from evo_door.render.control import is_loopback


class ConsoleServer:
    """The console on ``host``:``port`` for the renderer at ``control`` (host, port);
    ``model``: the rendered model, when the renderer's is not installed (a mechanism
    file: :class:`~evo_door.render.console.session.Console`).

    ``await start()`` reaches the renderer (trying for ``wait`` s), listens and
    returns the page's URL; ``await stop()`` ends it.
    """

    def __init__(
        self,
        control: tuple[str, int],
        token: str | None = None,
        host: str = "127.0.0.1",
        port: int = 8765,
        save_dir=".",
        wait: float | None = None,
        versions: dict | None = None,
        model=None,
    ):
        if not is_loopback(host) and not token:
            raise UserError(
                f"--host {host}: serving the console on a non-loopback address requires --token"
            )
        self.host, self.port, self.token = host, int(port), token or None
        self.wait = CONNECT_WAIT if wait is None else wait
        client = ControlClient(*control, token=self.token)
        self.console = Console(client, save_dir, versions, model)
        self.runner: web.AppRunner | None = None
        self.url = ""

    async def start(self) -> str:
        try:
            await self.console.connect(self.wait)
        except BaseException:
            await self.console.client.close()
            raise
        # the port is needed by the checks before the app exists: bind a socket first
        import socket

        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((self.host, self.port))
            sock.listen(128)
        except OSError as exc:
            sock.close()
            await self.console.client.close()
            raise UserError(
                f"--port {self.port}: cannot listen on {self.host}: {exc.strerror or exc}"
            ) from None
        sock.setblocking(False)
        self.port = sock.getsockname()[1]
        app = make_app(self.console, self.host, self.port, self.token)
        self.runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await self.runner.setup()
        await web.SockSite(self.runner, sock).start()
        self.console.start_polling()
        self.url = f"http://{host_port(self.host, self.port)}/"
        if self.token:
            from urllib.parse import quote

            self.url += f"?token={quote(self.token, safe='')}"
        return self.url

    async def stop(self) -> None:
        await self.console.stop()
        if self.runner is not None:
            await self.runner.cleanup()
