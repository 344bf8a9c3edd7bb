"""What a client may send, and how often: the bounds of one message and the rate limits.

The control port (:mod:`evo_door.render.control`) and the web console's WebSocket
(:mod:`evo_door.render.console`) read their clients' messages by the same rules, kept
here apart from either server: :func:`parse_message` reads one message within bounds
(size, count of values, nesting, bounded numbers), :func:`checked_values` checks a
parameter set a client sends against the declaration, :class:`RateLimit` is a token
bucket and :class:`ClientLimits` one client's rates (all its requests, and each kind).
Why each bound has its value is said beside it; the control port's module docstring
says what a client is told when it passes one.
"""

from __future__ import annotations

import json
import math
import threading
import time

from evo_door.errors import UserError, plain_text
from evo_door.models.haptic import PARAMS

#: the longest message: a request line, a page's WebSocket message (bytes)
MAX_LINE = 65536
#: values in one message at most (its commas and colons). json.loads builds them all in
#: one C call that holds the interpreter lock while the servo loop waits for it (16 KiB
#: of small numbers took 0.44 ms on a loaded 2-core machine, more than a 2500 Hz
#: period); the largest request (a whole parameter set) has about 80
MAX_ITEMS = 256
#: arrays and objects in one message at most, nested or not (a request has 2 or 3): it
#: bounds the nesting before json.loads recurses (30,000 deep raised RecursionError)
MAX_CONTAINERS = 32
#: digits of an integer at most (int() of a long digit string takes quadratic time, and
#: float() of a 400-digit one overflows)
MAX_DIGITS = 20
#: requests a second per connection on average, and at once; a console asks about 45
#: a second, plus two or three per operator action
REQUESTS_PER_S = 200.0
REQUESTS_BURST = 200
#: session events of one kind a second per connection on average, and at once
EVENTS_PER_S = 20.0
EVENTS_BURST = 40


class BadMessage(ValueError):
    """A message refused unread or half read; the reason on one line."""


def _bounded_int(text: str) -> int:
    digits = len(text) - text.startswith("-")
    if digits > MAX_DIGITS:
        raise BadMessage(f"an integer of {digits} digits: at most {MAX_DIGITS}")
    return int(text)


def _finite_float(text: str) -> float:
    x = float(text)
    if not math.isfinite(x):
        shown = text if len(text) <= 24 else text[:20] + "..."
        raise BadMessage(f"the number {shown} is beyond a 64-bit float")
    return x


def _no_constant(name: str):
    raise BadMessage(f"{name} is not a number: give a finite one")


_DECODER = json.JSONDecoder(
    parse_int=_bounded_int, parse_float=_finite_float, parse_constant=_no_constant
)


def parse_message(data: bytes | str) -> dict:
    """One client message (a control-port line, a console page's WebSocket text) as a
    JSON object, read within bounds; a :class:`BadMessage` with the reason otherwise.

    The size, the count of values and of arrays and objects are checked on the raw text
    (``bytes.count``, microseconds) before anything is built, so a message costs the
    process at most tens of microseconds of the interpreter lock; the numbers are read
    with bounds as they are parsed (:data:`MAX_DIGITS`, finite floats, no NaN or
    Infinity). Commas, colons and brackets inside strings count too: a text with more
    than a few hundred of them is refused, which no request of the protocol needs.
    """
    if isinstance(data, str):  # a WebSocket's text: at least one byte per character
        if len(data) > MAX_LINE:
            raise BadMessage(f"a message takes at most {MAX_LINE} bytes, this one more")
        data = data.encode("utf-8", "surrogatepass")
    if len(data) > MAX_LINE:
        raise BadMessage(f"a message takes at most {MAX_LINE} bytes, this one {len(data)}")
    items = data.count(b",") + data.count(b":")
    if items > MAX_ITEMS:
        raise BadMessage(f"a message holds at most {MAX_ITEMS} values, this one {items}")
    containers = data.count(b"{") + data.count(b"[")
    if containers > MAX_CONTAINERS:
        raise BadMessage(
            f"a message holds at most {MAX_CONTAINERS} arrays and objects, nested or not; "
            f"this one {containers}"
        )
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise BadMessage("not UTF-8 text: send one JSON object per line") from None
    try:
        message = _DECODER.decode(text)
    except json.JSONDecodeError as exc:
        raise BadMessage(
            f"not a JSON object on one line ({exc.msg}, character {exc.pos})"
        ) from None
    except RecursionError:  # unreachable within MAX_CONTAINERS; kept as a last guard
        raise BadMessage("nested too deep") from None
    if not isinstance(message, dict):
        raise BadMessage("not a JSON object on one line")
    _check_texts(message)
    return message


