"""The load reports of a vectorised batch's runs, all at once: each run's figures as
:func:`mps_core.analysis.loads.load_report` gives them (its steady cycle's period, and each
quantity's mean, peak, RMS, dynamic RMS and harmonic amplitudes), to round-off, from the states
a batch keeps (:class:`mps_core.run.batch_states.BatchStates`) rather than from each run's
trajectory.

The method is the report's (:mod:`.loads`), on arrays of all runs:

* the cycle: the last two passages of the crank through φ = 0 (mod 2π), each located on the
  cubic Hermite interpolant of (φ, φ̇) between its steps, by bisection to the last bit (the
  report's :func:`scipy.optimize.brentq` stops within 1e-15 s);
* the joint reactions solved at each run's cycle's steps only (the steps the report's spline
  goes through, three beyond each end);
* the not-a-knot cubic spline through those steps (scipy's :class:`~scipy.interpolate.CubicSpline`
  system, solved a run at a time by LAPACK's tridiagonal solver, every quantity of the run one
  right-hand side), evaluated at each run's N uniform instants of its cycle;
* the discrete Fourier transform of every run and quantity in one call.

A run whose report cannot be made (no full revolution, a cycle outside its steps) gets the
report's own error, as :func:`~mps_core.analysis.loads.load_report` raises it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import loads
from .loads import N_HARMONICS, QUANTITIES, TWO_PI, LoadReportError

#: runs a block of the resampling and the transform takes (its arrays: about 20 MB each)
BLOCK = 128


@dataclass(frozen=True)
class RunFigures:
    """One run's figures: its cycle's ``period`` (s), the ``names`` of the quantities its
    report has (:data:`~mps_core.analysis.loads.QUANTITIES` order, those not zero over the
    cycle), and ``values`` (quantity, 4 + n): mean, peak, RMS, dynamic RMS, A_1…A_n."""

    period: float
    names: tuple[str, ...]
    values: np.ndarray


@dataclass
class _Cycles:
    """The runs' cycles, one value a run: t0, the period, the change of the period from the
    revolution before (NaN: none), the steps i0 … i1 that bracket it; ``errors`` the runs
    that have none (run: its error)."""

    t0: np.ndarray
    period: np.ndarray
    change: np.ndarray
    i0: np.ndarray
    i1: np.ndarray
    errors: dict


def batch_figures(states, mode: str | None = "locked", n: int = N_HARMONICS) -> list:
    """Each run's :class:`RunFigures` (or its :class:`~mps_core.analysis.loads.LoadReportError`)
    over its last full crank revolution, from a batch's ``states``
    (:class:`~mps_core.run.batch_states.BatchStates`), in the batch's order. Raises
    :class:`~mps_core.run.batch_record.ReactionsNotSolved` as the batch's reactions do, and
    ``ValueError`` where the batch is not one this computes (its structure not ``mode``, a
    crank frozen)."""
    if mode is not None and states.structure != mode:
        raise ValueError(f"the batch runs in the {states.structure!r} structure, not {mode!r}")
    t = states.t[: states.k]
    phi = states.coordinate("phi")
    phi_dot = states.coordinate("phi", 1)
    if phi is None or phi_dot is None:
        raise ValueError("the batch's crank angle is frozen")
    phi = np.ascontiguousarray(phi.T)  # (run, step)
    phi_dot = np.ascontiguousarray(phi_dot.T)
    cyc = cycles(t, phi, phi_dot, mode)
    m, S = phi.shape
    out: list = [None] * m
    for r, err in cyc.errors.items():
        out[r] = err
    ok = np.array([r not in cyc.errors for r in range(m)])
    if not ok.any():
        return out
    steps = cyc.i1 - cyc.i0
    N = np.maximum(64, 2 ** np.ceil(np.log2(np.maximum(steps, 2 * n + 2))).astype(int))
    start = np.maximum(cyc.i0 - 3, 0)
    length = np.minimum(cyc.i1 + 4, S) - start
    # the runs in blocks of one N, each block's runs of alike lengths (least padding)
    order = [r for r in np.lexsort((length, N)) if ok[r]]
    blocks: list[list[int]] = []
    for r in order:
        if blocks and len(blocks[-1]) < BLOCK and N[blocks[-1][0]] == N[r]:
            blocks[-1].append(r)
        else:
            blocks.append([r])
    for block in blocks:
        rows = np.array(block)
        L = int(length[rows].max())
        at = np.minimum(start[rows, None] + np.arange(L), S - 1)  # (run, j)
        reactions = states.reactions(at, rows)
        for r, res in zip(block, _block(t, at, length[rows], reactions, cyc, rows, int(N[block[0]]), n)):
            out[r] = res
    return out


def cycles(t, phi, phi_dot, mode: str | None = "locked") -> _Cycles:
    """The last full crank revolution of each run: ``phi`` and ``phi_dot`` (run, step) at the
    steps' times ``t``, every step in the structure ``mode``."""
    m, S = phi.shape
    turns = np.floor(phi / TWO_PI + 1e-12)
    run, step = np.nonzero(turns[:, 1:] != turns[:, :-1])  # the steps after which φ passes 2πk
    count = np.bincount(run, minlength=m)
    end = np.cumsum(count)
    cross = np.full((m, 3), np.nan)  # the last three passages' times, the last first
    for j in range(3):
        has = count > j
        i = step[end[has] - 1 - j]
        r = np.nonzero(has)[0]
        cross[has, j] = _passage(t, phi[r], phi_dot[r], turns[r], i)
    errors = {}
    for k in np.nonzero(count < 2)[0].tolist():
        try:  # the report's own message
            loads.last_cycle(t, phi[k], phi_dot[k], None, mode)
        except LoadReportError as exc:
            errors[k] = exc
        else:  # cannot be: the report found two passages where these are fewer
            errors[k] = LoadReportError("no full crank revolution")
    t0, t1 = cross[:, 1], cross[:, 0]
    period = t1 - t0
    with np.errstate(invalid="ignore"):
        change = np.abs(period - (cross[:, 1] - cross[:, 2])) / period
        i0 = np.searchsorted(t, np.nan_to_num(t0), side="right") - 1
        i1 = np.searchsorted(t, np.nan_to_num(t1), side="left")
    return _Cycles(t0, period, change, np.maximum(i0, 0), np.minimum(i1, S - 1), errors)


