"""Is what was fitted what the participant felt? A render log against the model.

:func:`render_agreement` reads a render log (a trial file: the measured user force on
the door's tangent, theta and dtheta on the log's uniform grid), simulates the haptic
model under that force from the logged state (:func:`evo_door.sim.simulate` with the
model's own settings: Dormand-Prince, and dry friction as the sign law that sticks,
the renderer's implicit Coulomb law in the limit of a short period) and compares
theta and dtheta with the log. :func:`format_agreement` says it with units (``evo-door
render-check LOG.h5``).

What is simulated:

* by default, the sets the log rendered, each from the time it came into force, plus
  what the rendering itself put on the handle beyond the model, which is linear in the
  speed and so a model parameter: the device's own viscous damping b (N s/m), felt as
  ``b R`` more ``viscous_damping`` (N s/rad), its own dry friction (N) on both
  friction levels, and ``c_energy``'s push along the motion, ``-c_energy R``. The log
  records the device's terms (its ``device`` event); ``device_damping`` and
  ``device_friction`` replace them;
* ``params`` (a set fitted to the log, say) as it is for the whole log: a fit of a
  log already holds what the device added, unless ``device_damping`` or
  ``device_friction`` are given.

A log that did not keep every set (changes past its cap,
:data:`~evo_door.render.log.MAX_PARAM_SETS`: its ``changes_dropped`` event) does not
know the set in force from the first set it left out to the last: with the log's sets
that span is not simulated.

Each simulation starts from the logged angle and speed: at the start, at each change
of the parameter set, at every ``window`` seconds if one is given (an open-loop
simulation of a long session drifts), after samples that are not finite (a fault),
and after each gap of a paced loop (its ``gap`` events: slots missed in a row for 20
ms or more, :data:`~evo_door.render.loop.STALL_FLOOR`, which a loose watchdog let it
survive): over a gap the device held its last command and the loop saw nothing, so
the model's force there is not known and its samples, the log's interpolation
across the gap, are not compared.

The force is the log's, at the log's step: its rows are on an exact grid of the
loop's time already (:class:`~evo_door.render.log.RenderLog` interpolates the
loop's cycles, which come at the loop rate, late by the lateness its statistics give,
linearly onto the log's ticks, across a missed slot too), and the integrator takes
it as linear between two rows.

What the model leaves out, so that the two never agree to the last digit
(docs/renderer.md, "Does the log agree with the model?"): the loop's period, over
which the renderer solves the latch's snap in one implicit step and holds its
command (a round trip late over a network); the circle's spring (``k_radial``), on
which the handle runs outside the circle at speed; the device's own physics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evo_door.errors import UserError
from evo_door.models.haptic import MODEL, PARAMS
from evo_door.params import ParamSet, param_vector


@dataclass
class Agreement:
    """A render log and the model's response to its force, sample by sample.

    ``t`` (s), ``force`` (N, + toward closing), logged ``theta`` (rad) and ``dtheta``
    (rad/s), simulated ``theta_sim`` and ``dtheta_sim`` (NaN where nothing was
    simulated); ``starts``: the times (s) each simulation started from the logged
    state; ``model``: what was simulated, for people; ``statistics``: the loop's;
    ``device``: the device's terms that were added (damping N s/m, friction N).
    """

    t: np.ndarray
    force: np.ndarray
    theta: np.ndarray
    dtheta: np.ndarray
    theta_sim: np.ndarray
    dtheta_sim: np.ndarray
    starts: list[float]
    model: str
    statistics: dict = field(default_factory=dict)
    device: dict = field(default_factory=dict)

    def errors(self) -> dict:
        """The agreement in numbers (SI): RMS and largest difference (simulated minus
        logged) of theta (rad) and dtheta (rad/s) and when the largest was (s); the
        motion's scale, its span of angle (rad) and its top speed (rad/s); samples
        compared."""
        ok = np.isfinite(self.theta_sim) & np.isfinite(self.dtheta_sim)
        if not ok.any():
            raise UserError("render log: no sample could be simulated")
        out: dict[str, float] = {"samples": int(ok.sum())}
        for name, log, sim in (
            ("theta", self.theta, self.theta_sim),
            ("dtheta", self.dtheta, self.dtheta_sim),
        ):
            diff = np.where(ok, sim - log, 0.0)
            k = int(np.argmax(np.abs(diff)))
            out[f"{name}_rms"] = float(np.sqrt(np.sum(diff**2) / ok.sum()))
            out[f"{name}_max"] = float(abs(diff[k]))
            out[f"{name}_max_t"] = float(self.t[k])
        out["theta_span"] = float(np.ptp(self.theta[ok]))
        out["speed_max"] = float(np.max(np.abs(self.dtheta[ok])))
        return out


def felt_vector(params, device_damping=0.0, device_friction=0.0, c_energy=True) -> np.ndarray:
    """The haptic model's vector of what a hand felt when ``params`` was rendered.

    ``device_damping`` (N s/m) adds ``b R`` to ``viscous_damping`` (N s/rad),
    ``device_friction`` (N) to both friction levels, and with ``c_energy`` its push
    along the motion, ``c_energy R`` (N s/rad), comes off ``viscous_damping``. A
    vector, not a checked set: the sum may leave a declared range (a negative
    damping), which the integrators take as it is.
    """
    p = param_vector(params, PARAMS).copy()
    radius = p[PARAMS.index("radius")]
    extra = float(device_damping) - (p[PARAMS.index("c_energy")] if c_energy else 0.0)
    p[PARAMS.index("viscous_damping")] += extra * radius
    for name in ("friction_closing", "friction_opening"):
        p[PARAMS.index(name)] += float(device_friction)
    return p


def render_agreement(
    path, params=None, *, device_damping=None, device_friction=None, window=None
) -> Agreement:
    """The render log ``path`` against the haptic model (module docstring).

    ``params``: None (the sets the log rendered, with the device's terms), or a
    :class:`~evo_door.params.ParamSet` of the haptic model (or anything
    ``param_vector`` takes) simulated as it is; ``device_damping`` (N s/m) and
    ``device_friction`` (N): the device's own terms, instead of the log's (or of
    none, with ``params``); ``window`` (s): also restart from the logged state every
    ``window`` seconds. A file that is not a render log, or a bad number, is a
    UserError.
    """
    from evo_door.sim import simulate

    if window is not None and not (math.isfinite(window) and window > 0):
        raise UserError(f"--window {window!r}: give a time in seconds > 0")
    log = _read(path)
    t, force, theta, dtheta = log["trial"]
    device = {
        "damping": _device_term(device_damping, log, "damping", params, "N s/m"),
        "friction": _device_term(device_friction, log, "friction", params, "N"),
    }
    sets = [(0.0, params)] if params is not None else log["sets"]
    if not sets:
        raise UserError(f"{path}: the log holds no parameter set")
    vectors = [
        felt_vector(p, device["damping"], device["friction"], c_energy=params is None)
        for _, p in sets
    ]
    dt = float(t[1] - t[0])
    theta_sim = np.full_like(theta, np.nan)
    dtheta_sim = np.full_like(theta, np.nan)
    starts = []
    unknown = log["unknown"] if params is None else None
    runs = _runs(t, [s for s, _ in sets], force, theta, dtheta, window, unknown, log["gaps"])
    for i0, i1, k in runs:
        r = simulate(MODEL, vectors[k], force[i0:i1], dt, theta0=theta[i0], dtheta0=dtheta[i0])
        theta_sim[i0:i1] = r.theta
        dtheta_sim[i0:i1] = r.dtheta
        starts.append(float(t[i0]))
    return Agreement(
        t, force, theta, dtheta, theta_sim, dtheta_sim, starts,
        _model_note(sets, params, device, log),
        log["statistics"], device,
    )  # fmt: skip


def _read(path) -> dict:
    """The parts of a render log the check reads: its time and channels (read as they
    are: a fault's row is NaN, which a trial reader refuses), the sets in force with
    their times, the events, the statistics, the device's name."""
    from evo_door.files import fields, open_h5
    from evo_door.render.session import read_log

    with open_h5(path, "render log") as f:  # a missing or binary file says so
        if "render/params" not in f or "trials/render/theta" not in f:
            raise UserError(f"{path}: not a render log (no /render group with its sets)")
        log = read_log(f, path)
        trial: list[np.ndarray] = []
        for c in ("t", "force", "theta", "dtheta"):
            name = f"trials/render/{c}"
            if name not in f or not hasattr(f[name], "dtype"):
                raise UserError(f"{path}: /{name}: missing, or not a dataset")
            shape = (None,) if not trial else trial[0].shape
            trial.append(fields.as_array(f[name][()], f"{path}: /{name}", shape))
    _check_grid(path, trial[0])
    sets = [(ti, ParamSet.from_mapping(PARAMS, values)) for ti, values in log["sets"]]
    return {
        "trial": tuple(trial),
        "sets": sets,
        "events": log["events"],
        "statistics": log["statistics"],
        "device": log["device"],
        "unknown": _unknown_span(log["events"]),
        "gaps": [(float(e.get("from_t", e["t"])), float(e["t"])) for e in log["events"]
                 if e.get("kind") == "gap"],
    }  # fmt: skip


def _unknown_span(events) -> tuple[float, float] | None:
    """When (s, from and to) the log does not know the set in force: from the first
    set it did not keep to the last (its ``changes_dropped`` event), or None."""
    for e in events:
        if e.get("kind") == "changes_dropped":
            return float(e["t"]), float(e.get("last_t", e["t"]))
    return None


def _check_grid(path, t: np.ndarray) -> None:
    """A UserError unless ``t`` (s) is the uniform grid a render log is written on (its
    rows interpolated onto the log's ticks), to 1e-6 of a step."""
    if t.size < 2:
        raise UserError(f"{path}: fewer than two samples in the log")
    step = (t[-1] - t[0]) / (t.size - 1)
    off = np.abs(t - (t[0] + step * np.arange(t.size)))
    if not (step > 0 and np.all(np.isfinite(t)) and off.max() <= 1e-6 * step):
        k = int(np.nanargmax(off)) if np.isfinite(off).any() else 0
        raise UserError(
            f"{path}: its time is not the uniform grid of a render log (row {k}, {float(t[k])!r} s)"
        )


def _device_term(given, log: dict, name: str, params, unit: str) -> float:
    """A device term (``damping``, ``friction``): as given (checked), else the log's
    (its ``device`` event) for the sets it rendered, else 0."""
    if given is not None:
        value = float(given)
        if not (math.isfinite(value) and value >= 0):
            raise UserError(f"--device-{name} {given!r}: give a number >= 0 {unit}")
        return value
    if params is not None:
        return 0.0
    recorded = [e for e in log["events"] if e.get("kind") == "device"]
    logged = recorded[-1].get(name) if recorded else None
    return float(logged) if logged is not None else 0.0


def _runs(t, set_times, force, theta, dtheta, window, unknown=None, gaps=()):
    """``(i0, i1, k)`` of each simulation: samples ``i0:i1``, the set ``k`` in force.

    A run starts at the first sample, at each set's time, every ``window`` seconds
    (if given), after each sample that is not finite and at the end of each of the
    loop's ``gaps`` (s, from the last cycle before to the first after); it holds at
    least two samples and only finite ones. No run covers ``unknown`` (s, from and
    to: the set in force is not known) or a gap's inside (the ticks the log
    interpolated across it).
    """
    finite = np.isfinite(force) & np.isfinite(theta) & np.isfinite(dtheta)
    tol = 1e-6 * float(t[1] - t[0])
    spans = []  # (first, end) of the samples not simulated
    if unknown is not None:  # from the tick at its start to the tick at its end
        spans.append(np.searchsorted(t, np.asarray(unknown) - tol))
    for first, last in gaps:  # the ticks after the last cycle before, to the first after
        spans.append((np.searchsorted(t, first + tol), np.searchsorted(t, last - tol)))
    skipped = np.zeros(t.size, dtype=bool)
    cuts = {0}
    for a, b in spans:
        skipped[a:b] = True
        cuts.update((int(a), int(b)))
    cuts.update(int(np.searchsorted(t, s - 1e-9)) for s in set_times)
    if window is not None:
        cuts.update(int(np.searchsorted(t, t[0] + j * window - 1e-9))
                    for j in range(1, int((t[-1] - t[0]) / window) + 1))  # fmt: skip
    bad = np.flatnonzero(~finite)
    cuts.update(bad.tolist())
    cuts.update((bad + 1).tolist())
    edges = sorted(c for c in cuts if 0 <= c < t.size) + [t.size]
    set_index = np.searchsorted(np.asarray(set_times), t, side="right") - 1
    for i0, i1 in zip(edges[:-1], edges[1:], strict=True):
        if i1 - i0 >= 2 and finite[i0] and not skipped[i0]:
            yield i0, i1, max(int(set_index[i0]), 0)


def _model_note(sets, params, device: dict, log: dict) -> str:
    """What was simulated, in words with units."""
    if params is not None:
        source = getattr(params, "source", "")
        what = f"the set of {Path(source).name}" if source else "the set given"
    elif len(sets) == 1:
        what = "the set the log rendered"
    else:
        what = f"the {len(sets)} sets the log rendered, each from its time"
    radius = {round(p["radius"], 12) for _, p in sets} if params is None else set()
    terms = []
    if device["damping"]:
        shown = ", ".join(f"{device['damping'] * r:.3g}" for r in sorted(radius))
        terms.append(
            f"the device's damping {device['damping']:g} N s/m"
            + (f" (viscous_damping +{shown} N s/rad)" if shown else "")
        )
    if device["friction"]:
        terms.append(f"its dry friction {device['friction']:g} N on both levels")
    if params is None and any(p["c_energy"] for _, p in sets):
        terms.append("c_energy's push along the motion")
    if params is None and not any(e.get("kind") == "device" for e in log["events"]):
        terms.append("(the log does not record the device's own damping: --device-damping)")
    note = f"haptic, {what}" + (" + " + ", ".join(terms) if terms else "")
    if params is None and log["unknown"] is not None:
        first, last = log["unknown"]
        note += (
            f"; not from {first:.2f} to {last:.2f} s, where the log did not keep the sets "
            "in force (changes past its cap)"
        )
    if log["gaps"]:
        first, last = max(log["gaps"], key=lambda g: g[1] - g[0])
        note += (
            f"; not across {len(log['gaps'])} gap{'s' if len(log['gaps']) > 1 else ''} of "
            "the loop (the longest "
            f"{(last - first) * 1e3:.0f} ms at {first:.2f} s), over which the device held "
            "its last command"
        )
        counted = log["statistics"].get("gaps", 0)  # a number where present (read_log)
        if counted > len(log["gaps"]):
            note += (
                f" (the log kept the first {len(log['gaps'])} of {counted:.0f}: later ones "
                "are simulated across)"
            )
    return note


def format_agreement(a: Agreement, path="") -> str:
    """:meth:`Agreement.errors` for people: angles in degrees, speeds in rad/s."""
    e = a.errors()
    st = a.statistics
    deg = math.degrees
    lines = [f"render log {path}: {a.t[-1] - a.t[0]:.2f} s at {1.0 / (a.t[1] - a.t[0]):g} Hz"]
    if st.get("rate_hz"):
        lines[0] += (
            f", loop {st['rate_hz']:g} Hz"
            + (f", mean period {st['period_mean_s'] * 1e3:.3f} ms" if "period_mean_s" in st else "")
            + (f", {st['missed_cycles']} missed cycles" if "missed_cycles" in st else "")
        )
    lines.append(f"  simulated: {a.model}")
    runs = len(a.starts)
    lines.append(
        f"  from the logged state at {', '.join(f'{s:.2f}' for s in a.starts[:6])} s"
        + (f" ... ({runs} runs)" if runs > 6 else "")
        + f"; {e['samples']} samples compared"
    )
    lines.append(
        f"  theta:  RMS {deg(e['theta_rms']):.3g} deg, largest {deg(e['theta_max']):.3g} deg "
        f"at {e['theta_max_t']:.3f} s (the door moved over {deg(e['theta_span']):.3g} deg)"
    )
    lines.append(
        f"  dtheta: RMS {e['dtheta_rms']:.3g} rad/s, largest {e['dtheta_max']:.3g} rad/s "
        f"at {e['dtheta_max_t']:.3f} s (fastest {e['speed_max']:.3g} rad/s)"
    )
    if st.get("saturated_cycles"):
        lines.append(
            f"  {st['saturated_cycles']} cycles at the device's force limit, which the "
            "model does not have: the motion there is the device's"
        )
    return "\n".join(lines)