def _check_texts(value) -> None:
    """Every text of a parsed message (keys and values, at any depth) is Unicode that a
    file can hold: no lone surrogate (JSON's ``\\ud800`` escapes one) and no NUL. Such
    text is refused here, at entry, so that it never reaches a log's writer (which
    could not encode it, and would lose the whole session's log)."""
    if isinstance(value, str):
        plain_text(value, "a text in the message", BadMessage)
    elif isinstance(value, dict):
        for k, v in value.items():
            _check_texts(k)
            _check_texts(v)
    elif isinstance(value, list):
        for v in value:
            _check_texts(v)


class RateLimit:
    """At most ``rate`` a second on average and ``burst`` at once (a token bucket).

    Not thread-safe: one per client, or a lock around a shared one (:meth:`turn`).
    """

    def __init__(self, rate: float, burst: float, clock=time.monotonic):
        self.rate, self.burst, self._clock = float(rate), float(burst), clock
        self._tokens = self.burst
        self._at = clock()
        self._lock = threading.Lock()

    def turn(self, amount: float = 1.0) -> float:
        """:meth:`spend` from any thread: how long (s) to wait for its turn."""
        with self._lock:
            return self.spend(amount)

    def _refill(self) -> None:
        now = self._clock()
        self._tokens = min(self.burst, self._tokens + (now - self._at) * self.rate)
        self._at = now

    def take(self, amount: float = 1.0) -> bool:
        """Take ``amount`` if there is as much; whether it was there."""
        self._refill()
        if self._tokens < amount:
            return False
        self._tokens -= amount
        return True

    def spend(self, amount: float) -> float:
        """Take ``amount`` even into debt; how long (s) until the debt is paid off."""
        self._refill()
        self._tokens -= amount
        return max(0.0, -self._tokens / self.rate)

    def wait(self) -> float:
        """How long (s) until one more is allowed."""
        self._refill()
        return max(0.0, (1.0 - self._tokens) / self.rate)


class ClientLimits:
    """The rate limits of one client (a connection, a console page): all its requests,
    and its requests of each kind (session events, page actions).

    ``kinds`` lists the kinds limited on their own; any other counts only in the total
    (a client cannot grow the table with made-up kinds). ``what`` and ``kind_what`` name
    them in the reasons: "requests", "events of kind".
    """

    def __init__(
        self,
        kinds=(),
        rate: float = REQUESTS_PER_S,
        burst: float = REQUESTS_BURST,
        kind_rate: float = EVENTS_PER_S,
        kind_burst: float = EVENTS_BURST,
        what: str = "requests",
        kind_what: str = "events of kind",
    ):
        self.what, self.kind_what = what, kind_what
        self.total = RateLimit(rate, burst)
        self.kinds = {k: RateLimit(kind_rate, kind_burst) for k in kinds}

    def check_total(self) -> str | None:
        """Count one request; the reason to refuse it, or None."""
        if self.total.take():
            return None
        return (
            f"more than {self.total.rate:g} {self.what} a second on this connection "
            f"(bursts of {self.total.burst:g}): slow down"
        )

    def check(self, kind: str) -> str | None:
        """Count one request of ``kind``; the reason to refuse it, or None."""
        limit = self.kinds.get(kind)
        if limit is None or limit.take():
            return None
        return (
            f"more than {limit.rate:g} {self.kind_what} {kind!r} a second "
            f"(bursts of {limit.burst:g}): slow down"
        )

    def backoff(self) -> float:
        """How long (s, at most 0.1) a client refused for its rate is not read: until
        it may send one more, so that refusals cost no more than answers."""
        return min(0.1, self.total.wait())


def checked_values(
    values, key="params", names=None, what="parameter of the declaration", table=PARAMS
):
    """``values`` {name: SI value} checked (a UserError with the reason otherwise):
    a non-empty object under ``key``, names among ``names`` (default: the whole
    declaration ``table``, the haptic model's unless given; else a ``what``), finite
    numbers within their declared bounds."""
    if not isinstance(values, dict) or not values:
        raise UserError(f'"{key}" must be a non-empty object {{name: value}}')
    allowed = table.names if names is None else names
    out = {}
    for name, value in values.items():
        if name not in allowed:
            raise UserError(f"{name!r} is not a {what}")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise UserError(f"parameter {name!r}: {value!r} is not a number")
        q = table[name]
        if not (math.isfinite(value) and q.lower <= value <= q.upper):
            raise UserError(
                f"{name} = {value!r} {q.unit}: outside its declared range "
                f"[{q.lower:g}, {q.upper:g}] {q.unit}"
            )
        out[name] = float(value)
    return out
