"""The physical model of the dishwasher door: the mechanism AMESim held (seed chapter 3).

Five blocks, each in its own module with explicit inputs and outputs, as in the seed's
block diagram (fig. 3.5):

==================  ====================================================================
block               what it does
==================  ====================================================================
kinematics.pose     the closed chain O-A-B(-C) at angle theta and its velocity ratios
DOOR   (door)       the door rod OAE: inertia, gravity, hinge friction, user force
PLATE  (plate)      the plate ABC: spring and friction at C, joint friction at A, stop H
RELATIVESPEED       slip of the plate on the cabinet pad D and the pad's friction
FRICTIONFORCE       slot at B: normal force, Coulomb friction, pin friction
LATCH  (latch)      the catch near closed: unlock / lock springs and the wall
==================  ====================================================================

:func:`accel` wires them into the one compiled right-hand side that the integrators
take. Every block returns the generalised force (N m) it puts on theta, found by
virtual work (the plate is massless), and :func:`loads` sums them; a new block (a
soft-close damper, say) is one more function and one more ``q +=`` line there.

:func:`accel` is the closed form. Simulations and the GA run :func:`accel_tabulated`,
the same blocks with the chain's pose taken from a table (:mod:`.posetable`), on a
vector that :func:`prepare` fills once per parameter set; the door registers the pair
with :func:`~evo_door.sim.integrators.register_prepared` ("The fast path" in
``docs/physical-model.md``), and :func:`switches_prepared`, its switching functions on
that vector. :func:`hold`, the force that holds the door still, is
registered too (:func:`~evo_door.sim.hold.register_hold`): the perceptual
objective's force-angle curves with the mechanism computed once, not twice.

:func:`energy` gives the door's mechanical energy (kinetic, gravity, spring, latch and
stop potentials) for the conservation tests. Equations and the drawing of the
mechanism: ``docs/physical-model.md``.

Size: a little over 600 lines: the model's wiring, its fast path (the prepared vector,
its right-hand side and switching functions) and its holds, which share the blocks'
order and must change together.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from evo_door.models.base import Model
from evo_door.models.door.door import door, door_moment, door_potential
from evo_door.models.door.frictionforce import friction_force
from evo_door.models.door.kinematics import pose
from evo_door.models.door.latch import latch, latch_angles, latch_potential
from evo_door.models.door.plate import plate, spring_potential, stop_h
from evo_door.models.door.posetable import (
    NODE,
    TABLE_HI,
    TABLE_LO,
    TABLE_SIZE,
    TABLE_TOLERANCE,
    build_pose_table,
    table_pose_trig,
)
from evo_door.models.door.relativespeed import relative_speed, section_scale
from evo_door.models.door_params import N_SECTIONS, NOTES, TABLE, TITLE
from evo_door.params import param_vector
from evo_door.sim.hold import HOLD_ROWS_SIGNATURE, HOLD_SIGNATURE, register_hold, register_hold_rows
from evo_door.sim.integrators import PREPARE_SIGNATURE, register_prepared
from evo_door.sim.located import SWITCHES_SIGNATURE

PARAMS = TABLE

# Positions in the kernel vector, from the declaration (never literal).
L = TABLE.index("L")
L_OA = TABLE.index("L_OA")
L_BX = TABLE.index("L_Bx")
L_BY = TABLE.index("L_By")
L_CX = TABLE.index("L_Cx")
L_CY = TABLE.index("L_Cy")
L_DX = TABLE.index("L_Dx")
L_DY = TABLE.index("L_Dy")
G_X = TABLE.index("G_x")
G_Y = TABLE.index("G_y")
K = TABLE.index("K")
F_LOAD = TABLE.index("F_load")
M = TABLE.index("M")
I_Z = TABLE.index("I_z")
T_ATO = TABLE.index("T_atO")
T_ATA = TABLE.index("T_atA")
T_ATB = TABLE.index("T_atB")
MU = TABLE.index("mu")
F_ATC = TABLE.index("F_atC")
F_ATD = TABLE.index("F_atD")
UNLOCK_FORCE = TABLE.index("unlock_force")
LOCK_FORCE = TABLE.index("lock_force")
LATCH_LOOSE_ANGLE = TABLE.index("latch_loose_angle")
LATCH_OPEN_STIFFNESS = TABLE.index("latch_open_stiffness")
LATCH_CLOSE_STIFFNESS = TABLE.index("latch_close_stiffness")
LATCH_OPEN_HOLD = TABLE.index("latch_open_hold")
LATCH_CLOSE_HOLD = TABLE.index("latch_close_hold")
LATCH_SEAT_FORCE = TABLE.index("latch_seat_force")
FRICTION_SCALE_1 = TABLE.index("friction_scale_1")
A_LIN = TABLE.index("a")
A_ROT = TABLE.index("a_rot")
SECTION_SHARPNESS = TABLE.index("section_sharpness")
LATCH_SHARPNESS = TABLE.index("latch_sharpness")
LATCH_DAMPING = TABLE.index("latch_damping")
WALL_STIFFNESS = TABLE.index("wall_stiffness")
WALL_DAMPING = TABLE.index("wall_damping")
STOP_STIFFNESS = TABLE.index("stop_stiffness")
STOP_DAMPING = TABLE.index("stop_damping")

assert all(
    TABLE.index(f"friction_scale_{k + 1}") == FRICTION_SCALE_1 + k for k in range(N_SECTIONS)
)

CLOSED = 0.5 * math.pi

#: LLVM's fast-math flags for the fast path: no signed zeros, reciprocals, fused
#: multiply-adds. Never ``nnan`` / ``ninf``: the integrators' blow-up test needs them.
FAST = {"nsz", "arcp", "contract"}


@njit(cache=True, nogil=True)
def pad_scale(theta, p):
    """A(theta) of eq. 5.8-5.9; exactly 1 (and free) when every section scale is 1."""
    uniform = True
    for j in range(N_SECTIONS):
        if p[FRICTION_SCALE_1 + j] != 1.0:
            uniform = False
    if uniform:
        return 1.0
    return section_scale(
        theta, p[FRICTION_SCALE_1 : FRICTION_SCALE_1 + N_SECTIONS], p[SECTION_SHARPNESS]
    )


@njit(cache=True, nogil=True)
def mechanism_force(theta, dtheta, p):
    """Generalised force (N m) of the plate, pad, slot, latch and stop on theta.

    The wiring of fig. 3.5: pose -> PLATE -> RELATIVESPEED -> FRICTIONFORCE, with
    LATCH and the stop H beside them. Everything but the door's own inertia, gravity
    and hinge friction.
    """
    k = pose(theta, p[L_OA], p[L_BX], p[L_BY], p[L_CX], p[L_CY])
    q = loads(k, dtheta, p, pad_scale(theta, p))
    q += latch_load(theta, dtheta, p)
    q += stop_h(theta, dtheta, p[STOP_STIFFNESS], p[STOP_DAMPING])
    return q


@njit(cache=True, nogil=True, inline="always")
def loads(k, dtheta, p, scale):
    """The plate's, pad's and slot's generalised force (N m) at the pose ``k``.

    The pad friction is scaled by ``scale``; the latch (:func:`latch_load`) and the
    stop H (:func:`~evo_door.models.door.plate.stop_h`) are added by the caller, which
    knows where they give 0.
    """
    pl = plate(k, dtheta, p[L_CY], p[K], p[F_LOAD], p[F_ATC], p[T_ATA], p[A_LIN], p[A_ROT])
    pad = relative_speed(k, dtheta, p[L_DX], p[L_DY], p[F_ATD] * scale, p[A_LIN])
    slot = friction_force(
        k, dtheta, pad.F_Dx, pad.F_Dy, pad.T_B, pl.m, p[MU], p[T_ATB], p[A_LIN], p[A_ROT]
    )
    return pl.q + slot.q


@njit(cache=True, nogil=True)
def latch_load(theta, dtheta, p):
    """The latch's generalised force (N m) on theta (:func:`~.latch.latch` on ``p``)."""
    return latch(
        theta,
        dtheta,
        p[L],
        p[UNLOCK_FORCE],
        p[LOCK_FORCE],
        p[LATCH_LOOSE_ANGLE],
        p[LATCH_OPEN_STIFFNESS],
        p[LATCH_CLOSE_STIFFNESS],
        p[LATCH_OPEN_HOLD],
        p[LATCH_CLOSE_HOLD],
        p[LATCH_SEAT_FORCE],
        p[LATCH_DAMPING],
        p[LATCH_SHARPNESS],
        p[WALL_STIFFNESS],
        p[WALL_DAMPING],
    )


