"""Each stroke's cut fitted whole: the part's force curve from the crank angles over the cut.

The filter's process force is a random walk (:mod:`~mps_core.track.tracker`): it follows the
force's impulse step by step, and where the part's force lasts two samples its largest step
value overshoots the peak (docs/tracking.md). The part's force has a shape, though: the blanking
law the model itself runs (:mod:`mps_core.model.effects.blanking`), F = F_max·sin(π·p/p_b) with
the punch's penetration p = x_0 − x_C, from its contact x_0 to its breakthrough at depth p_b,
while the slider moves down. Once a cut is over (the work window closed: the slider turned at
the bottom), its three numbers are fitted to the crank angles measured over the window:

* the model's run from the filtered state before the window (its covariance the prior of the
  start), the load torque held constant over the window (the filter's estimate its prior), the
  force the law's at the middle of each substep (0.1 ms inside the part, 0.25 ms elsewhere: the
  run's own error at the window's end then 0.4 of an encoder count against 0.05 ms steps, where
  1 ms steps are 4.5 counts off);
* a Levenberg–Marquardt search over (δq₀, δq̇₀, τ_b) and the curve's work, middle and depth
  (W = 2·F_max·p_b/π, x_0 − p_b/2, p_b: better conditioned than F_max, x_0, p_b), each trial one
  run; the angles' derivatives in the parameters carried along the same run, linearised: the
  mechanism's and the motor's own slopes (∂q̈/∂q, ∂q̈/∂q̇ every millisecond: the motor damps a
  change of the crank's rate within some 4 ms) and the part's stiffness (∂F/∂x_C), within a few
  per cent of differences of whole runs, for one run instead of seven;
* the peak's 1-σ from the fit's covariance, widened by √(χ²/dof) where the residuals are larger
  than the measurements' noise (the model's own error: the press is not the model).

A crank-slider only (one coordinate: the latch closed); the fit of a cut that does not converge,
or has too few angles, is not given (None) and the stroke keeps the filter's peak. A fit is
made from plain values (:class:`CutJob`) on a model of its own (:class:`CutFitter`), never the
filter's run: the same numbers in the tracker's process or in another (a node's fitting
process, :mod:`~mps_core.track.fit_process`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..dynamics.reactions import compute_reactions
from ..errors import MpsError
from .nominal_model import NominalModel
from .settings import TrackSettings

if TYPE_CHECKING:
    from ..scene import Scene

__all__ = ["CutFit", "CutFitter", "CutJob", "CutStart", "part_guess"]

#: the substep inside the part (s) and elsewhere in the window
PART_STEP = 1e-4
WINDOW_STEP = 2.5e-4
#: how often the mechanism's own slopes (∂q̈/∂q, ∂q̈/∂q̇) are taken again over a run (s)
SLOPE_EVERY = 1e-3
#: the most trial runs a fit may take
MAX_RUNS = 16
#: fewest crank angles over a cut for a fit (six parameters, three of them with priors)
MIN_SAMPLES = 8


@dataclass(frozen=True)
class CutStart:
    """Where a cut's fit starts: the last state filtered before the work window.

    Plain values (a fit may run in another process): its time on the tracker's clock, the
    structure, chart view (by name) and controls of the tracker's run then
    (:meth:`~mps_core.track.nominal_model.NominalModel.controls_of`), the filtered (q, q̇) and
    their covariance, the load torque and its variance.
    """

    t: float
    structure: str
    chart: str
    controls: dict
    q: float
    qd: float
    covariance: np.ndarray
    torque: float
    torque_variance: float


@dataclass(frozen=True)
class CutJob:
    """A cut to fit.

    Where it starts, its crank angles (t, angle, variance) on the tracker's clock, the curve
    (F_max, x_0, p_b) the search begins at, scaled to ``work`` (J) where given, the load torque
    the start's plus ``torque_offset``; the stroke it belongs to and its number among the
    tracker's cuts (``serial``).
    """

    start: CutStart
    samples: tuple
    guess: tuple[float, float, float]
    work: float | None
    torque_offset: float
    stroke: int
    serial: int


@dataclass(frozen=True)
class CutFit:
    """A cut's fitted force curve (SI units), each figure with its 1-σ."""

    peak_force: float
    peak_force_sigma: float
    #: the model's time (the tracker's clock) where the fitted force peaks
    t_peak: float
    contact: float
    contact_sigma: float
    depth: float
    depth_sigma: float
    #: the fitted curve's work over the cut (J)
    work: float
    #: the foundation force's largest magnitude over the fitted run (N), its 1-σ
    peak_foundation: float
    peak_foundation_sigma: float
    #: the load torque fitted over the cut less the filter's at its start (N·m)
    torque_offset: float
    chi2: float
    dof: int
    runs: int
    #: the fitted curve (F_max, x_0, p_b): the next cut's search begins there
    curve: tuple[float, float, float]


