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

The columns are named in :mod:`.reaction_columns`, the system is built and solved in
:mod:`.newton_euler`, an impact's impulses taken in :mod:`.impulses`; here: the reactions at a
state, by a generated kernel where one holds and by the general path everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..codegen.reaction_kernels import Fallback
from ..derivatives.tracing import BranchChanged
from ..model.mechanism import FRAME, ChartView, Joint, Mechanism
from ..model.press import PRESS_JOINTS
from .engine import Kinematics
from .impulses import Impulses, impulses, plastic_impact
from .newton_euler import (
    BodyMotion,
    System,
    active_joints,
    body_motion,
    external_loads,
    frame_share,
    length_scale,
)
from .reaction_columns import DESCRIPTIONS, REACTION_COLUMNS

#: what a reaction kernel raises where the general path must answer
_FALLBACKS = (Fallback, BranchChanged, ArithmeticError, ValueError)


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
        """The :class:`~mps_core.codegen.load_sums.LoadSums` of a list of effects (made
        again when another list, or a changed one, is given)."""
        cached = self._loads
        if cached is None or cached[0] is not effects or cached[1] != len(effects):
            from ..codegen.load_sums import LoadSums

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
                system = System(mechanism, motion, joints, None)
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
    :class:`~mps_core.codegen.load_sums.LoadSums` gives them. A state where the kernel
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
        system = System(mechanism, motion, active_joints(mechanism, view.frozen), None)
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
    sysm = System(mechanism, motion, joints, drive)
    rows = motion.com_rows(mechanism)
    aG = motion.J[rows] @ qdd + motion.D2[rows]  # (nb, 2)
    alpha = motion.W @ qdd + motion.theta2  # (nb,)
    mass = np.array([b.mass for b in mechanism.bodies])
    inertia = np.array([b.inertia for b in mechanism.bodies])
    G = sysm.G
    ext, ext_M_O, frame_F, frame_M, m_motor = external_loads(mechanism, effects, t, kin, motion, G)
    b = np.empty(3 * len(mass))
    b[0::3] = mass * aG[:, 0] - ext[:, 0]
    b[1::3] = mass * aG[:, 1] - ext[:, 1]
    b[2::3] = inertia * alpha - ext[:, 2]
    u, r, rank = sysm.solve(b, scale if scale is not None else length_scale(mechanism))
    values = dict.fromkeys(REACTION_COLUMNS, 0.0)
    # what the frame receives from the moving links through the joints
    R_F, R_M, drive_solved = frame_share(sysm, u, motion, values)
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
