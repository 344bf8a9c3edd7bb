"""What each page message does: the table :data:`ACTIONS` of the message types a page
sends, each an ``async`` function of the console, the page and the message.

A change goes to the renderer as a control-port ``set`` (:meth:`Console.apply`); the
A/B steps are in :mod:`~evo_door.render.console.ab`, the JND session's in
:mod:`~evo_door.render.console.jnd_mode`, Save in
:mod:`~evo_door.render.console.saving`. An action raises a UserError to refuse; the
console tells the page (:meth:`Console.handle`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from evo_door.errors import UserError
from evo_door.render.console import ab, jnd_mode
from evo_door.render.console.page import error, one_line, refused
from evo_door.render.console.saving import MAX_ID, on_save

if TYPE_CHECKING:
    from evo_door.render.console.page import Page
    from evo_door.render.console.session import Console

SOURCES = ("slider", "key")


async def on_set(console: Console, page: Page, message: dict) -> None:
    source = message.get("source", "slider")
    if source not in SOURCES:
        source = "slider"
    try:
        values = console.tunable.check_values(message.get("values"))
    except UserError as exc:
        page.post(refused(exc, message.get("values")))
        return
    await console.apply(values, source, page)


async def on_undo(console: Console, page: Page, message: dict) -> None:
    if not console.undo:
        page.post(error("nothing to undo"))
        return
    if await console.apply_set(console.undo[-1], "undo", page, undoable=False):
        console.undo.pop()
        await console.event("undo")


async def on_reset(console: Console, page: Page, message: dict) -> None:
    if await console.apply_set(console.start, "reset", page):
        await console.event("reset")


async def on_participant(console: Console, page: Page, message: dict) -> None:
    ident = message.get("id")
    if not isinstance(ident, str) or not ident.strip() or len(ident) > MAX_ID:
        raise UserError(f"a participant id is a text of 1 to {MAX_ID} characters")
    ident = one_line(ident)
    await console.event("participant", id=ident)
    console.participant = ident
    console.broadcast({"type": "participant", "id": ident})


async def on_choose(console: Console, page: Page, message: dict) -> None:
    now = await console.refresh()
    await console.event("chosen", params=now)
    console.broadcast({"type": "chosen", "params": now, "participant": console.participant})


#: the message types a page sends, and what each does (each rate-limited on its own)
ACTIONS = {
    "set": on_set,
    "undo": on_undo,
    "reset": on_reset,
    "save": on_save,
    "participant": on_participant,
    "ab_store": ab.on_ab_store,
    "ab_switch": ab.on_ab_switch,
    "ab_blind": ab.on_ab_blind,
    "ab_choice": ab.on_ab_choice,
    "choose": on_choose,
    "jnd_start": jnd_mode.on_jnd_start,
    "jnd_answer": jnd_mode.on_jnd_answer,
    "jnd_stop": jnd_mode.on_jnd_stop,
}
#: their names
PAGE_KINDS = tuple(ACTIONS)
