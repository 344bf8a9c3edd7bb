"""``evo-door console``: the operator's web page for a running renderer."""

from __future__ import annotations

import argparse
import os

from evo_door.commands._common import PORT, TOKEN, check_ranges, declare_ranges
from evo_door.errors import UserError
from evo_door.render.console.process import TOKEN_ENV

ORDER = 62

#: the numeric flags' ranges (and the token's length), checked before any work
RANGES = {"--port": PORT, "--token": TOKEN}


def register(sub) -> None:
    p = sub.add_parser(
        "console",
        help="serve the operator's web console for a running renderer (render --control)",
        description="Serve a web page to tune a running renderer live: the door and its "
        "force-angle curve, loop health, a slider and two keys per sensation (a "
        "mechanism's: per parameter but its geometry), undo, "
        "reset, save, A/B comparison, JND sessions, the participant's choice. It talks to the "
        "renderer only through its control port. Runs until Ctrl-C.",
    )
    p.add_argument(
        "--control", required=True, metavar="HOST:PORT", help="the renderer's control port"
    )
    p.add_argument(
        "--model",
        metavar="MODEL",
        help="the rendered model, when it is not installed: the mechanism file (or "
        "path/file.py:MODEL) the renderer was started with (default: the model the "
        "renderer names; render --console passes its own)",
    )
    p.add_argument(
        "--token",
        help="the renderer's token; the page then requires it too (needed with a "
        f"non-loopback --host; default: ${TOKEN_ENV})",
    )
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to serve on (default 127.0.0.1; any other requires --token)",
    )
    p.add_argument(
        "--port", type=int, default=8765, help="port to serve on (default 8765; 0: any free)"
    )
    p.add_argument(
        "--save-dir",
        default=".",
        metavar="DIR",
        help="folder the page's Save writes parameter files to, and a JND session its "
        "JND file (default: here)",
    )
    p.add_argument("--open", action="store_true", help="open the page in the web browser")
    # render --console: end with the renderer even if it cannot say so (killed)
    p.add_argument("--with-parent", action="store_true", help=argparse.SUPPRESS)
    declare_ranges(p, RANGES)
    p.set_defaults(func=run)


def run(args) -> int:
    import asyncio
    import contextlib
    import signal
    from pathlib import Path

    from evo_door.render.control import parse_control

    check_ranges(args)

    try:
        from evo_door.render.console.server import ConsoleServer
    except ImportError as exc:  # aiohttp is an optional dependency
        raise UserError(
            f"the console needs aiohttp ({exc}): pip install 'evo-door[console]'"
        ) from None
    host, port = parse_control(args.control)
    if port == 0:
        raise UserError(f"--control {args.control}: give the renderer's port")
    if host in ("0.0.0.0", "::"):
        host = "127.0.0.1"
    save_dir = Path(args.save_dir)
    if not save_dir.is_dir():
        raise UserError(f"--save-dir {args.save_dir}: no such folder")
    token = args.token or os.environ.get(TOKEN_ENV) or None
    from evo_door.experiment.store import versions

    model = None
    if args.model:
        from evo_door.models import get_model

        model = get_model(args.model)
    server = ConsoleServer(
        (host, port), token, args.host, args.port, save_dir, versions=versions(), model=model
    )
    parent = os.getppid()

    async def serve() -> None:
        url = await server.start()
        try:
            print(f"console {url}", flush=True)
            if args.open:
                import webbrowser

                webbrowser.open(url)
            stop = asyncio.Event()
            loop = asyncio.get_running_loop()
            for sig in (signal.SIGTERM, signal.SIGHUP):
                loop.add_signal_handler(sig, stop.set)
            while not stop.is_set():
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), 1.0)
                if args.with_parent and os.getppid() != parent:
                    break  # the renderer that started us is gone
        finally:
            await server.stop()

    try:
        asyncio.run(serve())
    except KeyboardInterrupt:
        pass
    return 0