@njit(cache=True, nogil=True)
def accel(theta, dtheta, force, p):
    """Angular acceleration (rad/s^2) of the door under the user force ``force`` (N at E).

    The closed form: the chain's pose computed afresh at every call. Simulations and
    the GA run :func:`accel_tabulated` on a :func:`prepare`-d vector instead (same
    model, the pose from a table); this one is the reference and what the energy,
    curve and truth code call.
    """
    return door(
        theta,
        dtheta,
        force,
        mechanism_force(theta, dtheta, p),
        p[L],
        p[M],
        p[I_Z],
        p[G_X],
        p[G_Y],
        p[T_ATO],
        p[A_ROT],
    )


@njit(cache=True, nogil=True, inline="always")
def _hold_at(k, scale, theta, dtheta, p):
    """:func:`hold` at the chain's pose ``k`` and the pad's section ``scale``, as
    :func:`mechanism_force` sums the blocks (the same numbers, to the last bit)."""
    q_ext = loads(k, dtheta, p, scale)
    q_ext += latch_load(theta, dtheta, p)
    q_ext += stop_h(theta, dtheta, p[STOP_STIFFNESS], p[STOP_DAMPING])
    at = (p[L], p[M], p[I_Z], p[G_X], p[G_Y], p[T_ATO], p[A_ROT])
    a0 = door(theta, dtheta, 0.0, q_ext, *at)
    a1 = door(theta, dtheta, 1.0, q_ext, *at)
    return -a0 / (a1 - a0)


