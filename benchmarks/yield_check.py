"""An independent check of a specification's stated yield: build doors, judge each.

``python -m benchmarks.yield_check RUN.h5 [--stage specification] [--samples 2000]
[--seed 7] [--json]`` draws a fresh sample of doors from the nominal and the process
distribution the results file states (each specification ``nominal + d``, ``d`` normal
with 3 sigma = its tolerance or uniform on +-it, clipped to the declared bounds, as a
part is built), judges every door against the stored chosen feel with code of its own
and prints the share that passes beside the stated yield.

The judgement is the rule as the docs state it (docs/perception.md, "The perceptual
check"), written again here without the library's check: each door's Coulomb force-angle
curve from the model's ``accel`` on a grid of its own (1201 angles over the stroke, the
latch zone every 5e-5 rad, where the library uses the perceptual objective's grids), the
chosen curve linear between its stored points; every stroke point within max(Weber
fraction x |chosen|, floor); each latch peak (the least opening force, the largest
closing one) within the force JND of the chosen peak, and its angle within
``position / handle_radius``; the felt inertia and damping, where the chosen feel has
them, within theirs.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

#: points of the stroke's grid, and the spacing of the latch zone's (rad)
STROKE_POINTS = 1201
LATCH_STEP = 5e-5
LATCH_ZONE = math.radians(3.0)


def _feel(node) -> dict:
    """The stored chosen feel: curve (rad, N), JND settings, dynamics, closed angle."""
    a = node.attrs
    return {
        "theta": np.asarray(node["theta"]),
        "opening": np.asarray(node["opening"]),
        "closing": np.asarray(node["closing"]),
        "jnd": json.loads(a["jnd"]),
        "dynamics": json.loads(a["dynamics"]),
        "closed": float(a["closed"]),
    }


def _force_jnd(jnd: dict, force):
    return np.maximum(jnd["force"] * np.abs(force), jnd["force_floor"])


def judge_doors(model, P, feel: dict) -> tuple[np.ndarray, np.ndarray]:
    """Whether each door (a row of full kernel vectors ``P``) passes, and its worst
    difference in JND."""
    from evo_door.sim.simulate import COULOMB_SPEED, coulomb_vector, hold_forces_rows

    jnd = feel["jnd"]
    th_c = feel["theta"]
    edge = th_c[-1] - LATCH_ZONE
    stroke = np.linspace(th_c[0], edge, STROKE_POINTS)[:-1]
    zone = np.arange(edge, th_c[-1] + 0.5 * LATCH_STEP, LATCH_STEP)
    zone_c = th_c >= edge
    angle_jnd = jnd["position"] / jnd["handle_radius"]
    Q = np.array([coulomb_vector(model, p) for p in P])
    worst = np.zeros(len(P))
    for d, sign in (("opening", -1.0), ("closing", 1.0)):
        chosen = np.interp(stroke, th_c, feel[d])
        f = hold_forces_rows(model, Q, stroke, sign * COULOMB_SPEED)
        worst = np.maximum(worst, np.max(np.abs(f - chosen) / _force_jnd(jnd, chosen), axis=1))
        fz = hold_forces_rows(model, Q, zone, sign * COULOMB_SPEED)
        cz = feel[d][zone_c]
        pick = np.argmin if d == "opening" else np.argmax
        kc = int(pick(cz))
        km = pick(fz, axis=1)
        peak_m = fz[np.arange(len(P)), km]
        worst = np.maximum(worst, np.abs(peak_m - cz[kc]) / _force_jnd(jnd, cz[kc]))
        worst = np.maximum(worst, np.abs(zone[km] - th_c[zone_c][kc]) / angle_jnd)
    if feel["dynamics"] is not None:
        worst = np.maximum(worst, _dynamics_jnd(model, P, feel, edge))
    worst = np.where(np.isfinite(worst), worst, np.inf)
    return worst <= 1.0, worst


def _dynamics_jnd(model, P, feel, edge) -> np.ndarray:
    """The felt inertia's and damping's differences (JND), the larger, per door: the
    inertia the force per angular acceleration at half the typical opening speed, the
    damping the force per speed between half and the whole typical speed, both
    averaged over 33 angles of the stroke (docs/perception.md)."""
    from evo_door.sim.simulate import hold_forces_rows, inertia_rows

    jnd = feel["jnd"]
    v = jnd["speed"]
    theta = np.linspace(feel["theta"][0], edge, 33)
    inertia = inertia_rows(model, P, theta, -0.5 * v).mean(axis=1)
    damping = np.zeros(len(P))
    for s in (-1.0, 1.0):
        half = hold_forces_rows(model, P, theta, 0.5 * s * v)
        full = hold_forces_rows(model, P, theta, s * v)
        damping += np.mean((full - half) / (0.5 * s * v), axis=1)
    damping *= 0.5
    ti, tc = feel["dynamics"]
    ji = max(jnd["inertia"] * abs(ti), jnd["force_floor"] / jnd["acceleration"])
    jc = max(jnd["viscosity"] * abs(tc), jnd["force_floor"] / jnd["speed"])
    return np.maximum(np.abs(inertia - ti) / ji, np.abs(damping - tc) / jc)


def draw_doors(model, full, spec: dict, samples: int, seed: int) -> np.ndarray:
    """Doors built to the stated nominal and process: ``samples`` full vectors."""
    rng = np.random.default_rng(seed)
    P = np.repeat(np.asarray(full, dtype=np.float64)[None, :], samples, axis=0)
    for name, t in spec["process"].items():
        i = model.params.index(name)
        q = model.params[name]
        if spec["distribution"][name] == "uniform":
            d = rng.uniform(-t, t, samples)
        else:
            d = rng.normal(0.0, t / 3.0, samples)
        P[:, i] = np.clip(full[i] + d, q.lower, q.upper)
    return P


def check_file(path, stage: str | None, samples: int, seed: int) -> dict:
    """The stated yield of a results file's specification and the independent one."""
    from evo_door.experiment.results import Results
    from evo_door.files import open_h5

    res = Results(path, stage)
    spec = res.summary()
    if "yield" not in spec:
        raise SystemExit(f"{path}: no specification to check (a stage fitted to a chosen feel)")
    model = res.model
    with open_h5(path) as f:
        node = f["stages"][stage] if stage else f
        feel = _feel(node["setup"]["feel"])
        full = np.asarray(node["best"]["full"], dtype=np.float64)
    P = draw_doors(model, full, spec, samples, seed)
    ok, worst = judge_doors(model, P, feel)
    return {
        "stated": spec["yield"],
        "independent": {"estimate": float(ok.mean()), "samples": samples, "seed": seed},
        "difference_points": 100.0 * (float(ok.mean()) - spec["yield"]["estimate"]),
        "reachable": spec["reachable"],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.yield_check", description=__doc__)
    ap.add_argument("run")
    ap.add_argument("--stage", default=None)
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    out = check_file(args.run, args.stage, args.samples, args.seed)
    if args.json:
        print(json.dumps(out))
    else:
        s, i = out["stated"], out["independent"]
        print(
            f"stated yield {100 * s['estimate']:.1f} % ({s['samples']} doors, seed {s['seed']}); "
            f"independent check {100 * i['estimate']:.1f} % ({i['samples']} fresh doors, seed "
            f"{i['seed']}): {out['difference_points']:+.1f} points"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
