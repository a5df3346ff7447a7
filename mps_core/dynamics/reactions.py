"""Joint reactions and the foundation load, by Newton–Euler per body (contract §7).

For a state (q, q̇, q̈) in a chart view, every moving body b has, from the exact kinematics (jets
of the closed-form positions), its centre-of-mass acceleration
``a_G = ∂r_G/∂q·q̈ + (∂²r_G/∂q²)(q̇, q̇)`` and its angular acceleration ``α = ω*·q̈ + θ''``.
Newton–Euler (d'Alembert) for each body, with the moment equation taken **about the body's own
centre of mass**::

    Σ forces on b                       = m_b a_Gb
    Σ (P − G_b) × F  +  Σ torques on b   = J_b α_b

gives 3 equations a body (12 for the press) in the joint reactions. The unknowns follow from the
structure (``view.frozen``):

==========  =====================================================================================
``F_O``     force the **frame** receives from the **crank** at O (the crank receives −F_O)
``F_A``     force the **crank** receives from the **rod** at A (the rod receives −F_A)
``F_B``     force the **rod** receives from the **rocker** at B (the rocker receives −F_B)
``F_C``     force the **slider** receives from the **rocker** at C (the rocker receives −F_C)
``N_guide`` force along y the **frame** receives from the **slider** through the guide, at C
``M_guide`` moment the **frame** receives from the **slider** through the guide
``M_latch`` moment the **slider** receives from the **rocker** (latch closed: ``psi`` frozen)
``F_stop``  force along x the **frame** receives from the **slider** at the top stop, at C
            (slider held: ``x_C`` frozen); positive when the stop is compressed, so the slider
            leaves the stop where F_stop would turn negative
``M_motor`` torque the **crank** receives from the motor (known, from the motor effect); the
            frame receives −M_motor through the stator
==========  =====================================================================================

Forces are in the frame's axes (x along the guide, up; y across), moments about z (counter-
clockwise positive), SI units. Known loads are every effect's forces and torques on the moving
bodies (gravity, motor, and whatever effects the scene adds).

**Solution.** The system has as many equations more than unknowns as the structure has degrees
of freedom: what is left over is the equation of motion itself. It is solved by least squares in
which the moment rows are divided by a length ``L`` (the mean length of the rotating links) so
that every row is in newtons, under the exact constraint that the whole moving system's balance
(Σ forces, Σ moments about O) holds: the frame's resultant carries exactly the momentum change of
the moving links, and the leftover is shared among the single reactions in the least-squares
sense (e.g. M_guide, zero in ``free`` with exact derivatives, takes an O(Δ²) share of it with
central differences). The residual ``r = b − E u`` is kept per step:
``residual_force_N`` (norm of its force rows) and ``residual_moment_Nm`` (norm of its moment rows).
Because reactions do no work on admissible motions, ``J_bᵀ r = A q̈ + h − Q`` with the *exact* A
and h and the exact virtual work Q of the loads taken (J_b: the bodies' exact velocity analogs):
the residual measures how far the step's q̈ is from the exact equations of motion at its own
(q, q̇). With exact derivatives (``autodiff``) it is round-off; with the seed's central
differences it is O(Δ²) (the error of A, ∂A and the analogs); it does not see the integrator's
time-step error (q̈ is evaluated at the accepted state).

**Foundation load.** What the frame receives in sum: the frame-side joint reactions (F_O, the
guide's (0, N_guide) at C and M_guide, the stop's (F_stop, 0) at C) and every effect's ``frame``
entries (e.g. −M_motor); ``F_found`` and ``M_found_O`` (moment about O, the frame's origin). The
balance check, computed independently of the solve: ``Σ m_b a_Gb − (Σ effect forces on moving
bodies − Σ forces the frame receives from them)``, in N (``balance_residual_N``), and the same for
moments about O (``balance_residual_Nm``): round-off.

**Impacts.** :func:`impulses` solves the same system with momentum jumps in place of m·a and J·α
and no finite forces: the impulse per joint (N·s) of a plastic impact, reported as an event.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from ..codegen.reaction_kernels import Fallback
from ..derivatives.jet import Jet
from ..derivatives.tracing import BranchChanged
from ..model.mechanism import FRAME, ChartView, Joint, Mechanism
from ..model.press import PRESS_JOINTS
from .engine import Kinematics

#: what a reaction kernel raises where the general path must answer
_FALLBACKS = (Fallback, BranchChanged, ArithmeticError, ValueError)


#: reaction columns of a trajectory, in CSV order, with their units (contract §7, then residuals)
REACTION_COLUMNS: dict[str, str] = {
    "F_O_x": "N",
    "F_O_y": "N",
    "F_A_x": "N",
    "F_A_y": "N",
    "F_B_x": "N",
    "F_B_y": "N",
    "F_C_x": "N",
    "F_C_y": "N",
    "N_guide": "N",
    "M_guide": "N*m",
    "M_latch": "N*m",
    "F_stop": "N",
    "M_motor": "N*m",
    "F_found_x": "N",
    "F_found_y": "N",
    "M_found_O": "N*m",
    "residual_force_N": "N",
    "residual_moment_Nm": "N*m",
    "balance_residual_N": "N",
    "balance_residual_Nm": "N*m",
}

#: what each reaction column is: receiving body, point, axes
DESCRIPTIONS: dict[str, str] = {
    **{
        c: f"{j.meaning}, {axis}"
        for j in PRESS_JOINTS
        for c, axis in zip(
            j.columns,
            [
                {
                    "x": "x component (frame axes: x along the guide, up)",
                    "y": "y component (frame axes: y across the guide)",
                    "m": "about z, counter-clockwise positive",
                }[k]
                for k in j.components
            ],
        )
    },
    "M_motor": "torque the crank receives from the motor (the frame receives -M_motor through "
    "the stator), about z",
    "F_found_x": "foundation load: x component of the resultant force the frame receives from "
    "the moving links and the effects (along the guide, up)",
    "F_found_y": "foundation load: y component of the resultant force the frame receives (across the guide)",
    "M_found_O": "foundation load: resultant moment about O the frame receives, about z",
    "residual_force_N": "norm of the force rows left over by the least-squares solve "
    "(the equation of motion's residual)",
    "residual_moment_Nm": "norm of the moment rows left over by the least-squares solve",
    "balance_residual_N": "|sum m a_G - (effect forces on moving links - forces the frame "
    "receives from them)|",
    "balance_residual_Nm": "the same balance for moments about O",
}

_JOINT_COLUMNS = tuple(
    c
    for c in REACTION_COLUMNS
    if c
    not in (
        "M_motor",
        "F_found_x",
        "F_found_y",
        "M_found_O",
        "residual_force_N",
        "residual_moment_Nm",
        "balance_residual_N",
        "balance_residual_Nm",
    )
)


# -- exact kinematics from jets -------------------------------------------------------------
def _parts(c, n: int):
    """(value, gradient (n,), first, second directional derivative) of a jet or a constant."""
    if isinstance(c, Jet):
        return (float(c.val), np.asarray(c.grad, dtype=float).reshape(n), float(c.d1), float(c.d2))
    return float(c), np.zeros(n), 0.0, 0.0


@dataclass
class BodyMotion:
    """Exact kinematics of the moving bodies at (q, q̇): everything but q̈.

    ``X``/``J``/``D1``/``D2``: positions, analogs ∂r/∂q, velocities and convective accelerations
    of the points and centres of mass ``G_<body>`` (rows by ``names``); ``W`` (nbody, n): angular
    analogs, ``theta2`` (nbody,): convective angular accelerations (zero for bodies that only
    translate).
    """

    names: dict
    X: np.ndarray
    J: np.ndarray
    D1: np.ndarray
    D2: np.ndarray
    W: np.ndarray
    theta2: np.ndarray
    bodies: dict

    def com_rows(self, mechanism: Mechanism) -> np.ndarray:
        return np.array([self.names[f"G_{b.name}"] for b in mechanism.bodies], dtype=int)

    def kinematics(self, t: float, q, qd) -> Kinematics:
        """The engine's :class:`Kinematics` with exact analogs (for effects' loads)."""
        return Kinematics(
            t, np.asarray(q, float), np.asarray(qd, float), self.names, self.X, self.J, self.W, self.bodies
        )


def body_motion(mechanism: Mechanism, view: ChartView, q, qd) -> BodyMotion:
    """Exact positions, analogs and convective accelerations from one jet evaluation."""
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    n = view.n
    pose = dict(view.pose_jets(q, qd))
    for b in mechanism.bodies:
        pose[f"G_{b.name}"] = b.com_of(pose)
    names = {p: k for k, p in enumerate(list(mechanism.points) + [f"G_{b.name}" for b in mechanism.bodies])}
    NP = len(names)
    X = np.zeros((NP, 2))
    J = np.zeros((NP, 2, n))
    D1 = np.zeros((NP, 2))
    D2 = np.zeros((NP, 2))
    for name, row in names.items():
        for k, c in enumerate(pose[name]):
            X[row, k], J[row, k], D1[row, k], D2[row, k] = _parts(c, n)
    nb = len(mechanism.bodies)
    W = np.zeros((nb, n))
    theta2 = np.zeros(nb)
    for k, b in enumerate(mechanism.bodies):
        if b.toward is None:  # translates only
            continue
        o, t = names[b.origin], names[b.toward]
        r, rj = X[t] - X[o], J[t] - J[o]
        r1, r2v = D1[t] - D1[o], D2[t] - D2[o]
        rr = float(r @ r)
        W[k] = (r[0] * rj[1] - r[1] * rj[0]) / rr
        w1 = (r[0] * r1[1] - r[1] * r1[0]) / rr
        theta2[k] = (r[0] * r2v[1] - r[1] * r2v[0]) / rr - 2.0 * w1 * float(r @ r1) / rr
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(J))):
        raise ValueError(f"reactions: no finite kinematics in chart {view.name} at q = {q.tolist()}")
    return BodyMotion(names, X, J, D1, D2, W, theta2, {b.name: k for k, b in enumerate(mechanism.bodies)})


# -- the system -----------------------------------------------------------------------------
def active_joints(mechanism: Mechanism, frozen: Iterable[str]) -> list[Joint]:
    """The joints that carry load in a structure with these frozen coordinates."""
    frozen = set(frozen)
    joints = mechanism.joints
    return [j for j in joints if j.requires is None or j.requires in frozen]


def length_scale(mechanism: Mechanism) -> float:
    """L (m) dividing the moment rows in the least squares: mean length of the rotating links."""
    lengths = [b.length for b in mechanism.bodies if b.rotates and b.length > 0]
    return float(np.mean(lengths)) if lengths else 1.0


class _System:
    """E u = b: 3 rows a moving body (Fx, Fy, M about its centre of mass), one column an unknown."""

    def __init__(self, mechanism: Mechanism, motion: BodyMotion, joints: Sequence[Joint], drive: str | None):
        self.mechanism = mechanism
        self.motion = motion
        self.body_row = {b.name: 3 * k for k, b in enumerate(mechanism.bodies)}
        self.G = motion.X[motion.com_rows(mechanism)]
        self.origin = motion.X[motion.names["O"]] if "O" in motion.names else np.zeros(2)
        cols: list[tuple[Joint | None, str, str]] = []
        for j in joints:
            for comp, col in zip(j.components, j.columns):
                cols.append((j, comp, col))
        if drive is not None:
            if drive not in self.body_row:
                raise ValueError(
                    f"reactions: drive = {drive!r}: expected a moving body, one of "
                    + ", ".join(self.body_row)
                )
            cols.append((None, "m", "M_drive"))
        self.cols = cols
        self.drive = drive
        nrow = 3 * len(mechanism.bodies)
        E = np.zeros((nrow, len(cols)))
        for c, (joint, comp, _col) in enumerate(cols):
            if joint is None:  # the drive: its body receives +M, the frame −M
                assert drive is not None  # (its column is there only with a drive)
                E[self.body_row[drive] + 2, c] += 1.0
                continue
            for body, sign in ((joint.receiver, 1.0), (joint.giver, -1.0)):
                if body == FRAME:
                    continue
                self._add(E[:, c], body, comp, joint.point, sign)
        self.E = E
        # whole-system balance (Σ force x, Σ force y, Σ moment about O) as rows on the residual
        C = np.zeros((3, nrow))
        for k in range(len(mechanism.bodies)):
            r0 = 3 * k
            g = self.G[k] - self.origin
            C[0, r0] = 1.0
            C[1, r0 + 1] = 1.0
            C[2, r0] = -g[1]
            C[2, r0 + 1] = g[0]
            C[2, r0 + 2] = 1.0
        self.C = C

    def _add(self, col: np.ndarray, body: str, comp: str, point: str | None, sign: float):
        r0 = self.body_row.get(body)
        if r0 is None:
            raise ValueError(f"reactions: joint body {body!r} is not a body of the mechanism")
        if comp == "m":
            col[r0 + 2] += sign
            return
        d = self.motion.X[self.motion.names[point]] - self.G[r0 // 3]
        if comp == "x":
            col[r0] += sign
            col[r0 + 2] += -sign * d[1]
        else:
            col[r0 + 1] += sign
            col[r0 + 2] += sign * d[0]

    def solve(self, b: np.ndarray, scale: float):
        """Least squares in newtons (moment rows / scale) with the whole-system balance exact."""
        E, C = self.E, self.C
        s = np.ones(len(b))
        s[2::3] = 1.0 / scale
        K = C @ E
        U, sv, Vt = np.linalg.svd(K)
        tol = max(K.shape) * np.finfo(float).eps * (sv[0] if sv.size else 0.0)
        rk = int(np.sum(sv > tol))
        d = C @ b
        up = Vt[:rk].T @ ((U[:, :rk].T @ d) / sv[:rk])
        N = Vt[rk:].T
        u = up
        rz = 0
        if N.shape[1]:
            M = s[:, None] * (E @ N)
            z, _res, rz, _sv = np.linalg.lstsq(M, s * (b - E @ up), rcond=None)
            u = up + N @ z
        return u, b - E @ u, rk + int(rz)


def _external(mechanism, effects, t, kin, motion: BodyMotion, G: np.ndarray):
    """Known loads: per body (Fx, Fy, M about G), their sums about O, the frame's own entries,
    and the motor torque."""
    nb = len(mechanism.bodies)
    index = motion.bodies
    ext = np.zeros((nb, 3))
    frame_F = np.zeros(2)
    frame_M = 0.0
    ext_M_O = 0.0
    m_motor = 0.0
    for e in effects:
        ld = e.loads(t, kin)
        for body, point, fx, fy in ld.forces:
            k = index.get(body)
            if k is None:
                raise ValueError(
                    f"effect {e.name!r}: force on {body!r}, expected a moving body "
                    f"({', '.join(index)}); the frame's share belongs in Loads.frame"
                )
            p = _point(motion, point, e.name)
            ext[k, 0] += fx
            ext[k, 1] += fy
            ext[k, 2] += (p[0] - G[k, 0]) * fy - (p[1] - G[k, 1]) * fx
            ext_M_O += p[0] * fy - p[1] * fx
        for body, m in ld.torques:
            k = index.get(body)
            if k is None:
                raise ValueError(
                    f"effect {e.name!r}: torque on {body!r}, expected a moving body ({', '.join(index)})"
                )
            ext[k, 2] += m
            ext_M_O += m
            if getattr(e, "kind", "") == "motor":
                m_motor += m
        for entry in ld.frame:
            if len(entry) == 4:
                _, point, fx, fy = entry
                p = _point(motion, point, e.name)
                frame_F += (fx, fy)
                frame_M += p[0] * fy - p[1] * fx
            elif len(entry) == 2:
                frame_M += entry[1]
            else:
                raise ValueError(
                    f"effect {e.name!r}: frame entry {entry!r}: expected "
                    "('frame', point, Fx, Fy) or ('frame', M)"
                )
    return ext, ext_M_O, frame_F, frame_M, m_motor


def _point(motion: BodyMotion, point, effect: str) -> np.ndarray:
    """A load's point relative to O: a mechanism point's name, ``G_<body>``, or (x, y) in m."""
    o = motion.X[motion.names["O"]] if "O" in motion.names else np.zeros(2)
    if isinstance(point, str):
        row = motion.names.get(point)
        if row is None:
            raise ValueError(
                f"effect {effect!r}: point {point!r}: expected one of "
                + ", ".join(motion.names)
                + " or coordinates (x, y) in m"
            )
        return motion.X[row] - o
    p = np.asarray(point, dtype=float)
    if p.shape != (2,):
        raise ValueError(f"effect {effect!r}: point {point!r}: expected a name or (x, y) in m")
    return p - o


# -- results ----------------------------------------------------------------------------------
@dataclass
class Reactions:
    """The reactions at one state. ``values`` has every :data:`REACTION_COLUMNS` key (zero where
    the structure has no such joint); ``residual`` is the least squares' leftover ``b − E u``
    (3 rows a body: Fx, Fy in N, M about the centre of mass in N·m); ``unknowns`` names the
    solved columns; ``rank`` is the rank of the solve (a value below ``len(unknowns)`` means the
    reactions are not unique here: a singular position of the machine)."""

    t: float
    values: dict
    residual: np.ndarray
    unknowns: tuple
    rank: int

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    @property
    def foundation_force(self) -> np.ndarray:
        return np.array([self.values["F_found_x"], self.values["F_found_y"]])


def _frame_share(sysm, u, motion, values) -> tuple[np.ndarray, float, float]:
    """Put each solved unknown into ``values`` and sum what the frame receives through the
    joints: (force, moment about the system's origin, drive torque solved as an unknown)."""
    R_F = np.zeros(2)
    R_M = 0.0
    drive = 0.0
    o = sysm.origin
    for (j, comp, col), val in zip(sysm.cols, u):
        if j is None:
            drive += val
            continue
        values[col] = float(val)
        sign = 1.0 if j.receiver == FRAME else (-1.0 if j.giver == FRAME else 0.0)
        if sign == 0.0:
            continue
        if comp == "m":
            R_M += sign * val
            continue
        f = np.array([val, 0.0] if comp == "x" else [0.0, val]) * sign
        p = motion.X[motion.names[j.point]] - o
        R_F += f
        R_M += p[0] * f[1] - p[1] * f[0]
    return R_F, R_M, drive


class _Kernels:
    """A mechanism's reaction kernels by (chart view, length scale), and the maps they are
    written from."""

    def __init__(self, mechanism: Mechanism):
        from .engine import PartialSystems

        self.engine = PartialSystems(mechanism, (), scheme="autodiff")
        self.mechanism = mechanism
        self.scale = length_scale(mechanism)
        self.views: dict = {}
        self._loads = None  # (the effects' list and its length, LoadSums)
        self._with_loads = None  # (kernel, traced sums, the two as one function)
        #: per view, the function that answered last (reaction_values): (the effects' state
        #: counter and its value then, the effects' list, its length, the kernel with its
        #: loads, the unknowns, whether it reads the kinematics' motion)
        self.last: dict = {}

    def loads(self, effects):
        """The :class:`~mps_core.codegen.reaction_kernels.LoadSums` of a list of effects (made
        again when another list, or a changed one, is given)."""
        cached = self._loads
        if cached is None or cached[0] is not effects or cached[1] != len(effects):
            from ..codegen.reaction_kernels import LoadSums

            cached = self._loads = (effects, len(effects), LoadSums(effects, self.mechanism))
        return cached[2]

    def with_loads(self, kernel, traced):
        """:func:`~mps_core.codegen.reaction_kernels.with_loads` of a kernel and traced load sums,
        kept per pair (the last one asked for first); None for a kernel that is not generated
        code."""
        last = self._with_loads
        if last is not None and last[0] is kernel and last[1] is traced:
            return last[2]
        from ..codegen.reaction_kernels import with_loads

        try:
            fn = with_loads(kernel, traced)
        except (AttributeError, ValueError):
            fn = None
        self._with_loads = (kernel, traced, fn)
        return fn

    def get(self, view, ql, scale, from_kinematics: bool = False):
        """(kernel, unknowns) of a view, built at ``ql`` on first use; None where the view
        has none. ``from_kinematics``: the kernel that reads an exact evaluation's kinematics
        (:func:`~mps_core.codegen.reaction_kernels.reaction_kernel`)."""
        mechanism = self.mechanism
        key = (view, scale, True) if from_kinematics else (view, scale)
        entry = self.views.get(key, False)
        if entry is False:
            from ..codegen.reaction_kernels import reaction_kernel

            joints = active_joints(mechanism, view.frozen)
            q = np.array(ql, float)
            try:
                motion = body_motion(mechanism, view, q, np.zeros_like(q))
                system = _System(mechanism, motion, joints, None)
                k = reaction_kernel(
                    self.engine, view, q, system, motion, tuple(REACTION_COLUMNS), scale, from_kinematics
                )
            except (ArithmeticError, ValueError):
                return None  # outside the chart here: built at a later state
            unknowns = tuple(c for j in joints for c in j.columns)
            entry = self.views[key] = None if k is None else (k, unknowns)
        return entry


def kernels_of(mechanism: Mechanism) -> _Kernels:
    """The mechanism's reaction kernels (kept with it)."""
    ks = mechanism.__dict__.get("_reaction_kernels")
    if ks is None:
        ks = _Kernels(mechanism)
        object.__setattr__(mechanism, "_reaction_kernels", ks)
    return ks


def array_reactions(mechanism: Mechanism, view: ChartView, q, columns=None):
    """The reactions of many states of ``view`` in one call, or None where the view has no
    reaction kernel: the view's reaction kernel (built at ``q``, the bodies' masses and
    inertias an argument) run on arrays (:mod:`mps_core.codegen.array_kernels`):
    ``fn(q…, q̇…, q̈…, masses, loads) -> (values, residual)``, each an array a state (or a
    float the same for all), ``values`` in :data:`REACTION_COLUMNS` order, ``masses`` the
    bodies' masses then their inertias and ``loads`` as
    :class:`~mps_core.codegen.reaction_kernels.LoadSums` gives them. A state where the kernel
    does not hold (a pivot below its guard: a singular position) raises
    :class:`~mps_core.codegen.array_kernels.ArrayBranchChanged`. ``columns``: the
    :data:`REACTION_COLUMNS` the caller reads (None: all); the others' values are None, the
    residual is None, and nothing is computed for them alone."""
    from ..codegen.array_kernels import array_kernel
    from ..codegen.reaction_kernels import reaction_kernel

    ks = kernels_of(mechanism)
    q = np.array(q, float)
    try:
        motion = body_motion(mechanism, view, q, np.zeros_like(q))
        system = _System(mechanism, motion, active_joints(mechanism, view.frozen), None)
        kernel = reaction_kernel(
            ks.engine, view, q, system, motion, tuple(REACTION_COLUMNS), ks.scale, masses=True
        )
    except (ArithmeticError, ValueError):
        return None
    if kernel is None:
        return None
    if columns is None:
        return array_kernel(kernel)
    unread = tuple((0, j) for j, c in enumerate(REACTION_COLUMNS) if c not in columns)
    return array_kernel(kernel, drop=(*unread, 1))


def _last_that_holds(ks, view: ChartView, effects, moving: bool):
    """The entry of the function that last answered ``view`` (:func:`reaction_values`), where it
    still holds: the same effects, unchanged since, and the same kind of kinematics; else None."""
    last = ks.last.get(view)
    if (
        last is not None
        and last[0][0] == last[1]
        and last[2] is effects
        and last[3] == len(effects)
        and last[6] is moving
    ):
        return last
    return None


def reaction_values(
    mechanism: Mechanism,
    effects,
    view: ChartView,
    t: float,
    ql,
    vl,
    al,
    kin: Kinematics,
    scale: float | None = None,
):
    """The reactions at (t, q, q̇, q̈) by the view's reaction kernel
    (:mod:`mps_core.codegen.reaction_kernels`), all on floats: ``(values, residual, unknowns)`` with
    ``values`` in :data:`REACTION_COLUMNS` order; None where the general path must answer (no
    kernel for this view, or a singular position). ``kin`` gives the effects' loads, as in
    :func:`compute_reactions`."""
    ks = mechanism.__dict__.get("_reaction_kernels") or kernels_of(mechanism)
    xl, jl, wl = kin._xl, kin._jl, kin._wl
    lists = xl is not None and jl is not None and wl is not None
    # an exact kernel's kinematics carry the bodies' motion at q̈ = 0 (cv): the kernel that
    # reads it, instead of running the position function forward again
    cv = kin._conv
    moving = lists and cv is not None and len(cv) == 3 * len(mechanism.bodies)
    if lists and scale is None:
        # the view's last function that held, for the same effects in the same state:
        # straight to it (the lookups below made it)
        last = _last_that_holds(ks, view, effects, moving)
        if last is not None:
            try:
                v = kin._vl if kin._vl is not None else kin._v()
                values, residual = (
                    last[4](t, *ql, *vl, *al, xl, jl, wl, cv, v)
                    if moving
                    else last[4](t, *ql, *vl, *al, xl, jl, wl, v)
                )
                return values, residual, last[5]
            except _FALLBACKS:
                pass
    entry = ks.get(view, ql, ks.scale if scale is None else float(scale), moving)
    if entry is None:
        return None
    kernel, unknowns = entry
    sums = ks.loads(effects)
    if lists:
        traced = sums.first(kin.n)
        both = ks.with_loads(kernel, traced) if traced is not None else None
        if both is not None:
            # the load sums and the kernel as one function; where it raises, the two below
            # say which part failed (a branch of a force law, or the kernel's own fallback)
            try:
                v = kin._vl if kin._vl is not None else kin._v()
                values, residual = (
                    both(t, *ql, *vl, *al, xl, jl, wl, cv, v)
                    if moving
                    else both(t, *ql, *vl, *al, xl, jl, wl, v)
                )
                if scale is None:
                    ks.last[view] = (
                        sums.version,
                        sums.version[0],
                        effects,
                        len(effects),
                        both,
                        unknowns,
                        moving,
                    )
                return values, residual, unknowns
            except _FALLBACKS:
                pass
    try:
        values, residual = (
            kernel(*ql, *vl, *al, xl, jl, wl, cv, sums(t, kin))
            if moving
            else kernel(*ql, *vl, *al, sums(t, kin))
        )
    except _FALLBACKS:
        return None
    return values, residual, unknowns


def compute_reactions(
    mechanism: Mechanism,
    effects,
    view: ChartView,
    t: float,
    q,
    qd,
    qdd,
    *,
    kin: Kinematics | None = None,
    drive: str | None = None,
    scale: float | None = None,
    kernel: bool = True,
) -> Reactions:
    """Joint reactions, motor torque, foundation load and checks at (t, q, q̇, q̈) in ``view``.

    ``effects`` are the scene's effects, already bound to ``mechanism``; their loads are taken
    with ``kin`` (pass the engine's evaluation's kinematics to use exactly the loads the step
    used; by default exact kinematics from jets). ``drive``: a body that receives an unknown
    driving torque from the frame (kinetostatics of a prescribed motion: give q̈ and get the
    torque that makes it); it is added to ``M_motor``. Unknown joints follow ``view.frozen``.

    With ``kin`` given and no ``drive``, the view's reaction kernel answers where it holds
    (:func:`reaction_values`; ``kernel=False``: never); the general path below is the
    reference, and answers everywhere else.
    """
    if kernel and kin is not None and drive is None:
        fast = reaction_values(
            mechanism,
            effects,
            view,
            t,
            [float(x) for x in q],
            [float(x) for x in qd],
            [float(x) for x in qdd],
            kin,
            scale,
        )
        if fast is not None:
            values, residual, unknowns = fast
            return Reactions(
                float(t), dict(zip(REACTION_COLUMNS, values)), np.array(residual), unknowns, len(unknowns)
            )
    return _least_squares(mechanism, effects, view, t, q, qd, qdd, kin, drive, scale)


def _least_squares(mechanism, effects, view, t, q, qd, qdd, kin, drive, scale) -> Reactions:
    """:func:`compute_reactions`' general path: the joints' unknowns by least squares over the
    bodies' equations of motion, the frame's share, the foundation load and the checks."""
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    qdd = np.asarray(qdd, dtype=float)
    motion = body_motion(mechanism, view, q, qd)
    if kin is None:
        kin = motion.kinematics(t, q, qd)
    joints = active_joints(mechanism, view.frozen)
    sysm = _System(mechanism, motion, joints, drive)
    rows = motion.com_rows(mechanism)
    aG = motion.J[rows] @ qdd + motion.D2[rows]  # (nb, 2)
    alpha = motion.W @ qdd + motion.theta2  # (nb,)
    mass = np.array([b.mass for b in mechanism.bodies])
    inertia = np.array([b.inertia for b in mechanism.bodies])
    G = sysm.G
    ext, ext_M_O, frame_F, frame_M, m_motor = _external(mechanism, effects, t, kin, motion, G)
    b = np.empty(3 * len(mass))
    b[0::3] = mass * aG[:, 0] - ext[:, 0]
    b[1::3] = mass * aG[:, 1] - ext[:, 1]
    b[2::3] = inertia * alpha - ext[:, 2]
    u, r, rank = sysm.solve(b, scale if scale is not None else length_scale(mechanism))
    values = dict.fromkeys(REACTION_COLUMNS, 0.0)
    # what the frame receives from the moving links through the joints
    R_F, R_M, drive_solved = _frame_share(sysm, u, motion, values)
    m_motor += drive_solved
    R_M -= drive_solved
    values["M_motor"] = float(m_motor)
    F_found = R_F + frame_F
    values["F_found_x"], values["F_found_y"] = float(F_found[0]), float(F_found[1])
    values["M_found_O"] = float(R_M + frame_M)
    values["residual_force_N"] = float(np.linalg.norm(np.concatenate([r[0::3], r[1::3]])))
    values["residual_moment_Nm"] = float(np.linalg.norm(r[2::3]))
    # balance of the whole moving system, from its own momentum (not from the solve's rows)
    p_dot = (mass[:, None] * aG).sum(axis=0)
    bal_F = p_dot - (ext[:, :2].sum(axis=0) - R_F)
    g = G - sysm.origin
    h_dot = float(np.sum(g[:, 0] * mass * aG[:, 1] - g[:, 1] * mass * aG[:, 0]) + inertia @ alpha)
    bal_M = h_dot - (ext_M_O - R_M)
    values["balance_residual_N"] = float(np.linalg.norm(bal_F))
    values["balance_residual_Nm"] = float(abs(bal_M))
    return Reactions(float(t), values, r, tuple(c for _, _, c in sysm.cols), rank)


# -- impacts --------------------------------------------------------------------------------
def plastic_impact(A: np.ndarray, qd_minus, g) -> tuple[np.ndarray, float]:
    """Perfectly plastic impact on a constraint with gradient g (contract §5).

    Returns ``(q̇⁺, λ)`` with ``q̇⁺ = q̇⁻ − A⁻¹g·λ``, ``λ = (gᵀq̇⁻)/(gᵀA⁻¹g)``: the generalized
    impulse is −g·λ and gᵀq̇⁺ = 0.
    """
    qd_minus = np.asarray(qd_minus, dtype=float)
    g = np.asarray(g, dtype=float)
    Ainv_g = np.linalg.solve(A, g)
    lam = float(g @ qd_minus) / float(g @ Ainv_g)
    return qd_minus - Ainv_g * lam, lam


@dataclass
class Impulses:
    """Joint impulses (N·s, N·m·s for moments) of an impact, keyed like the reaction columns
    (``F_O_x`` is the impulse of F_O's x component, same receiving body and sign); the
    foundation's impulse as ``F_found_x``, ``F_found_y``, ``M_found_O``; ``momentum_jump``:
    per body (Δp_x, Δp_y, ΔL about its centre of mass); ``residual`` as :class:`Reactions`;
    ``energy_loss`` (J): the kinetic energy lost, T(q̇⁻) − T(q̇⁺). An impact is instantaneous:
    its duration is 0."""

    t: float
    values: dict
    momentum_jump: dict
    residual: np.ndarray
    unknowns: tuple
    rank: int
    energy_loss: float = math.nan

    def as_event(self, kind: str = "impulse", **extra) -> dict:
        ev = {
            "t": self.t,
            "kind": kind,
            "impulses_Ns": {
                k: v
                for k, v in self.values.items()
                if k in self.unknowns or k.startswith(("F_found", "M_found"))
            },
            "energy_loss_J": self.energy_loss,
            "duration_s": 0.0,
        }
        ev.update(extra)
        return ev


def impulses(
    mechanism: Mechanism,
    view: ChartView,
    q,
    qd_minus,
    qd_plus,
    *,
    closing: Iterable[str] = (),
    t: float = math.nan,
    scale: float | None = None,
) -> Impulses:
    """Per-joint impulses of a velocity jump q̇⁻ → q̇⁺ at configuration q (in ``view``).

    The Newton–Euler system of :func:`compute_reactions` with the bodies' momentum jumps
    ``m Δv_G`` and ``J Δω`` in place of m·a and J·α, and no finite forces (they give no impulse
    in an instant). ``closing`` names the coordinates the impact freezes (``"psi"`` for the
    latch, ``"x_C"`` for the top stop): their joints join the unknowns even though ``view``
    (the state before the impact) does not freeze them yet.
    """
    q = np.asarray(q, dtype=float)
    qd_minus = np.asarray(qd_minus, dtype=float)
    qd_plus = np.asarray(qd_plus, dtype=float)
    dqd = qd_plus - qd_minus
    motion = body_motion(mechanism, view, q, np.zeros_like(q))
    joints = active_joints(mechanism, set(view.frozen) | set(closing))
    sysm = _System(mechanism, motion, joints, None)
    rows = motion.com_rows(mechanism)
    dv = motion.J[rows] @ dqd
    dw = motion.W @ dqd
    mass = np.array([b.mass for b in mechanism.bodies])
    inertia = np.array([b.inertia for b in mechanism.bodies])
    b = np.empty(3 * len(mass))
    b[0::3] = mass * dv[:, 0]
    b[1::3] = mass * dv[:, 1]
    b[2::3] = inertia * dw
    u, r, rank = sysm.solve(b, scale if scale is not None else length_scale(mechanism))
    values = {c: 0.0 for c in _JOINT_COLUMNS}
    R_F, R_M, _ = _frame_share(sysm, u, motion, values)
    values["F_found_x"], values["F_found_y"], values["M_found_O"] = (float(R_F[0]), float(R_F[1]), float(R_M))
    jumps = {
        bd.name: (float(mass[k] * dv[k, 0]), float(mass[k] * dv[k, 1]), float(inertia[k] * dw[k]))
        for k, bd in enumerate(mechanism.bodies)
    }
    JG = motion.J[rows]
    A = np.einsum("b,bki,bkj->ij", mass, JG, JG) + np.einsum("b,bi,bj->ij", inertia, motion.W, motion.W)
    loss = 0.5 * float(qd_minus @ A @ qd_minus - qd_plus @ A @ qd_plus)
    return Impulses(float(t), values, jumps, r, tuple(c for _, _, c in sysm.cols), rank, loss)


__all__ = [
    "FRAME",
    "Joint",
    "PRESS_JOINTS",
    "REACTION_COLUMNS",
    "DESCRIPTIONS",
    "BodyMotion",
    "body_motion",
    "active_joints",
    "length_scale",
    "Reactions",
    "compute_reactions",
    "array_reactions",
    "plastic_impact",
    "Impulses",
    "impulses",
]