@njit(HOLD_SIGNATURE, cache=True, nogil=True)
def hold(theta, dtheta, p):
    """Force (N at E, + toward closing) that holds the door still at ``(theta, dtheta)``.

    :func:`accel` is affine in the force, so the force is ``-a(0) / (a(1) - a(0))``; the
    mechanism's forces do not depend on it and are computed once here, where two calls
    of :func:`accel` compute them twice: the same numbers, for about half the work (the
    perceptual objective's force-angle curves; registered with
    :func:`~evo_door.sim.hold.register_hold`).
    """
    k = pose(theta, p[L_OA], p[L_BX], p[L_BY], p[L_CX], p[L_CY])
    return _hold_at(k, pad_scale(theta, p), theta, dtheta, p)


#: the columns the chain's pose depends on, and those of the pad's section scale
POSE_COLUMNS = np.array([L_OA, L_BX, L_BY, L_CX, L_CY])
SCALE_COLUMNS = np.array([FRICTION_SCALE_1 + j for j in range(N_SECTIONS)] + [SECTION_SHARPNESS])


@njit(cache=True, nogil=True)
def _same(P, columns) -> bool:
    """Whether every row of ``P`` holds the first row's values in ``columns``."""
    for r in range(1, P.shape[0]):
        for c in columns:
            if P[r, c] != P[0, c]:
                return False
    return True


@njit(HOLD_ROWS_SIGNATURE, cache=True, parallel=True)
def hold_rows(P, theta, dtheta, out):
    """:func:`hold` of every row of ``P`` (doors of one geometry) at every ``theta``
    into ``out`` (rows, angles), across threads; registered with
    :func:`~evo_door.sim.hold.register_hold_rows`.

    Doors of one geometry (a tolerance's sample, a population that leaves the lengths
    alone) share the chain's pose at each angle, and doors whose pad sections agree
    its scale too: computed once an angle, not once a door and angle (a third of the
    time for a tolerance's sample). The same numbers, to the last bit. Returns False,
    with nothing written, for doors of geometries of their own (:func:`hold` at each
    door and angle is the way there).
    """
    if not _same(P, POSE_COLUMNS):
        return False
    shared_scale = _same(P, SCALE_COLUMNS)
    p0 = P[0]
    for i in prange(theta.shape[0]):
        th = theta[i]
        k = pose(th, p0[L_OA], p0[L_BX], p0[L_BY], p0[L_CX], p0[L_CY])
        s0 = pad_scale(th, p0)
        for r in range(P.shape[0]):
            s = s0 if shared_scale else pad_scale(th, P[r])
            out[r, i] = _hold_at(k, s, th, dtheta, P[r])
    return True


#: How many switching functions :func:`switches` writes.
N_SWITCHES = 9


