"""One open page: the messages a page is sent and the queue that sends them.

The server's answers are JSON text (:func:`dumps`, non-finite numbers as null); a
refusal is an ``error`` or, for a change, a ``refused`` message, its reason on one
line. A :class:`Page` queues what goes to its socket, so that a slow page never holds
up the others: it misses ticks (past :data:`TICK_BACKLOG` waiting), never a change.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math

from aiohttp import web

#: messages waiting for a slow page before ticks are dropped for it
TICK_BACKLOG = 8


def one_line(text) -> str:
    """``text`` on one line (its runs of white space one space)."""
    return " ".join(str(text).split())


def _clean(value):
    """``value`` for JSON: non-finite floats become None (JavaScript cannot parse NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def dumps(message: dict) -> str:
    """A message to a page as compact JSON text."""
    return json.dumps(_clean(message), separators=(",", ":"))


def error(text) -> dict:
    """An ``error`` message to a page: the reason on one line."""
    return {"type": "error", "ok": False, "error": one_line(text)}


def refused(text, values) -> dict:
    """A ``refused`` message to a page: the change it asked for did not happen."""
    return {
        "type": "refused",
        "ok": False,
        "error": one_line(text),
        "values": values if isinstance(values, dict) else {},
    }


class Page:
    """A connected WebSocket and the queue of messages going to it."""

    def __init__(self, ws: web.WebSocketResponse):
        self.ws = ws
        self.queue: asyncio.Queue[str] = asyncio.Queue(maxsize=256)
        self.task = asyncio.get_running_loop().create_task(self._pump())

    def post(self, message: dict | str, droppable: bool = False) -> None:
        text = message if isinstance(message, str) else dumps(message)
        if droppable and self.queue.qsize() >= TICK_BACKLOG:
            return  # a slow page misses ticks, never a change
        try:
            self.queue.put_nowait(text)
        except asyncio.QueueFull:  # hopelessly behind: let it reconnect
            self.task.cancel()
            asyncio.get_running_loop().create_task(self.ws.close())

    async def _pump(self) -> None:
        with contextlib.suppress(ConnectionError, RuntimeError):
            while True:
                await self.ws.send_str(await self.queue.get())
