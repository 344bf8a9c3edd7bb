"""The console's bridge to the renderer: one persistent control-port connection.

The console reaches the renderer only through its control port
(:mod:`evo_door.render.control`): JSON lines, one answer per request, in order.
"""

from __future__ import annotations

import asyncio
import contextlib
import json

from evo_door.errors import UserError

#: answer timeout of one control-port request (s)
REQUEST_TIMEOUT = 5.0


class ControlClient:
    """One persistent connection to a renderer's control port (JSON lines).

    :meth:`ask` sends a batch of requests on one write and reads their answers, in
    order, one batch at a time; a dropped connection is opened again once per batch.
    Raises a UserError when the renderer cannot be reached or does not answer.
    """

    def __init__(self, host: str, port: int, token: str | None = None, timeout=REQUEST_TIMEOUT):
        self.host, self.port = host, port
        self.token = token or None
        self.timeout = timeout
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._lock = asyncio.Lock()

    @property
    def where(self) -> str:
        return f"{self.host}:{self.port}"

    async def close(self) -> None:
        writer, self._reader, self._writer = self._writer, None, None
        if writer is not None:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    async def ask(self, *messages: dict) -> list[dict]:
        base = {"token": self.token} if self.token else {}
        payload = "".join(json.dumps({**base, **m}) + "\n" for m in messages).encode()
        async with self._lock:
            for attempt in (1, 2):
                fresh = self._writer is None
                try:
                    if fresh:
                        self._reader, self._writer = await asyncio.wait_for(
                            asyncio.open_connection(self.host, self.port, limit=1 << 24),
                            self.timeout,
                        )
                    self._writer.write(payload)
                    await self._writer.drain()
                    answers = []
                    for _ in messages:
                        line = await asyncio.wait_for(self._reader.readline(), self.timeout)
                        if not line.endswith(b"\n"):
                            raise ConnectionResetError("the renderer closed the connection")
                        answer = json.loads(line)
                        if not isinstance(answer, dict) or "ok" not in answer:
                            raise ValueError
                        answers.append(answer)
                    return answers
                except TimeoutError:
                    await self.close()
                    raise UserError(
                        f"the renderer at {self.where} did not answer in {self.timeout:g} s"
                    ) from None
                except ValueError:
                    await self.close()
                    raise UserError(
                        f"{self.where} did not answer with the control protocol"
                    ) from None
                except (OSError, asyncio.IncompleteReadError) as exc:
                    await self.close()
                    if fresh or attempt == 2:  # a stale connection gets one more try
                        reason = getattr(exc, "strerror", None) or exc
                        raise UserError(
                            f"cannot reach the renderer at {self.where}: {reason}"
                        ) from None
        raise AssertionError("unreachable")


async def cancel_and_wait(task: asyncio.Task, every: float = 0.1) -> None:
    """Cancel ``task`` and wait until it has ended, cancelling it again while it runs.

    Python 3.11's ``asyncio.wait_for`` (which :meth:`ControlClient.ask` awaits) can
    swallow a cancellation that arrives as the awaited answer does (fixed in 3.12):
    the console's polling loops then went on, and a stop that awaited them once hung
    for ever (under load, one shutdown in three).
    """
    while not task.done():
        task.cancel()
        await asyncio.wait({task}, timeout=every)
    if not task.cancelled():
        with contextlib.suppress(BaseException):
            task.exception()  # retrieved: no "never retrieved" warning