@njit(cache=True, nogil=True, inline="always")
def latch_edges(p):
    """The latch's switching angles (rad) for the parameters ``p`` of a door with a
    latch: ``(theta_0, seat, rise_end, theta_3, ramp)``, the catch's edge, the seat's
    width past it, where the catch's rise ends, the lock ramp's foot and its width."""
    unlock = p[UNLOCK_FORCE]
    lock = p[LOCK_FORCE]
    k_1 = p[LATCH_OPEN_STIFFNESS]
    theta_0, _theta_1, theta_3 = latch_angles(
        unlock,
        lock,
        p[LATCH_LOOSE_ANGLE],
        k_1,
        p[LATCH_CLOSE_STIFFNESS],
        p[LATCH_OPEN_HOLD],
        p[LATCH_CLOSE_HOLD],
    )
    rise_end = theta_0 - unlock / k_1
    return theta_0, p[LATCH_SEAT_FORCE] / k_1, rise_end, theta_3, lock / p[LATCH_CLOSE_STIFFNESS]


@njit(cache=True, nogil=True, inline="always")
def write_switches(
    theta, dtheta, p, g, has_latch, has_catch, theta_0, seat, rise_end, theta_3, ramp
):  # fmt: skip
    """The nine values of :func:`switches` into ``g``, the latch's angles given
    (:func:`latch_edges`; unread without a latch): what it and
    :func:`switches_prepared` share."""
    g[0] = theta
    if theta < 0.0:
        g[1] = -p[STOP_STIFFNESS] * theta - p[STOP_DAMPING] * dtheta
    else:
        g[1] = 1.0
    pen = theta - CLOSED
    g[2] = pen
    g[3] = p[WALL_STIFFNESS] * pen + p[WALL_DAMPING] * dtheta if pen > 0.0 else 1.0
    if has_latch:
        g[4] = theta - theta_0
        g[5] = theta - theta_0 - seat if has_catch else 1.0
        g[6] = theta - rise_end
        g[7] = theta - theta_3
        g[8] = theta - theta_3 - ramp
    else:
        for i in range(4, N_SWITCHES):
            g[i] = 1.0


@njit(SWITCHES_SIGNATURE, cache=True, nogil=True)
def switches(theta, dtheta, force, p, g):
    """The door's switching functions (where its right-hand side kinks or jumps), into ``g``.

    The stop H at fully open and the wall at closed (contact, and where their damper
    would pull: they never do), the free play's end, the seat's rise, the catch's
    and the lock ramp's rise ends, the lock ramp's foot. The apex and the latch
    damping's window are steep tanh edges, smooth (the adaptive step follows them).
    Reads only parameters, so it serves the prepared vector too. A function that
    does not apply is 1.
    """
    unlock = p[UNLOCK_FORCE]
    if unlock > 0.0 or p[LOCK_FORCE] > 0.0:
        theta_0, seat, rise_end, theta_3, ramp = latch_edges(p)
        write_switches(
            theta, dtheta, p, g, True, unlock > 0.0, theta_0, seat, rise_end, theta_3, ramp
        )
    else:
        write_switches(theta, dtheta, p, g, False, False, 0.0, 0.0, 0.0, 0.0, 0.0)