def _passage(t, phi, phi_dot, turns, i):
    """The times at which φ passes its multiple of 2π between steps ``i`` and ``i + 1`` (one
    a run of ``phi``, ``phi_dot``, ``turns``): the report's rule (:func:`loads._crossings`)
    with bisection on the cubic Hermite interpolant, to the last bit."""
    r = np.arange(len(i))
    ta, tb = t[i], t[i + 1]
    level = TWO_PI * np.maximum(turns[r, i], turns[r, i + 1])
    f = loads.hermite_minus(ta, tb, phi[r, i], phi[r, i + 1], phi_dot[r, i], phi_dot[r, i + 1], level)

    fa, fb = f(ta), f(tb)
    a, b = ta.copy(), tb.copy()
    fl = fa.copy()
    for _ in range(200):
        mid = 0.5 * (a + b)
        moving = (mid != a) & (mid != b)
        if not moving.any():
            break
        fm = f(mid)
        left = np.signbit(fm) == np.signbit(fl)
        a = np.where(left & moving, mid, a)
        fl = np.where(left & moving, fm, fl)
        b = np.where(~left & moving, mid, b)
    root = np.where(np.abs(f(a)) <= np.abs(f(b)), a, b)
    return np.where(fa == 0.0, ta, np.where(fa * fb < 0, root, tb))


