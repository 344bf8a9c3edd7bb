"""The ``evo-door`` command line: a thin argparse layer over the library.

Each sub-command lives in its own module of :mod:`evo_door.commands`, which defines
``register(subparsers)``; the parser it adds sets ``func(args) -> int | None``.
Modules are discovered, so adding a command never means editing this file.

User errors (:class:`~evo_door.errors.UserError`) and what the file system refuses
(``OSError``: a missing file, a read-only folder, a full disk) print one line
``evo-door: error: ...`` and exit with status 2, whichever command met them; anything
else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys

import evo_door
import evo_door.plugins  # noqa: F401 (fills the lower layers' registries: render logs as parameter files)
from evo_door import __version__
from evo_door.errors import UserError, error_line


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="evo-door",
        description="Re-engineer how a product feels: model the mechanism, estimate its "
        "parameters with a genetic algorithm, fit and render a haptic model, "
        "and translate the chosen feel back into specifications.",
    )
    parser.add_argument("--version", action="version", version=f"evo-door {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    import evo_door.commands as commands

    modules = [
        importlib.import_module(f"{commands.__name__}.{info.name}")
        for info in pkgutil.iter_modules(commands.__path__)
        if not info.name.startswith("_")
    ]
    for module in sorted(modules, key=lambda m: (getattr(m, "ORDER", 50), m.__name__)):
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    compile_notes(True)
    try:
        for spec in getattr(args, "allow_model", None) or []:  # --allow-model (reading)
            from evo_door.errors import plain_text
            from evo_door.models import allow_model

            allow_model(plain_text(spec, "--allow-model"))
        return int(args.func(args) or 0)
    except UserError as exc:
        print(error_line(exc), file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stderr.close()
        return 0
    except OSError as exc:
        # the file system said no (missing, read-only, full, a folder for a file...):
        # the user's to fix, whichever command met it
        from evo_door.files.atomic import write_reason

        name = getattr(exc, "filename", None) or _numba_cache(exc)
        reason = write_reason(exc)
        print(error_line(f"{name}: {reason}" if name else reason), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("evo-door: interrupted", file=sys.stderr)
        return 130
    finally:
        compile_notes(False)


def compile_notes(on: bool) -> None:
    """Say on stderr what numba compiles while a command runs (a first run after an
    install or an edit), instead of a silent wait; ``EVO_DOOR_COMPILE_NOTES=0`` keeps
    quiet. Nothing is imported for it: :mod:`evo_door.kernel_cache` reads
    ``evo_door.compile_notes`` when numba first imports it."""
    on = on and os.environ.get("EVO_DOOR_COMPILE_NOTES", "1") != "0"
    evo_door.compile_notes = on
    cache = sys.modules.get("evo_door.kernel_cache")
    if cache is not None:
        cache.announce() if on else cache.finish_announce()


def _numba_cache(exc: BaseException) -> str | None:
    """The folder of numba's compiled-code cache if saving to it raised ``exc`` (its
    errors name no file; a full disk there stops the first compile of a function)."""
    tb = exc.__traceback__
    while tb is not None:
        frame = tb.tb_frame
        if frame.f_globals.get("__name__") == "numba.core.caching":
            folder = getattr(frame.f_locals.get("self"), "_cache_path", None)
            if folder:
                return f"{folder} (numba's cache of compiled code; NUMBA_CACHE_DIR moves it)"
        tb = tb.tb_next
    return None


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