# -- the fast path: a kernel vector with the pose table appended -----------------------
N_PARAMS = len(TABLE)
# Header of a prepared vector, after the parameters (what depends on the parameters
# but not on the state, worked out once per parameter set):
#: 1.0 when the pose table passed its check (else the closed form is used throughout)
TABLE_OK = N_PARAMS
#: the largest error the table's check found (for tests and reports)
TABLE_ERROR = N_PARAMS + 1
#: 1.0 when every section scale of the pad friction is 1 (A(theta) = 1)
PAD_UNIFORM = N_PARAMS + 2
#: 1 / I_O (1 / (kg m^2))
INV_INERTIA = N_PARAMS + 3
#: The angle (rad) above which the latch (or, without a catch, the wall) may act: the
#: foot of the lock ramp theta_3 less the width where its activation is 0 to double
#: precision, and a margin (the latch tests that edge itself, exactly); pi/2 without
#: a catch, -inf if the test cannot be made (NaN or zero sharpness).
LATCH_FROM = N_PARAMS + 4
#: Lowest angle (rad) the pose table serves: ``TABLE_LO``, or +inf if the table
#: failed its check (the closed form is used throughout).
TABLE_FROM = N_PARAMS + 5
#: The stamp of the pose table the vector holds (an int64 in the float's bits): its
#: geometry's and its floats' bits folded (:func:`table_stamp`). :func:`prepare` builds
#: the table only where the stamp does not match what the vector holds.
TABLE_STAMP = N_PARAMS + 6
#: The latch's switching angles of :func:`switches` (rad), for
#: :func:`switches_prepared`: 1.0 in ``HAS_LATCH`` where there is a latch (a catch or a
#: lock ramp), 1.0 in ``HAS_CATCH`` where there is a catch; the catch's edge theta_0;
#: the seat's width past it; where the catch's rise ends; the lock ramp's foot
#: theta_3; the ramp's width past it. Worked out as :func:`switches` works them out.
#: The two flags could be derived from the latch's forces at the vector's start, but
#: :func:`write_switches` testing those instead made :func:`switches_prepared` some ten
#: times slower a call and the door's population kernel a tenth slower (measured on
#: 2026-12-02): they stay.
HAS_LATCH, HAS_CATCH, CATCH_EDGE, SEAT_WIDTH, RISE_END, RAMP_FOOT, RAMP_WIDTH = (
    N_PARAMS + 7 + i for i in range(7)
)
#: First float of the pose table (:mod:`~evo_door.models.door.posetable`).
TABLE_START = N_PARAMS + 14
#: Length of a prepared vector.
PREPARED_SIZE = TABLE_START + TABLE_SIZE


#: The geometry, the only parameters the pose table depends on.
GEOMETRY = (L_OA, L_BX, L_BY, L_CX, L_CY)


@njit(cache=True, nogil=True)
def table_stamp(p, q):
    """The stamp of a pose table in ``q`` built for the geometry of ``p``: the bits of
    the five lengths and of every float of the table folded into one int64 (a table
    not built, or changed since, gives another stamp)."""
    bits = q.view(np.int64)
    folded = np.int64(0)
    for i in range(TABLE_START, TABLE_START + TABLE_SIZE):
        folded ^= bits[i]
    lengths = p.view(np.int64)
    stamp = np.int64(-3750763034362895579)  # FNV-1a's offset basis
    for g in GEOMETRY:
        stamp = (stamp ^ lengths[g]) * np.int64(1099511628211)
    for w in (bits[TABLE_OK], bits[TABLE_ERROR], bits[TABLE_FROM], folded):
        stamp = (stamp ^ w) * np.int64(1099511628211)
    return stamp


@njit(cache=True, nogil=True)
def prepare_switches(p, q):
    """The latch's switching angles of :func:`switches` (:func:`latch_edges`) into the
    header of ``q`` (``HAS_LATCH`` ... ``RAMP_WIDTH``): what :func:`switches_prepared`
    reads instead of working them out at every call."""
    unlock = p[UNLOCK_FORCE]
    lock = p[LOCK_FORCE]
    q[HAS_LATCH] = 1.0 if unlock > 0.0 or lock > 0.0 else 0.0
    q[HAS_CATCH] = 1.0 if unlock > 0.0 else 0.0
    if q[HAS_LATCH] == 0.0:  # nothing reads them (and they would divide by nothing)
        for i in (CATCH_EDGE, SEAT_WIDTH, RISE_END, RAMP_FOOT, RAMP_WIDTH):
            q[i] = math.nan
        return
    edges = latch_edges(p)
    q[CATCH_EDGE], q[SEAT_WIDTH], q[RISE_END], q[RAMP_FOOT], q[RAMP_WIDTH] = edges


