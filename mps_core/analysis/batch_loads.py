"""The load reports of a vectorised batch's runs, all at once: each run's figures as
:func:`mps_core.analysis.loads.load_report` gives them (its steady cycle's period, and each
quantity's mean, peak, RMS, dynamic RMS and harmonic amplitudes), to round-off, from the states
a batch keeps (:class:`mps_core.run.batch.states.BatchStates`) rather than from each run's
trajectory.

The method is the report's (:mod:`.loads`), on arrays of all runs:

* the cycle: the last two passages of the crank through φ = 0 (mod 2π), each located on the
  cubic Hermite interpolant of (φ, φ̇) between its steps, by bisection to the last bit (the
  report's root finder, :func:`mps_core.run.roots.brent_root`, stops within 1e-15 s);
* the joint reactions solved at each run's cycle's steps only (the steps the report's spline
  goes through, three beyond each end);
* the not-a-knot cubic spline through those steps (scipy's :class:`~scipy.interpolate.CubicSpline`
  system on the batch's uniform steps, solved by LAPACK for the runs of a block of one length
  and every quantity at once: :func:`_slopes`), evaluated at each run's N uniform instants of
  its cycle;
* the discrete Fourier transform of a block's runs and quantities in one call.

A run whose report cannot be made (no full revolution, a cycle outside its steps) gets the
report's own error, as :func:`~mps_core.analysis.loads.load_report` raises it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import loads
from .loads import N_HARMONICS, QUANTITIES, TWO_PI, LoadReportError

#: the reaction columns the reports read
COLUMNS = frozenset(c for _name, cols, _unit in QUANTITIES for c in cols)

#: runs a block of the resampling and the transform takes: its arrays (quantity, run, sample)
#: of about 3 MB each stay in the caches and the allocator's reach; blocks of 8 to 256 runs
#: were tried in turns, 8 and 16 the fastest, 128 about a third slower
BLOCK = 16


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
    (:class:`~mps_core.run.batch.states.BatchStates`), in the batch's order. Raises
    :class:`~mps_core.run.batch.record.ReactionsNotSolved` as the batch's reactions do, and
    ``ValueError`` where the batch is not one this computes (its structure not ``mode``, a
    crank frozen)."""
    if mode is not None and states.structure != mode:
        raise ValueError(f"the batch runs in the {states.structure!r} structure, not {mode!r}")
    t = states.t[: states.k]
    phi = states.coordinate("phi")
    phi_dot = states.coordinate("phi", 1)
    if phi is None or phi_dot is None:
        raise ValueError("the batch's crank angle is frozen")
    cyc = cycles(t, phi, phi_dot, mode)
    S, m = phi.shape
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
        reactions = states.reactions(at, rows, COLUMNS)
        for r, res in zip(block, _block(t, at, length[rows], reactions, cyc, rows, int(N[block[0]]), n)):
            out[r] = res
    return out


def cycles(t, phi, phi_dot, mode: str | None = "locked") -> _Cycles:
    """The last full crank revolution of each run: ``phi`` and ``phi_dot`` (step, run) at the
    steps' times ``t``, every step in the structure ``mode``."""
    S, m = phi.shape
    turns = np.floor(phi / TWO_PI + 1e-12)
    step, run = np.nonzero(turns[1:] != turns[:-1])  # the steps after which φ passes 2πk
    order = np.argsort(run, kind="stable")  # by run, each run's by step
    step, run = step[order], run[order]
    count = np.bincount(run, minlength=m)
    end = np.cumsum(count)
    cross = np.full((m, 3), np.nan)  # the last three passages' times, the last first
    for j in range(3):
        has = count > j
        i = step[end[has] - 1 - j]
        cross[has, j] = _passage(t, phi, phi_dot, turns, i, np.nonzero(has)[0])
    errors = {}
    for k in np.nonzero(count < 2)[0].tolist():
        try:  # the report's own message
            loads.last_cycle(t, phi[:, k], phi_dot[:, k], None, mode)
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


