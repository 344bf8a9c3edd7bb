"""Models exported from other tools as Functional Mock-up Units (FMI 2.0 and 3.0).

``path/to/model.fmu`` is a model wherever a model is accepted: :func:`load_fmu` reads
its description (:mod:`.description`), declares its real parameters, finds the force,
angle and speed among its variables and runs it with compiled kernels that call its C
functions (:mod:`.kernels`, :mod:`.calls`) on one instance per process
(:mod:`.instance`). FMPy (an optional extra, ``pip install -e '.[fmi]'``) reads and
loads the FMU. Loading an FMU runs its code: load only FMUs you trust.
"""

from evo_door.models.fmu.description import is_fmu_spec, join_spec, split_spec


def load_fmu(spec: str, mapping=None):
    """:func:`evo_door.models.fmu.model.load_fmu`, importing FMPy and numba only now."""
    try:
        import fmpy  # noqa: F401
    except ImportError:
        from evo_door.errors import UserError

        raise UserError(
            "reading an FMU needs FMPy: pip install -e '.[fmi]' (or pip install fmpy)"
        ) from None
    from evo_door.models.fmu.model import load_fmu as load

    return load(spec, mapping)


__all__ = ["is_fmu_spec", "join_spec", "load_fmu", "split_spec"]