# its signature declared: the objective kernels take it as a first-class function and
# Python calls it (Prepared.vector), and numba's cache keys the two ways apart
@njit(PREPARE_SIGNATURE, cache=True, nogil=True)
def prepare(p, q):
    """Fill the prepared vector ``q`` (:data:`PREPARED_SIZE`) for the parameters ``p``.

    ``q`` holds ``p``, then what depends on ``p`` but not on the state (the header
    above: 1 / I_O, whether the pad friction is uniform, where the latch begins, where
    the table applies, the latch's switching angles), then
    the pose table of ``p``'s geometry with its check
    (:func:`~evo_door.models.door.posetable.build_pose_table`): some 50 us, 1-2 % of a
    5 s trial, once per parameter set for all its trials.

    Where ``q`` already holds a table built for ``p``'s geometry (its stamp,
    :data:`TABLE_STAMP`, matches), the table is kept: a kernel that prepares one
    vector after another into the same ``q`` (a population, whose geometry is rarely
    free) builds it once. The vector is the same, bit for bit, either way.
    """
    n = p.shape[0]
    if q.view(np.int64)[TABLE_STAMP] != table_stamp(p, q):
        scratch = np.empty(NODE)
        err = build_pose_table(p[L_OA], p[L_BX], p[L_BY], p[L_CX], p[L_CY], q, TABLE_START, scratch)
        q[TABLE_ERROR] = err
        q[TABLE_OK] = 1.0 if err <= TABLE_TOLERANCE else 0.0
        q[TABLE_FROM] = TABLE_LO if err <= TABLE_TOLERANCE else math.inf
        q.view(np.int64)[TABLE_STAMP] = table_stamp(p, q)
    for i in range(n):
        q[i] = p[i]
    uniform = 1.0
    for j in range(N_SECTIONS):
        if p[FRICTION_SCALE_1 + j] != 1.0:
            uniform = 0.0
    q[PAD_UNIFORM] = uniform
    q[INV_INERTIA] = 1.0 / (p[I_Z] + p[M] * (p[G_X] * p[G_X] + p[G_Y] * p[G_Y]))
    if p[UNLOCK_FORCE] > 0.0 or p[LOCK_FORCE] > 0.0:
        theta_3 = latch_angles(
            p[UNLOCK_FORCE],
            p[LOCK_FORCE],
            p[LATCH_LOOSE_ANGLE],
            p[LATCH_OPEN_STIFFNESS],
            p[LATCH_CLOSE_STIFFNESS],
            p[LATCH_OPEN_HOLD],
            p[LATCH_CLOSE_HOLD],
        )[2]
        # latch() is exactly 0 where (theta_3 - theta) sharpness > 20 and theta <= pi/2
        edge = theta_3 - 20.0 / p[LATCH_SHARPNESS]
        edge -= 1e-9 * (1.0 + abs(edge))
        latch_from = min(edge, CLOSED) if p[LATCH_SHARPNESS] > 0.0 else -math.inf
        q[LATCH_FROM] = latch_from if not math.isnan(latch_from) else -math.inf
    else:
        q[LATCH_FROM] = CLOSED
    prepare_switches(p, q)


# Not inlined where the kernels take it: a first-class function, like switches.
@njit(SWITCHES_SIGNATURE, cache=True, nogil=True)
def switches_prepared(theta, dtheta, force, q, g):
    """:func:`switches` on a :func:`prepare`-d vector ``q``, to the last bit: the latch's
    angles read from its header (:func:`prepare_switches`) rather than worked out at
    every call: their five divisions were most of its time, and it is called at the end
    of every step and at every sample inside a step over several."""
    write_switches(
        theta, dtheta, q, g, q[HAS_LATCH] != 0.0, q[HAS_CATCH] != 0.0, q[CATCH_EDGE],
        q[SEAT_WIDTH], q[RISE_END], q[RAMP_FOOT], q[RAMP_WIDTH],
    )  # fmt: skip


# error_model="numpy": a float division by zero gives inf / nan instead of raising, so
# numba drops its zero test before each of the ~10 divisions; none of them can divide
# by zero (I_O > 0, the slot's denominator is floored, tanh's denominators are >= 1).
@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def accel_tabulated(theta, dtheta, force, q):
    """:func:`accel` on a :func:`prepare`-d vector ``q``: the pose from its table.

    Same blocks, same equations; the chain's pose (and cos, sin of theta for gravity)
    is interpolated, to within 1e-11 of the closed form
    (:mod:`~evo_door.models.door.posetable`), and the header's values replace work per
    call (1 / I_O, the uniform pad, where the latch can act: below :data:`LATCH_FROM`
    it is not called, nor the stop above 0). Outside the table's angles, or when the
    table failed its check, the pose is the closed form. Fast-math :data:`FAST`;
    """
    if q[TABLE_FROM] <= theta <= TABLE_HI:
        k, c, s = table_pose_trig(theta, q[L_OA], q[L_BX], q, TABLE_START)
    else:
        k = pose(theta, q[L_OA], q[L_BX], q[L_BY], q[L_CX], q[L_CY])
        c = math.cos(theta)
        s = math.sin(theta)
    if q[PAD_UNIFORM] != 0.0:
        scale = 1.0
    else:
        scale = section_scale(
            theta, q[FRICTION_SCALE_1 : FRICTION_SCALE_1 + N_SECTIONS], q[SECTION_SHARPNESS]
        )
    q_ext = loads(k, dtheta, q, scale)
    # the latch and the stop give exactly 0 over most of the stroke: skip their calls
    if theta > q[LATCH_FROM]:
        q_ext += latch_load(theta, dtheta, q)
    if theta < 0.0:
        q_ext += stop_h(theta, dtheta, q[STOP_STIFFNESS], q[STOP_DAMPING])
    moment = door_moment(c, s, dtheta, force, q_ext, q[L], q[M], q[G_X], q[G_Y], q[T_ATO], q[A_ROT])
    return moment * q[INV_INERTIA]


