"""The console's web application: its routes, the page's static files, and the
WebSocket of each open page, read within its limits.

``GET /`` and ``/static/NAME`` serve the page, ``/api/declaration`` and ``/api/curve``
the rendered model's data (:mod:`~evo_door.render.console.sensations`), ``/ws`` the
WebSocket whose messages the console's session handles
(:meth:`~evo_door.render.console.session.Console.handle`).
"""

from __future__ import annotations

import asyncio
import re
from pathlib import Path

from aiohttp import WSCloseCode, WSMsgType, web

from evo_door.render.console.actions import PAGE_KINDS
from evo_door.render.console.page import Page, dumps, error
from evo_door.render.console.security import GUARD, guard_for, headers, security
from evo_door.render.console.session import Console
from evo_door.render.messages import MAX_LINE, BadMessage, ClientLimits, parse_message

#: the page's files (index.html, console.js, console.css)
STATIC = Path(__file__).parent / "static"
_STATIC_NAME = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9_.-]*$")
#: the largest message a page may send (bytes): the control port's line
MAX_PAGE_MESSAGE = MAX_LINE
#: the largest WebSocket frame read at all (bytes); up to it, a message over
#: MAX_PAGE_MESSAGE is answered and the socket goes on; past it aiohttp closes the socket
MAX_FRAME = 16 * 2**20
#: pages served at once
MAX_PAGES = 8
#: messages a second one page may send on average, and at once (a held key sends 10)
PAGE_PER_S = 30.0
PAGE_BURST = 60
#: messages of one type a second one page may send on average, and at once
PAGE_KIND_PER_S = 15.0
PAGE_KIND_BURST = 30


#: the console of the application
CONSOLE = web.AppKey("console", Console)


async def _index(request: web.Request) -> web.StreamResponse:
    page = STATIC / "index.html"
    if page.is_file():
        return web.FileResponse(page)
    return web.Response(text="evo-door console: the page (static/index.html) is not installed\n")


async def _static(request: web.Request) -> web.StreamResponse:
    name = request.match_info["name"]
    path = STATIC / name
    if not _STATIC_NAME.match(name) or not path.is_file():
        raise web.HTTPNotFound()
    return web.FileResponse(path)


async def _declaration(request: web.Request) -> web.Response:
    return web.json_response(request.app[CONSOLE].tunable.declaration())


async def _curve(request: web.Request) -> web.Response:
    body = await request.app[CONSOLE].curve()
    return web.Response(text=dumps(body), content_type="application/json")


async def _ws(request: web.Request) -> web.WebSocketResponse:
    console = request.app[CONSOLE]
    ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=MAX_FRAME)
    await ws.prepare(request)
    if console.open_pages >= MAX_PAGES:
        why = f"the console serves at most {MAX_PAGES} pages at once: close one, then reload"
        await ws.send_str(dumps(error(why)))
        await ws.close(code=WSCloseCode.TRY_AGAIN_LATER, message=b"too many pages")
        return ws
    console.open_pages += 1  # counted before any await: two pages never both pass
    page = Page(ws)
    try:
        await console.read_health()
        page.post(console.hello())
        console.pages.add(page)
        await _read_page(console, page)
    finally:
        console.open_pages -= 1
        console.pages.discard(page)
        page.task.cancel()
    return ws


async def _read_page(console: Console, page: Page) -> None:
    """Read a page's messages within the limits and do what they ask."""
    limits = ClientLimits(
        PAGE_KINDS,
        PAGE_PER_S,
        PAGE_BURST,
        PAGE_KIND_PER_S,
        PAGE_KIND_BURST,
        what="messages",
        kind_what="messages of type",
    )
    async for msg in page.ws:
        if msg.type == WSMsgType.BINARY:
            page.post(error("binary WebSocket messages are not read: send JSON text"))
            continue
        if msg.type != WSMsgType.TEXT:
            continue
        reason = limits.check_total()
        if reason is not None:
            page.post(error(reason))
            await asyncio.sleep(limits.backoff())  # and read this page no sooner
            continue
        try:
            message = parse_message(msg.data)
        except BadMessage as exc:
            page.post(error(exc))
            continue
        await console.handle(page, message, limits)


def make_app(console: Console, host: str, port: int, token: str | None) -> web.Application:
    """The aiohttp application of ``console`` served on ``host``:``port``."""
    app = web.Application(middlewares=[security], client_max_size=MAX_PAGE_MESSAGE)
    app[CONSOLE] = console
    app[GUARD] = guard_for(host, port, token)
    app.on_response_prepare.append(headers)
    app.router.add_get("/", _index)
    app.router.add_get("/static/{name}", _static)
    app.router.add_get("/api/declaration", _declaration)
    app.router.add_get("/api/curve", _curve)
    app.router.add_get("/ws", _ws)
    app.router.add_get("/favicon.ico", _no_icon)
    return app


async def _no_icon(request: web.Request) -> web.Response:
    return web.Response(status=204)  # no icon, and no 404 in the browser's console
