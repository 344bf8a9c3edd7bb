"""Who may use the console: the checks every request passes, and the headers of every
response (the server's module docstring says what they are and why).

The server binds 127.0.0.1 unless told otherwise, and any other address requires a
token: every request then carries it, in the query or in the cookie that
``GET /?token=T`` sets. A request from another origin (other than a GET or HEAD, and
the WebSocket) is refused, and on a loopback bind one whose ``Host`` is not a loopback
name of the server (DNS rebinding).
"""

from __future__ import annotations

import hmac

from aiohttp import web

from evo_door.render.control import is_loopback

#: the application's security settings (:func:`guard_for`)
GUARD = web.AppKey("guard", dict)


def host_port(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def guard_for(host: str, port: int, token: str | None) -> dict:
    """What the security checks accept for a server on ``host``:``port``."""
    hosts = {host_port(host, port)}
    loopback = is_loopback(host)
    if loopback:
        hosts |= {host_port(h, port) for h in ("127.0.0.1", "localhost", "::1")}
    wildcard = host in ("0.0.0.0", "::", "")
    return {
        "hosts": hosts,
        "origins": {f"http://{h}" for h in hosts},
        "loopback": loopback,
        "wildcard": wildcard,
        "token": token,
        "cookie": f"evo_door_console_{port}",
        "csp": "default-src 'self'; connect-src 'self' "
        + " ".join(sorted(f"ws://{h}" for h in hosts if not h.startswith("[")))  # no IPv6
        + "; frame-ancestors 'none'",
    }


def _forbidden(why: str) -> web.HTTPForbidden:
    return web.HTTPForbidden(text=f"403 forbidden: {why}\n")


@web.middleware
async def security(request: web.Request, handler):
    guard = request.app[GUARD]
    if guard["loopback"] and request.host not in guard["hosts"]:
        raise _forbidden("unexpected Host header")
    origin = request.headers.get("Origin")
    if origin is not None and (request.method not in ("GET", "HEAD") or request.path == "/ws"):
        allowed = origin in guard["origins"] or (
            guard["wildcard"] and origin == f"http://{request.host}"
        )
        if not allowed:
            raise _forbidden("cross-origin request")
    token = guard["token"]
    set_cookie = False
    if token is not None:
        given = request.query.get("token")
        by_query = isinstance(given, str) and hmac.compare_digest(given.encode(), token.encode())
        cookie = request.cookies.get(guard["cookie"], "")
        by_cookie = hmac.compare_digest(cookie.encode(), token.encode())
        if not (by_query or by_cookie):
            raise _forbidden("missing or wrong token (open the URL the console printed)")
        set_cookie = by_query and request.path == "/"
    response = await handler(request)
    if set_cookie:
        response.set_cookie(
            guard["cookie"], token, httponly=True, samesite="Strict", path="/", max_age=None
        )
    return response


async def headers(request: web.Request, response: web.StreamResponse) -> None:
    guard = request.app[GUARD]
    response.headers["Content-Security-Policy"] = guard["csp"]
    response.headers["X-Frame-Options"] = "DENY"
    response.headers["X-Content-Type-Options"] = "nosniff"
    response.headers["Referrer-Policy"] = "no-referrer"
    response.headers["Cache-Control"] = "no-store"