def _passage(t, phi, phi_dot, turns, i, r):
    """The times at which φ passes its multiple of 2π between steps ``i`` and ``i + 1`` of
    runs ``r`` (``phi``, ``phi_dot``, ``turns``: (step, run)): the report's rule
    (:func:`loads._crossings`) with bisection on the cubic Hermite interpolant, to the last
    bit."""
    ta, tb = t[i], t[i + 1]
    level = TWO_PI * np.maximum(turns[i, r], turns[i + 1, r])
    f = loads.hermite_minus(ta, tb, phi[i, r], phi[i + 1, r], phi_dot[i, r], phi_dot[i + 1, r], level)

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
    h = (t[-1] - t[0]) / max(1, t.size - 1)  # the batch's step: its times are uniform
    ys = _resample(Y, length, h, tq - first[:, None])  # (quantity, run, sample)
    # the coefficients times N (N a power of two: dividing by it, where read, is exact)
    c = np.fft.rfft(ys, axis=2)
    means = c[:, :, 0].real / N
    amps = (2.0 / N) * np.abs(c[:, :, 1 : n + 1])  # (quantity, run, k)
    # the mean squares by Parseval's theorem: of y − mean, every coefficient but the first
    # (the others twice, as rfft gives half of them, but N/2's); the squares of the real and
    # imaginary parts in one pass (k's at 2k and 2k + 1)
    sq = c.view(np.float64) ** 2
    zero, middle = sq[:, :, 0] + sq[:, :, 1], sq[:, :, N] + sq[:, :, N + 1]
    dynamic = (2.0 * sq[:, :, 2:].sum(axis=2) - middle) / (N * N)
    rms = np.sqrt(dynamic + zero / (N * N))
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


def _resample(Y, length, h, u):
    """The not-a-knot cubic splines through ``Y`` (quantity, run, j) at the knots j·h, each
    run's first ``length`` knots its own, at ``u`` (run, sample): (quantity, run, sample)."""
    s = _slopes(Y, length, h)
    # each sample's interval, as PPoly finds it (the last interval for a sample beyond it)
    Q, g, L = Y.shape
    idx = np.clip(np.floor(u / h).astype(np.intp), 0, (length - 2)[:, None])
    # the cubic Hermite interpolant of the values and the slopes at the interval's ends
    tau = u / h - idx
    tau2 = tau * tau
    tau3 = tau2 * tau
    w = (
        2.0 * tau3 - 3.0 * tau2 + 1.0,
        (tau3 - 2.0 * tau2 + tau) * h,
        -2.0 * tau3 + 3.0 * tau2,
        (tau3 - tau2) * h,
    )
    flat = np.arange(g)[:, None] * L + idx  # (run, sample): the interval's start in (run, j)
    Yf, sf = Y.reshape(Q, g * L), s.reshape(Q, g * L)
    return (
        w[0] * np.take(Yf, flat, axis=1)
        + w[1] * np.take(sf, flat, axis=1)
        + w[2] * np.take(Yf, flat + 1, axis=1)
        + w[3] * np.take(sf, flat + 1, axis=1)
    )


def _slopes(Y, length, h):
    """The splines' first derivatives at their knots j·h (as ``Y``: (quantity, run, j), a
    run's first ``length`` knots its own, its rows beyond zero): scipy's not-a-knot system
    (:class:`~scipy.interpolate.CubicSpline`) on a uniform grid, divided by h,

        row 0:  s_0 + 2 s_1 = (5 σ_0 + σ_1) / 2,
        row j:  s_{j-1} + 4 s_j + s_{j+1} = 3 (σ_{j-1} + σ_j),
        last:   2 s_{l-1} + s_l = (σ_{l-2} + 5 σ_{l-1}) / 2,

    σ_j = (y_{j+1} − y_j) / h: tridiagonal, one matrix for the runs of one length, solved
    by LAPACK (``gtsv``) for all of them and every quantity in one call."""
    from scipy.linalg.lapack import dgtsv

    Q, g, L = Y.shape
    if int(length.min()) < 4:
        raise ValueError(f"a cycle of {int(length.min())} steps: too few for the batch's splines")
    sig = np.diff(Y, axis=2) / h  # (quantity, run, j)
    s = np.zeros_like(Y)
    for n in np.unique(length).tolist():
        runs = np.nonzero(length == n)[0]
        last = n - 1
        sg = sig[:, runs, :last]
        b = np.empty((Q, len(runs), n))  # the right-hand sides, each contiguous
        b[..., 0] = 2.5 * sg[..., 0] + 0.5 * sg[..., 1]
        np.add(sg[..., :-1], sg[..., 1:], out=b[..., 1:last])
        b[..., 1:last] *= 3.0
        b[..., last] = 0.5 * sg[..., last - 2] + 2.5 * sg[..., last - 1]
        below, above = np.ones(last), np.ones(last)
        below[-1], above[0] = 2.0, 2.0
        diagonal = np.full(n, 4.0)
        diagonal[0] = diagonal[-1] = 1.0
        *_, x, info = dgtsv(below, diagonal, above, b.reshape(-1, n).T, overwrite_b=1)
        if info != 0:  # cannot be: the system is regular for every n >= 4
            raise ValueError(f"the batch's spline system of {n} knots is singular (LAPACK info {info})")
        s[:, runs, :n] = x.T.reshape(Q, len(runs), n)
    return s


__all__ = ["BLOCK", "RunFigures", "batch_figures", "cycles"]