def part_guess(effect_params: list[dict]) -> tuple[float, float, float] | None:
    """Return (F_max, x_0, p_b) of the scene's blanking law (its first), None where it has none."""
    for p in effect_params:
        return float(p["peak_force"]), float(p["x_contact"]), float(p["breakthrough"]) * float(p["thickness"])
    return None


def _law(theta: np.ndarray | list, x: float) -> tuple[float, float, float, float]:
    """Return F and its derivatives in (F_max, x_0, p_b) at slider position x (moving down)."""
    f_max, x0, pb = theta
    p = x0 - x
    if p <= 0.0 or p >= pb:
        return 0.0, 0.0, 0.0, 0.0
    u = math.pi * p / pb
    s, c = math.sin(u), math.cos(u)
    return f_max * s, s, f_max * c * math.pi / pb, -f_max * c * u / pb


class _Runner:
    """The model's run over a cut at given parameters.

    It gives the angles at the samples' times and their derivatives in the parameters.
    """

    def __init__(self, model: NominalModel, start: CutStart, times: list[float]) -> None:
        self.model, self.start, self.times = model, start, times
        view = model.view(start.structure, start.chart)
        #: the run made once at the start, and its checkpoint there: each trial comes back to it
        #: (a few µs, where making the run again took half a millisecond)
        self.sim = model.new_run(
            (view, np.array([start.q]), np.array([start.qd])), start.t, start.structure, start.controls
        )
        self._at_start = self.sim.checkpoint()
        self.runs = 0

    def __call__(self, p: np.ndarray, loads: bool = False) -> tuple[np.ndarray, np.ndarray, dict]:
        """Return the angles at the samples' times, their derivatives in ``p``, what the run met.

        What it met: the force's peak, the work, the lowest slider; with ``loads`` the
        foundation force's largest magnitude inside the part and its change per newton of
        process force there (over the whole window of `working`'s cuts the same peaks).
        """
        model, st = self.model, self.start
        inputs = model.inputs
        self.runs += 1
        dq, dqd, tau = float(p[0]), float(p[1]), float(p[2])
        theta = p[3:6]
        x0, pb = float(theta[1]), float(theta[2])
        inputs.set(0.0, tau)
        sim = self.sim
        sim.restore(self._at_start)
        sim.restart_at(np.array([st.q + dq]), np.array([st.qd + dqd]))
        force = 0.0
        # q's and q̇'s derivatives in the parameters, carried substep by substep (floats: six
        # columns are cheaper by hand than as arrays)
        s_q = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        s_v = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0]
        t_slopes, slope_q, slope_v = -math.inf, 0.0, 0.0
        phi = np.empty(len(self.times))
        rows = np.zeros((len(self.times), 6))
        info = {"peak": 0.0, "t_peak": math.nan, "work": 0.0, "x_min": math.inf}
        for k, tk in enumerate(self.times):
            while sim.t < tk - 1e-12:
                e = sim.solver.current
                kin = e.kin
                x, v = float(kin.xy("C")[0]), float(kin.vxy("C")[0])
                h = min(tk - sim.t, WINDOW_STEP)
                if v < 0.0 and x + v * h < x0 and x > x0 - pb:
                    if x > x0:  # to the contact first
                        h = min(h, max((x - x0) / -v, 1e-7))
                    else:
                        h = min(h, PART_STEP)
                    f, d_max, d_x0, d_pb = _law(theta, x + 0.5 * v * h)
                else:
                    f = d_max = d_x0 = d_pb = 0.0
                if f != force:
                    inputs.set(f, tau)
                    sim.restart_at(e.q, e.qd)
                    e = sim.solver.current
                    kin = e.kin
                    force = f
                if e.t - t_slopes >= SLOPE_EVERY:
                    t_slopes = e.t
                    slope_q, slope_v = _slopes(sim.engine.accelerations, e)
                jac_x = float(kin.jac("C")[0][0])
                a_inv = 1.0 / float(e.A[0, 0])
                unit_f = jac_x * a_inv  # q̈ per unit process force
                unit_tau = float(kin.omega("crank")[0]) * a_inv  # and per unit load torque
                forcing = (0.0, 0.0, unit_tau, unit_f * d_max, unit_f * d_x0, unit_f * d_pb)
                # δq̈ = a_q·δq + a_v·δq̇ + forcing, taken at the substep's middle; a_q has the
                # force's own change with the slider's position (∂F/∂x = −∂F/∂x₀): the part's
                # stiffness on the crank
                a_q = slope_q - unit_f * d_x0 * jac_x
                a_v = slope_v
                hh = 0.5 * h
                for j in range(6):
                    sq, sv, fj = s_q[j], s_v[j], forcing[j]
                    a0 = a_q * sq + a_v * sv + fj
                    acc = a_q * (sq + hh * sv) + a_v * (sv + hh * a0) + fj
                    s_q[j] = sq + h * sv + hh * h * acc
                    s_v[j] = sv + h * acc
                if f > info["peak"]:
                    info["peak"], info["t_peak"] = f, sim.t + hh
                if loads and f:  # the foundation's peak is where the part's force is (measured)
                    _foundation(model, sim, e, f, tau, unit_f, info)
                sim.advance_to(sim.t + h)
                x1 = float(sim.solver.current.kin.xy("C")[0])
                if x1 < info["x_min"]:
                    info["x_min"] = x1
                if f:
                    info["work"] -= f * (x1 - x)
            phi[k] = sim.joint_state()[0]
            rows[k] = s_q
            rows[k] *= float(sim.solver.current.kin.omega("crank")[0])
        return phi, rows, info