def prepared_vector(params) -> np.ndarray:
    """The prepared kernel vector of a ParamSet or a parameter vector (plain Python)."""
    q = np.empty(PREPARED_SIZE)
    prepare(param_vector(params, TABLE), q)
    return q


register_prepared(accel, accel_tabulated, prepare, PREPARED_SIZE, switches=switches_prepared)
register_hold(accel, hold)
register_hold_rows(accel, hold_rows)


@njit(cache=True, nogil=True)
def energy(theta, dtheta, p):
    """Mechanical energy (J): kinetic + gravity + spring at C + latch springs + stops.

    Zero-referenced at the fully-open pose at rest. The latch's potential is in closed
    form (:func:`~evo_door.models.door.latch.latch_potential`), the stop and wall
    potentials are the one-sided ``k x^2 / 2``.
    """
    inertia_o = p[I_Z] + p[M] * (p[G_X] ** 2 + p[G_Y] ** 2)
    e = 0.5 * inertia_o * dtheta * dtheta
    e += door_potential(theta, p[M], p[G_X], p[G_Y]) - door_potential(0.0, p[M], p[G_X], p[G_Y])
    k = pose(theta, p[L_OA], p[L_BX], p[L_BY], p[L_CX], p[L_CY])
    e += spring_potential(k, p[L_CY], p[K], p[F_LOAD])
    # latch: V(theta) = -int L F_latch dtheta, in closed form (latch.latch_potential)
    if p[UNLOCK_FORCE] > 0.0 or p[LOCK_FORCE] > 0.0:
        e += p[L] * latch_potential(
            theta,
            p[UNLOCK_FORCE],
            p[LOCK_FORCE],
            p[LATCH_LOOSE_ANGLE],
            p[LATCH_OPEN_STIFFNESS],
            p[LATCH_CLOSE_STIFFNESS],
            p[LATCH_OPEN_HOLD],
            p[LATCH_CLOSE_HOLD],
            p[LATCH_SEAT_FORCE],
        )
    if theta > CLOSED:
        e += 0.5 * p[WALL_STIFFNESS] * p[L] * (theta - CLOSED) ** 2
    if theta < 0.0:
        e += 0.5 * p[STOP_STIFFNESS] * theta * theta
    return e


def energy_of(params, theta, dtheta) -> np.ndarray:
    """:func:`energy` over arrays (J), for a ParamSet or a kernel vector."""
    p = param_vector(params, TABLE)
    theta = np.asarray(theta, dtype=np.float64)
    dtheta = np.broadcast_to(np.asarray(dtheta, dtype=np.float64), theta.shape)
    return np.array(
        [energy(float(a), float(b), p) for a, b in zip(theta.ravel(), dtheta.ravel())]
    ).reshape(theta.shape)


#: Dormand-Prince 5(4), adaptive, steps of at most one 1024 Hz sample, the stops, the
#: wall and the latch's kinks located (:func:`switches`): the steep apex and the tanh
#: frictions are followed by the step control. Its accuracy against a converged
#: reference: tests/test_events.py (bounds), benchmarks/trial.md (measured).
MODEL = Model(
    name="door",
    title=TITLE,
    params=TABLE,
    accel=accel,
    method="dopri5",
    substeps=1,
    theta0=0.0,
    notes=NOTES,
    rig_kinds=("impulse", "unlock", "lock", "slow"),
    switches=switches,
    n_switches=N_SWITCHES,
)
