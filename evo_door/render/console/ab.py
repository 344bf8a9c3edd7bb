"""A/B comparison and blind mode: two slots hold sets; a page switches between them
(blind: the page does not show which is in force) and records the participant's
preference. Each step is a session event in the render log."""

from __future__ import annotations

from typing import TYPE_CHECKING

from evo_door.errors import UserError

if TYPE_CHECKING:
    from evo_door.render.console.page import Page
    from evo_door.render.console.session import Console

SLOTS = ("A", "B")


def slot_of(console: Console, message, stored: bool = False) -> str:
    """The slot a message names, "A" or "B" (``stored``: one holding a set)."""
    slot = message.get("slot")
    if slot not in SLOTS:
        raise UserError(f"slot {slot!r}: expected 'A' or 'B'")
    if stored and console.ab[slot] is None:
        raise UserError(f"slot {slot} is empty: store a set in it first")
    return slot


async def on_ab_store(console: Console, page: Page, message: dict) -> None:
    slot = slot_of(console, message)
    now = await console.refresh()
    await console.event("ab_store", slot=slot, params=now)
    console.ab[slot] = dict(now)
    console.broadcast({"type": "ab", **console.ab_state()})


async def on_ab_switch(console: Console, page: Page, message: dict) -> None:
    slot = slot_of(console, message, stored=True)
    if await console.apply_set(console.ab[slot], "ab", page):
        console.ab["active"] = slot
        await console.event("ab_switch", slot=slot, blind=bool(console.ab["blind"]))
        console.broadcast({"type": "ab", **console.ab_state()})


async def on_ab_blind(console: Console, page: Page, message: dict) -> None:
    blind = message.get("blind")
    if not isinstance(blind, bool):
        raise UserError('"blind" must be true or false')
    console.ab["blind"] = blind
    console.broadcast({"type": "ab", **console.ab_state()})


async def on_ab_choice(console: Console, page: Page, message: dict) -> None:
    slot = slot_of(console, message, stored=True)
    await console.event("ab_choice", slot=slot, params=console.ab[slot])
    console.ab["choice"] = slot
    console.broadcast({"type": "ab", **console.ab_state()})