def _foundation(
    model: NominalModel, sim: Any, e: Any, force: float, tau: float, unit_f: float, info: dict
) -> None:
    """Keep the foundation force's magnitude at evaluation ``e`` where it is the largest so far.

    In ``info``: ``found``, and its change per newton of process force there, ``found_per_N``
    (the loads are affine in it, q̈ moving by ``unit_f`` a newton).
    """
    effects = sim.engine.effects
    rx = compute_reactions(model.mechanism, effects, e.view, e.t, e.q, e.qd, e.qdd, kin=e.kin).values
    fx, fy = rx["F_found_x"], rx["F_found_y"]
    magnitude = math.hypot(fx, fy)
    if magnitude <= info.get("found", -1.0):
        return
    model.inputs.set(force + 1.0, tau)
    try:
        qdd = np.asarray(e.qdd, dtype=float) + unit_f
        r1 = compute_reactions(model.mechanism, effects, e.view, e.t, e.q, e.qd, qdd, kin=e.kin).values
    finally:
        model.inputs.set(force, tau)
    per_n = ((r1["F_found_x"] - fx) * fx + (r1["F_found_y"] - fy) * fy) / magnitude if magnitude else 0.0
    info["found"], info["found_per_N"] = magnitude, per_n


def _slopes(accelerations: Any, e: Any) -> tuple[float, float]:
    """Return ∂q̈/∂q and ∂q̈/∂q̇ at evaluation ``e`` (one coordinate).

    Forward differences, the unknown inputs held: the mechanism's and the motor's own slopes,
    which damp a change of the crank's rate within milliseconds.
    """
    q, qd, base = float(e.q[0]), float(e.qd[0]), float(e.qdd[0])
    hq, hv = 1e-6 * (1.0 + abs(q)), 1e-5 * (1.0 + abs(qd))
    dq = (float(accelerations(e.view, e.t, [q + hq], [qd])[0]) - base) / hq
    dv = (float(accelerations(e.view, e.t, [q], [qd + hv])[0]) - base) / hv
    return dq, dv