def _block(t, at, length, reactions, cyc, rows, N: int, n: int) -> list:
    """The figures of a block of runs (``rows``) of one N: their cycles' steps ``at`` (run, j)
    of which each run's first ``length`` are its own, the ``reactions`` there."""
    g, L = at.shape
    Y = np.empty((len(QUANTITIES), g, L))  # (quantity, run, j)
    for k, (_name, cols, _unit) in enumerate(QUANTITIES):
        if len(cols) == 1:
            Y[k] = reactions[cols[0]]
        else:
            np.hypot(reactions[cols[0]], reactions[cols[1]], out=Y[k])
    own = np.arange(L) < length[:, None]  # (run, j)
    found = np.any((Y != 0.0) & own, axis=2)  # (quantity, run)
    t0, period = cyc.t0[rows], cyc.period[rows]
    tq = t0[:, None] + period[:, None] * np.arange(N) / N
    out: list = [None] * g
    tt = t[at]
    first, last = tt[:, 0], tt[np.arange(g), length - 1]
    outside = (tq[:, 0] < first - 1e-12 * period) | (tq[:, -1] > last + 1e-12 * period)
    for r in np.nonzero(outside)[0]:
        out[r] = LoadReportError(
            f"resample: the cycle [{t0[r]:.9g}, {t0[r] + period[r]:.9g}] s is not "
            f"inside the data [{first[r]:.9g}, {last[r]:.9g}] s"
        )
    active = np.nonzero(found.any(axis=1))[0]  # the quantities some run of the block has
    Y = Y[active] if active.size < len(QUANTITIES) else Y
    ys = _resample(_times(t, at, length), Y, length, tq - first[:, None])  # (quantity, run, sample)
    c = np.fft.rfft(ys, axis=2)
    c /= N
    means = c[:, :, 0].real
    amps = 2.0 * np.abs(c[:, :, 1 : n + 1])  # (quantity, run, k)
    # the mean squares by Parseval's theorem: of y − mean, every coefficient but the first
    # (the others twice, as rfft gives half of them, but N/2's)
    power = c.real**2 + c.imag**2
    dynamic = 2.0 * power[:, :, 1:].sum(axis=2) - power[:, :, N // 2]
    rms = np.sqrt(dynamic + power[:, :, 0])
    rms_dynamic = np.sqrt(dynamic)
    inside = (tt >= t0[:, None]) & (tt <= (t0 + period)[:, None]) & own
    peaks = np.maximum.reduce(
        [
            np.max(Y, axis=2, where=inside, initial=0.0),
            -np.min(Y, axis=2, where=inside, initial=0.0),
            np.max(ys, axis=2),
            -np.min(ys, axis=2),
        ]
    )
    values = np.concatenate([np.stack([means, peaks, rms, rms_dynamic], axis=2), amps], axis=2).transpose(
        1, 0, 2
    )  # (run, quantity, 4 + n)
    names = [QUANTITIES[k][0] for k in active]
    for j in range(g):
        if out[j] is None:
            keep = np.nonzero(found[active, j])[0]
            out[j] = RunFigures(float(period[j]), tuple(names[k] for k in keep), values[j, keep])
    return out


def _times(t, at, length):
    """Each run's steps' times from its first (run, j), beyond its own ``length`` continued by
    whole steps (its spline's padding)."""
    g, L = at.shape
    x = t[at] - t[at[:, 0]][:, None]
    beyond = np.arange(L) >= length[:, None]
    if beyond.any():
        dt = (t[-1] - t[0]) / max(1, t.size - 1)
        j = np.broadcast_to(np.arange(L), (g, L))
        last = x[np.arange(g), length - 1][:, None]
        x = np.where(beyond, last + (j - length[:, None] + 1) * dt, x)
    return x


def _resample(x, Y, length, u):
    """The not-a-knot cubic splines through (x, Y) (x: (run, j), Y: (quantity, run, j)), each
    run's first ``length`` points its own, at ``u`` (run, sample): (quantity, run, sample)."""
    s = _slopes(x, Y, length)
    # each sample's interval, as PPoly finds it (the last interval for a sample beyond it)
    g, L = x.shape
    idx = np.empty(u.shape, dtype=np.intp)
    for r in range(g):
        k = int(length[r])
        idx[r] = np.clip(np.searchsorted(x[r, :k], u[r], side="right") - 1, 0, k - 2)
    # the cubic Hermite interpolant of the values and the slopes at the interval's ends
    x0 = np.take_along_axis(x, idx, axis=1)
    h = np.take_along_axis(x, idx + 1, axis=1) - x0
    tau = (u - x0) / h
    tau2 = tau * tau
    tau3 = tau2 * tau
    w = (
        2.0 * tau3 - 3.0 * tau2 + 1.0,
        (tau3 - 2.0 * tau2 + tau) * h,
        -2.0 * tau3 + 3.0 * tau2,
        (tau3 - tau2) * h,
    )
    flat = np.arange(g)[:, None] * L + idx  # (run, sample): the interval's start in (run, j)
    Q = Y.shape[0]
    Yf, sf = Y.reshape(Q, g * L), s.reshape(Q, g * L)
    return (
        w[0] * np.take(Yf, flat, axis=1)
        + w[1] * np.take(sf, flat, axis=1)
        + w[2] * np.take(Yf, flat + 1, axis=1)
        + w[3] * np.take(sf, flat + 1, axis=1)
    )


def _slopes(x, Y, length):
    """The splines' first derivatives at their points (as ``Y``): scipy's not-a-knot system
    (:class:`~scipy.interpolate.CubicSpline`) of every run (at least 4 points), solved for all
    runs and quantities at once by elimination without pivoting (the system is diagonally
    dominant but for its first and last rows, whose pivots stay about h/2), a run's padding
    identity rows."""
    g, L = x.shape
    if int(length.min()) < 4:
        raise ValueError(f"a cycle of {int(length.min())} steps: too few for the batch's splines")
    r = np.arange(g)
    last = length - 1
    own = np.arange(L) < length[:, None]
    dx = np.diff(x, axis=1)  # (run, j)
    slope = np.diff(Y, axis=2) / dx  # (quantity, run, j)
    # the tridiagonal matrix, (j, run): its diagonal D, above it U (A[j, j+1]), below it W
    # (A[j+1, j])
    D = np.ones((g, L))
    D[:, 1:-1] = 2.0 * (dx[:, :-1] + dx[:, 1:])
    D[:, 0] = dx[:, 1]
    D[r, last] = dx[r, last - 1]
    D[~own] = 1.0
    U = np.zeros((g, L))
    U[:, 1:-1] = dx[:, :-1]
    U[:, 0] = x[:, 2] - x[:, 0]
    U[np.arange(L) >= last[:, None]] = 0.0
    W = np.zeros((g, L))
    W[:, :-2] = dx[:, 1:]
    W[r, last - 1] = x[r, last] - x[r, last - 2]
    W[np.arange(L) >= last[:, None]] = 0.0
    B = np.zeros_like(Y)  # (quantity, run, j)
    B[:, :, 1:-1] = 3.0 * (dx[:, 1:] * slope[:, :, :-1] + dx[:, :-1] * slope[:, :, 1:])
    w = x[:, 2] - x[:, 0]
    B[:, :, 0] = ((dx[:, 0] + 2.0 * w) * dx[:, 1] * slope[:, :, 0] + dx[:, 0] ** 2 * slope[:, :, 1]) / w
    w = x[r, last] - x[r, last - 2]
    d1, d2 = dx[r, last - 1], dx[r, last - 2]
    B[:, r, last] = (d1**2 * slope[:, r, last - 2] + (2.0 * w + d1) * d2 * slope[:, r, last - 1]) / w
    B[:, ~own] = 0.0
    # elimination, a row j of every run and quantity at a time
    b = np.ascontiguousarray(np.moveaxis(B, 2, 0))  # (j, quantity, run)
    D, U, W = D.T.copy(), U.T.copy(), W.T.copy()
    for j in range(1, L):
        f = W[j - 1] / D[j - 1]
        D[j] -= f * U[j - 1]
        b[j] -= f * b[j - 1]
    inv = 1.0 / D
    b[L - 1] *= inv[L - 1]
    for j in range(L - 2, -1, -1):
        b[j] -= U[j] * b[j + 1]
        b[j] *= inv[j]
    return np.moveaxis(b, 0, 2)


__all__ = ["BLOCK", "RunFigures", "batch_figures", "cycles"]