def _curve(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (F_max, x_0, p_b) from the search's (W, x_mid, p_b) and the map T between their derivatives.

    The search goes along the curve's work W = 2·F_max·p_b/π and middle x_mid = x_0 − p_b/2,
    which the crank tells well, and its depth p_b, which it tells less (F_max and p_b alone
    trade against each other along a curved valley).
    """
    work, x_mid, pb = float(p[3]), float(p[4]), float(p[5])
    f_max = 0.5 * math.pi * work / pb
    T = np.array([[0.5 * math.pi / pb, 0.0, -f_max / pb], [0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])
    return np.array([f_max, x_mid + 0.5 * pb, pb]), T


class CutFitter:
    """Fit cuts on a nominal press's model of its own (:class:`NominalModel`).

    Each fit from plain values (:class:`CutJob`), each trial a new run, so that a fit here and
    one in another process made from the same scene give the same numbers.
    """

    def __init__(self, scene: Scene, settings: TrackSettings) -> None:
        self.model = NominalModel(scene, settings)

    def fit(self, job: CutJob) -> CutFit | None:
        """Fit the cut ``job`` (:func:`fit_cut`)."""
        return fit_cut(self.model, job.start, job.samples, job.guess, job.work, job.torque_offset)


def fit_cut(
    model: NominalModel,
    start: CutStart,
    samples: tuple[tuple[float, float, float], ...],
    guess: tuple[float, float, float],
    work: float | None = None,
    torque_offset: float = 0.0,
) -> CutFit | None:
    """Fit the part's force curve to a cut's crank angles; None where it does not converge.

    ``samples``: (t, angle, variance) on the run's clock, from ``start`` (None where fewer
    than :data:`MIN_SAMPLES`). The search begins at the curve ``guess`` (F_max, x_0, p_b)
    scaled to ``work`` (J: the filter's, where given), the load torque the start's plus
    ``torque_offset`` (the last fit's off its start's: what the model misses over a cut). Each
    trial is a run of ``model`` from the start.
    """
    if len(samples) < MIN_SAMPLES or start.covariance.shape != (2, 2):
        return None
    times = [s[0] for s in samples]
    z = np.array([s[1] for s in samples])
    sigma = np.sqrt([s[2] for s in samples])
    try:
        prior = np.linalg.cholesky(np.linalg.inv(start.covariance))  # Pinv = L·Lᵀ
    except np.linalg.LinAlgError:
        return None
    tau_sd = math.sqrt(max(start.torque_variance, 1e-6))
    run = _Runner(model, start, times)
    m = len(z)

    def residuals(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
        theta, T = _curve(p)
        phi, rows, info = run(np.concatenate([p[:3], theta]))
        zz = z + 2.0 * math.pi * np.round((phi - z) / (2.0 * math.pi))  # the encoder's turn
        r = np.concatenate([(zz - phi) / sigma, prior.T @ p[:2], [(p[2] - start.torque) / tau_sd]])
        J = np.zeros((len(r), 6))
        J[:m, :3] = -rows[:, :3] / sigma[:, None]
        J[:m, 3:] = -(rows[:, 3:] @ T) / sigma[:, None]
        J[m : m + 2, :2] = prior.T
        J[-1, 2] = 1.0 / tau_sd
        return r, J, info

    f_max, x0, pb = guess
    w = 2.0 * f_max * pb / math.pi if work is None or not work > 0.0 else float(work)
    p = np.array([0.0, 0.0, start.torque + torque_offset, w, x0 - 0.5 * pb, pb], dtype=float)
    scale = np.array([*np.sqrt(np.diag(start.covariance)), tau_sd, 1.0, 1e-4, 1e-4])
    converged = False
    try:
        r, J, info = residuals(p)
        lam = 1e-2
        while True:
            Js = J * scale
            A = Js.T @ Js
            step = -np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), Js.T @ r) * scale
            # converged where the next step would move each parameter by a twentieth of its 1-σ
            sd = np.sqrt(np.abs(np.diag(np.linalg.pinv(A)))) * scale
            if np.all(np.abs(step) <= 0.05 * sd):
                converged = True
                break
            if run.runs >= MAX_RUNS:
                break
            trial = p + step
            if not (trial[3] > 0.0 and trial[5] > 1e-6):
                lam *= 4.0
                continue
            r1, J1, info1 = residuals(trial)
            if r1 @ r1 <= r @ r:
                p, r, J, info = trial, r1, J1, info1
                lam = max(lam / 3.0, 1e-7)
            else:
                lam *= 4.0
    except (MpsError, ArithmeticError, ValueError, np.linalg.LinAlgError):
        converged = False
    if not converged:
        return None
    dof = len(r) - 6
    chi2 = float(r @ r)
    theta, T = _curve(p)
    try:
        cov = np.linalg.inv(J.T @ J) * max(1.0, chi2 / max(dof, 1))
    except np.linalg.LinAlgError:
        return None
    cov_curve = T @ cov[3:, 3:] @ T.T
    sd = np.sqrt(np.maximum(np.diag(cov_curve), 0.0))
    try:  # the fitted run once more, its foundation force at each substep
        loads = run(np.concatenate([p[:3], theta]), loads=True)[2]
    except (MpsError, ArithmeticError, ValueError):
        loads = {}
    # the peak the punch met: the curve's top, or where the slider turned inside the part
    depth_met = min(float(theta[1] - info["x_min"]) / float(theta[2]), 0.5)
    peak_scale = math.sin(math.pi * depth_met) if depth_met > 0.0 else 0.0
    return CutFit(
        peak_force=float(theta[0] * peak_scale),
        peak_force_sigma=float(sd[0] * peak_scale),
        t_peak=float(info["t_peak"]),
        contact=float(theta[1]),
        contact_sigma=float(sd[1]),
        depth=float(theta[2]),
        depth_sigma=float(sd[2]),
        work=float(info["work"]),
        # the foundation's 1-σ from the peak force's: the state's own share is far smaller
        peak_foundation=float(loads.get("found", math.nan)),
        peak_foundation_sigma=float(abs(loads.get("found_per_N", math.nan)) * sd[0]),
        torque_offset=float(p[2] - start.torque),
        chi2=chi2,
        dof=dof,
        runs=run.runs,
        curve=(float(theta[0]), float(theta[1]), float(theta[2])),
    )
