"""The load report: what the press does to its foundation over a steady working cycle.

From a run with reactions (:mod:`mps_core.dynamics.reactions`) the report takes the **last full crank
revolution** in the working structure (``locked`` by default) and gives, for every joint
reaction's components and magnitude and for the foundation resultant:

* ``mean``, ``peak`` (max |y| over the cycle's recorded steps), ``rms`` (root mean square of y over
  the cycle, in time) and ``rms_dynamic`` (that of y − mean);
* the amplitude A_k and phase φ_k of harmonics k = 1…6 of the crank frequency Ω = 2π/T, with
  ``y(t) ≈ mean + Σ_k A_k·cos(k·Ω·(t − t0) + φ_k)``, t0 the time at which the crank passes
  φ = 0 (mod 2π) at the start of the cycle (the top dead centre of the crank-slider).

Method. The cycle's ends t0 and t0 + T are the last two passages of the crank through φ = 0
(mod 2π), located by cubic Hermite interpolation of (φ, φ̇) between steps. Each quantity is
resampled at N uniform instants t0 + jT/N (j = 0…N−1, N a power of two with at least as many
points as the cycle has steps) by a cubic spline through the recorded steps, and the harmonics are
its discrete Fourier coefficients: A_k = 2|c_k|, φ_k = arg c_k, c_k = (1/N) Σ_j y_j e^{−2πijk/N}.
For a signal that is a trigonometric polynomial of degree < N/2 sampled uniformly this is exact;
otherwise the error is the spline's (O(Δt⁴)). The first and second harmonics are the dynamic
loads that СП 26.13330 asks for crank machines. The cycle's steadiness is reported as the
relative change of the period from the revolution before (when there is one).

Impacts are transients, not part of a steady cycle: their impulses (N·s) and durations are listed
as they were recorded (``kind: "impulse"`` events), never folded into the time series.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..dynamics.reactions import DESCRIPTIONS
from ..errors import MpsError
from ..run.roots import brent_root

N_HARMONICS = 6
TWO_PI = 2.0 * math.pi
#: what the report gives of each quantity beside its harmonics, in the order of its columns
FIGURES = ("mean", "peak", "rms", "rms_dynamic")


class LoadReportError(MpsError, ValueError):
    """The data cannot give a load report (no steady cycle, missing columns)."""


# -- harmonics ------------------------------------------------------------------------------
def harmonics(samples, n: int = N_HARMONICS) -> tuple[float, np.ndarray, np.ndarray]:
    """Mean, amplitudes A_k and phases φ_k (rad), k = 1…n, of one period sampled uniformly.

    ``samples[j] = y(t0 + j·T/N)``, j = 0…N−1 (the end point t0 + T excluded), and
    ``y(t) = mean + Σ A_k cos(k·2π(t − t0)/T + φ_k)``. Exact for trigonometric polynomials of
    degree < N/2; requires N > 2n.
    """
    y = np.asarray(samples, dtype=float)
    N = y.size
    if y.ndim != 1 or N <= 2 * n:
        raise LoadReportError(
            f"harmonics: {N} samples for {n} harmonics: expected a 1-D array "
            f"of more than {2 * n} samples of one period"
        )
    c = np.fft.rfft(y) / N
    return float(c[0].real), 2.0 * np.abs(c[1 : n + 1]), np.angle(c[1 : n + 1])


def resample(t, y, t0: float, period: float, samples: int) -> np.ndarray:
    """y at t0 + j·period/samples (j = 0…samples−1) by a cubic spline through (t, y) (``y``
    with more columns than one: each column's, one row an instant)."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    tq = t0 + period * np.arange(samples) / samples
    if tq[0] < t[0] - 1e-12 * period or tq[-1] > t[-1] + 1e-12 * period:
        raise LoadReportError(
            f"resample: the cycle [{t0:.9g}, {t0 + period:.9g}] s is not "
            f"inside the data [{t[0]:.9g}, {t[-1]:.9g}] s"
        )
    from scipy.interpolate import CubicSpline  # (a quarter of a second: only where resampled)

    return CubicSpline(t, y)(tq)


# -- the steady cycle -----------------------------------------------------------------------
@dataclass(frozen=True)
class Cycle:
    """One crank revolution: from ``t0`` to ``t0 + period`` (the crank passing φ = 0 mod 2π),
    the step indices ``i0 … i1`` (inclusive) that bracket it, its mean crank speed (rad/s), and
    ``period_change`` = |T − T_previous| / T (NaN where there is no previous revolution)."""

    t0: float
    period: float
    i0: int
    i1: int
    omega: float
    period_change: float

    @property
    def t1(self) -> float:
        return self.t0 + self.period

    @property
    def frequency_hz(self) -> float:
        return 1.0 / self.period


def _crossings(t, phi, phi_dot):
    """Times where φ passes a multiple of 2π, in order (φ may turn either way)."""
    k = np.floor(phi / TWO_PI + 1e-12)
    idx = np.nonzero(np.diff(k))[0]
    out = []
    for i in idx:
        level = TWO_PI * max(k[i], k[i + 1])
        if phi_dot is not None:
            f = _hermite(float(t[i]), float(t[i + 1]), phi[i : i + 2], phi_dot[i : i + 2], level)
        else:
            ts, ps = t[i : i + 2], phi[i : i + 2]
            f = lambda s, ts=ts, ps=ps, level=level: float(np.interp(s, ts, ps)) - level  # noqa: E731
        fa, fb = f(t[i]), f(t[i + 1])
        if fa == 0.0:
            out.append(float(t[i]))
        elif fa * fb < 0:
            out.append(float(brent_root(f, float(t[i]), float(t[i + 1]), xtol=1e-15, rtol=1e-15)))
        else:
            out.append(float(t[i + 1]))
    return out


def _hermite(t0: float, t1: float, p, d, level: float):
    """s ↦ H(s) − level, H the cubic Hermite interpolant of (p, d) at t0 and t1 (the cubic of
    :class:`scipy.interpolate.CubicHermiteSpline` on one interval), on floats."""
    return hermite_minus(t0, t1, float(p[0]), float(p[1]), float(d[0]), float(d[1]), level)


def hermite_minus(t0, t1, p0, p1, d0, d1, level):
    """s ↦ H(s) − level, H the cubic Hermite interpolant of the values p0, p1 and slopes d0,
    d1 at t0 and t1: on floats, or on arrays of many intervals at once."""
    h = t1 - t0
    slope = (p1 - p0) / h
    c2 = (3.0 * slope - 2.0 * d0 - d1) / h
    c3 = (d0 + d1 - 2.0 * slope) / (h * h)

    def f(s):
        x = s - t0
        return ((c3 * x + c2) * x + d0) * x + p0 - level

    return f


def last_cycle(t, phi, phi_dot=None, structure=None, mode: str | None = "locked") -> Cycle:
    """The last full crank revolution, all of it in structure ``mode`` (if ``structure`` given)."""
    t = np.asarray(t, dtype=float)
    phi = np.asarray(phi, dtype=float)
    pd = None if phi_dot is None else np.asarray(phi_dot, dtype=float)
    if structure is not None and mode is not None:
        ok = np.asarray(structure) == mode
        if not ok.any():
            raise LoadReportError(
                f"no step of the run is in the {mode!r} structure (the "
                "working mode); the load report needs a steady working cycle"
            )
        # the last run of consecutive steps in the mode: from after the last step before its
        # end that is not in it
        end = int(np.nonzero(ok)[0][-1])
        out = np.nonzero(~ok[:end])[0]
        start = int(out[-1]) + 1 if out.size else 0
        t, phi = t[start : end + 1], phi[start : end + 1]
        pd = None if pd is None else pd[start : end + 1]
    else:
        start = 0
    cross = _crossings(t, phi, pd)
    if len(cross) < 2:
        span = (phi[-1] - phi[0]) / TWO_PI if phi.size else 0.0
        raise LoadReportError(
            f"no full crank revolution between two passages of phi = 0 (mod 360 deg) in the "
            f"{mode or 'whole'} run ({span:.3g} revolutions from t = {t[0]:.6g} s to "
            f"{t[-1]:.6g} s): run the scene longer (--t-end)"
        )
    t0, t1 = cross[-2], cross[-1]
    period = t1 - t0
    change = abs(period - (cross[-2] - cross[-3])) / period if len(cross) >= 3 else math.nan
    i0 = int(np.searchsorted(t, t0, side="right")) - 1
    i1 = int(np.searchsorted(t, t1, side="left"))
    i0, i1 = max(i0, 0), min(i1, t.size - 1)
    return Cycle(t0, period, start + i0, start + i1, TWO_PI / period, change)


# -- the report -----------------------------------------------------------------------------
#: the quantities of the report: (name, columns it is made of, unit); two columns: a magnitude
QUANTITIES: tuple[tuple[str, tuple[str, ...], str], ...] = (
    ("F_O_x", ("F_O_x",), "N"),
    ("F_O_y", ("F_O_y",), "N"),
    ("|F_O|", ("F_O_x", "F_O_y"), "N"),
    ("F_A_x", ("F_A_x",), "N"),
    ("F_A_y", ("F_A_y",), "N"),
    ("|F_A|", ("F_A_x", "F_A_y"), "N"),
    ("F_B_x", ("F_B_x",), "N"),
    ("F_B_y", ("F_B_y",), "N"),
    ("|F_B|", ("F_B_x", "F_B_y"), "N"),
    ("F_C_x", ("F_C_x",), "N"),
    ("F_C_y", ("F_C_y",), "N"),
    ("|F_C|", ("F_C_x", "F_C_y"), "N"),
    ("N_guide", ("N_guide",), "N"),
    ("M_guide", ("M_guide",), "N*m"),
    ("M_latch", ("M_latch",), "N*m"),
    ("F_stop", ("F_stop",), "N"),
    ("M_motor", ("M_motor",), "N*m"),
    ("F_found_x", ("F_found_x",), "N"),
    ("F_found_y", ("F_found_y",), "N"),
    ("|F_found|", ("F_found_x", "F_found_y"), "N"),
    ("M_found_O", ("M_found_O",), "N*m"),
)

FOUNDATION = ("F_found_x", "F_found_y", "|F_found|", "M_found_O")


def _meaning(name: str, cols: tuple[str, ...]) -> str:
    if len(cols) == 1:
        return DESCRIPTIONS.get(cols[0], "")
    base = DESCRIPTIONS.get(cols[0], "").split(", x component")[0]
    if name == "|F_found|":
        base = "foundation load: magnitude of the resultant force the frame receives"
    return f"magnitude of the {base}"


def _figures(quantities: list, ys: np.ndarray, inside: np.ndarray, n: int) -> list[dict]:
    """The quantities' figures: ``quantities`` their (name, unit, meaning), ``ys`` their cycle
    resampled (one row a quantity), ``inside`` their samples in the cycle (a row each; the
    peak is over both). Each row as :func:`harmonics` and the means would take it alone (a
    row's sums in its own order), all rows in one call each."""
    N = ys.shape[1]
    if N <= 2 * n:
        harmonics(ys[0], n)  # its error
    c = np.fft.rfft(ys, axis=1) / N
    means = c[:, 0].real
    amps = 2.0 * np.abs(c[:, 1 : n + 1])
    phases = np.degrees(np.angle(c[:, 1 : n + 1]))
    peaks = np.maximum(np.max(np.abs(inside), axis=1, initial=0.0), np.max(np.abs(ys), axis=1))
    rms = np.sqrt(np.mean(ys**2, axis=1))
    rms_dynamic = np.sqrt(np.mean((ys - means[:, None]) ** 2, axis=1))
    out = []
    for j, (name, unit, meaning) in enumerate(quantities):
        tiny = 1e-9 * max(float(peaks[j]), 1e-300)
        amp, ph = amps[j].tolist(), phases[j].tolist()
        out.append(
            {
                "name": name,
                "unit": unit,
                "meaning": meaning,
                "mean": float(means[j]),
                "peak": float(peaks[j]),
                "rms": float(rms[j]),
                "rms_dynamic": float(rms_dynamic[j]),
                "harmonics": [
                    {"k": k + 1, "amplitude": amp[k], "phase_deg": (ph[k] if amp[k] > tiny else None)}
                    for k in range(n)
                ],
            }
        )
    return out


def load_report(
    columns: Mapping[str, np.ndarray],
    *,
    n: int = N_HARMONICS,
    mode: str | None = "locked",
    events: Iterable[dict] = (),
    source: str = "",
) -> dict:
    """The load report (a JSON-ready dict) of a run's columns (a Trajectory's ``columns`` or a
    CSV read back), over its last full crank revolution in structure ``mode``.

    Keys: ``source``, ``cycle`` (t0, period, crank frequency and speed, steadiness), ``method``,
    ``quantities`` (one dict a quantity: name, unit, meaning, mean, peak, rms, rms_dynamic,
    ``harmonics``: k, amplitude, phase_deg), ``transients`` (recorded impulse events), ``checks``
    (the largest least-squares and balance residuals over the cycle).
    """
    missing = [c for c in ("t", "phi", "F_found_x") if c not in columns]
    if missing:
        raise LoadReportError(
            "load report: the run has no column "
            + ", ".join(missing)
            + " (run with reactions: mps run SCENE --reactions --csv FILE)"
        )
    t = np.asarray(columns["t"], dtype=float)
    cyc = last_cycle(t, columns["phi"], columns.get("phi_dot"), columns.get("structure"), mode)
    steps = cyc.i1 - cyc.i0
    N = max(64, 1 << int(math.ceil(math.log2(max(steps, 2 * n + 2)))))
    sl = slice(max(cyc.i0 - 3, 0), min(cyc.i1 + 4, t.size))
    inside = (t >= cyc.t0) & (t <= cyc.t1)
    found, window = [], []
    for name, cols, unit in QUANTITIES:
        if any(c not in columns for c in cols):
            continue
        arr = [np.asarray(columns[c], dtype=float) for c in cols]
        y = arr[0] if len(arr) == 1 else np.hypot(arr[0], arr[1])
        if not np.any(y[sl] != 0.0):
            continue  # no such joint in this structure
        found.append((name, unit, _meaning(name, cols)))
        window.append(y)
    quantities = []
    if found:
        # one spline through every quantity's steps (their common times), one row a quantity
        Y = np.stack(window)
        ys = np.ascontiguousarray(resample(t[sl], Y[:, sl].T, cyc.t0, cyc.period, N).T)
        quantities = _figures(found, ys, Y[:, inside], n)
    checks = {}
    for c in ("residual_force_N", "residual_moment_Nm", "balance_residual_N", "balance_residual_Nm"):
        if c in columns:
            checks["max_" + c] = float(np.max(np.asarray(columns[c])[cyc.i0 : cyc.i1 + 1]))
    transients = [dict(ev) for ev in events if ev.get("kind") == "impulse"]
    return {
        "source": source,
        "cycle": {
            "t0_s": cyc.t0,
            "t1_s": cyc.t1,
            "period_s": cyc.period,
            "crank_frequency_hz": cyc.frequency_hz,
            "crank_speed_mean_rad_s": cyc.omega,
            "period_change": None if math.isnan(cyc.period_change) else cyc.period_change,
            "steps": steps,
            "resampled_points": N,
            "structure": mode,
        },
        "method": (
            "last full crank revolution between passages of phi = 0 (mod 2 pi); cubic "
            "spline resampling at N uniform instants; DFT: A_k = 2|c_k|, phase = arg c_k "
            "in y = mean + sum A_k cos(k Omega (t - t0) + phase_k)"
        ),
        "quantities": quantities,
        "transients": transients,
        "checks": checks,
    }


def quantity(report: dict, name: str) -> dict:
    """One quantity's entry of a report, by name (``"F_found_x"``, ``"|F_O|"``…)."""
    for q in report["quantities"]:
        if q["name"] == name:
            return q
    raise KeyError(
        f"load report has no quantity {name!r}; it has " + ", ".join(q["name"] for q in report["quantities"])
    )


# -- outputs --------------------------------------------------------------------------------
def format_table(report: dict) -> str:
    """The report as text tables: amplitudes for every quantity, phases for the foundation."""
    c = report["cycle"]
    n = len(report["quantities"][0]["harmonics"]) if report["quantities"] else 0
    lines = [
        f"load report {report['source']}: cycle t = {c['t0_s']:.6g} .. {c['t1_s']:.6g} s, "
        f"period {c['period_s'] * 1e3:.4g} ms, crank {c['crank_speed_mean_rad_s']:.5g} rad/s "
        f"({c['crank_frequency_hz']:.5g} Hz)"
        + (
            ""
            if c["period_change"] is None
            else f", period change from the revolution before {c['period_change']:.2e}"
        )
    ]
    head = f"{'quantity':<11} {'unit':<4} {'mean':>10} {'peak':>10} {'RMS':>10}" + "".join(
        f" {'A' + str(k + 1):>9}" for k in range(n)
    )
    lines += ["", head, "-" * len(head)]
    for q in report["quantities"]:
        lines.append(
            f"{q['name']:<11} {q['unit']:<4} {q['mean']:>10.4g} {q['peak']:>10.4g} "
            f"{q['rms']:>10.4g}" + "".join(f" {h['amplitude']:>9.4g}" for h in q["harmonics"])
        )
    lines += [
        "",
        "phases of the foundation load (deg; y = mean + sum A_k cos(k W (t - t0) + ph_k),"
        " t0: crank at phi = 0)",
    ]
    for q in report["quantities"]:
        if q["name"] in FOUNDATION:
            lines.append(
                f"{q['name']:<11}"
                + "".join(
                    f" {'-' if h['phase_deg'] is None else format(h['phase_deg'], '.1f'):>9}"
                    for h in q["harmonics"]
                )
            )
    tr = report["transients"]
    lines.append("")
    if tr:
        lines.append("transients (impulses, N*s):")
        for ev in tr:
            imp = ", ".join(f"{k} {v:.4g}" for k, v in ev.get("impulses_Ns", {}).items())
            lines.append(f"  t = {ev['t']:.6g} s, duration {ev.get('duration_s', 0.0):g} s: {imp}")
    else:
        lines.append("transients: none in this run (no impacts recorded)")
    ch = report["checks"]
    if ch:
        lines.append("checks over the cycle: " + ", ".join(f"{k} {v:.3g}" for k, v in ch.items()))
    return "\n".join(lines)


def write_json(report: dict, path) -> Path:
    path = Path(path)
    path.write_text(json.dumps(report, indent=2, default=_json_default) + "\n")
    return path


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {o!r}")


def write_csv(report: dict, path) -> Path:
    """One row a quantity: name, unit, mean, peak, rms, rms_dynamic, A1…An, phase1_deg…"""
    path = Path(path)
    n = len(report["quantities"][0]["harmonics"]) if report["quantities"] else 0
    head = (
        ["quantity", "unit", *FIGURES]
        + [f"A{k + 1}" for k in range(n)]
        + [f"phase{k + 1}_deg" for k in range(n)]
        + ["meaning"]
    )
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(head)
        for q in report["quantities"]:
            w.writerow(
                [q["name"], q["unit"]]
                + [repr(q[k]) for k in FIGURES]
                + [repr(h["amplitude"]) for h in q["harmonics"]]
                + ["" if h["phase_deg"] is None else repr(h["phase_deg"]) for h in q["harmonics"]]
                + [q["meaning"]]
            )
    return path


def write_png(report: dict, columns: Mapping[str, np.ndarray], path, title: str = "") -> Path:
    """A figure for people: the cycle's foundation force and joint forces against the crank
    angle, and the harmonic amplitudes of the foundation load as bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    c = report["cycle"]
    t = np.asarray(columns["t"], dtype=float)
    i0 = int(np.searchsorted(t, c["t0_s"], side="left"))
    i1 = int(np.searchsorted(t, c["t1_s"], side="right"))
    sel = slice(i0, i1)
    ang = np.degrees(np.asarray(columns["phi"], dtype=float)[sel])
    ang = ang - 360.0 * math.floor(ang[0] / 360.0 + 1e-9) if ang.size else ang
    kn = lambda a: np.asarray(a, dtype=float)[sel] / 1e3  # noqa: E731  (kN)

    fig, ax = plt.subplots(2, 2, figsize=(13, 8.5), constrained_layout=True)
    _foundation_panel(ax[0, 0], report, columns, ang, kn)
    _joints_panel(ax[0, 1], columns, ang, kn)
    for a in ax[0]:
        a.set_xlabel("crank angle within the cycle (deg, 0 = top dead centre)")
        a.set_xlim(0, 360)
        a.set_xticks(range(0, 361, 45))
        a.grid(alpha=0.3)
    k = np.arange(1, len(report["quantities"][0]["harmonics"]) + 1)
    _force_harmonics_panel(ax[1, 0], report, k)
    _moment_harmonics_panel(ax[1, 1], report, k)

    fx = quantity(report, "|F_found|") if _has(report, "|F_found|") else None
    head = title or f"Load report: {report['source']}"
    sub = (
        f"steady cycle t = {c['t0_s']:.4g}..{c['t1_s']:.4g} s, crank {c['crank_speed_mean_rad_s']:.4g} rad/s"
    )
    if fx:
        sub += f"; |F_found| peak {fx['peak'] / 1e3:.3g} kN, RMS {fx['rms'] / 1e3:.3g} kN"
    fig.suptitle(f"{head}\n{sub}", fontsize=12)
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)
    return path


def _foundation_panel(a, report: dict, columns, ang, kn) -> None:
    """The foundation force over the cycle: its components, magnitude and static mean."""
    a.plot(
        ang,
        kn(columns["F_found_x"]),
        label="F_found_x (vertical, along the guide, up)",
        color="tab:blue",
        lw=2,
    )
    a.plot(ang, kn(columns["F_found_y"]), label="F_found_y (across the guide)", color="tab:orange", lw=2)
    a.plot(
        ang,
        np.hypot(kn(columns["F_found_x"]), kn(columns["F_found_y"])),
        label="|F_found|",
        color="k",
        lw=1,
        ls="--",
    )
    if _has(report, "F_found_x"):
        a.axhline(
            quantity(report, "F_found_x")["mean"] / 1e3,
            color="tab:blue",
            lw=0.8,
            ls=":",
            label="mean of F_found_x (static: the weight)",
        )
    a.axhline(0, color="0.6", lw=0.8)
    a.set_title("Foundation load: force the frame receives")
    a.set_ylabel("force (kN)")
    _headroom(a)
    a.legend(loc="upper center", fontsize=8, ncol=2)


def _joints_panel(a, columns, ang, kn) -> None:
    """The joint forces' magnitudes over the cycle, and the guide's normal force."""
    for name, cx, cy in (
        ("|F_O| crank bearing", "F_O_x", "F_O_y"),
        ("|F_A| crank-rod", "F_A_x", "F_A_y"),
        ("|F_B| rod-rocker", "F_B_x", "F_B_y"),
        ("|F_C| rocker-slider", "F_C_x", "F_C_y"),
    ):
        if cx in columns:
            a.plot(ang, np.hypot(kn(columns[cx]), kn(columns[cy])), label=name, lw=1.6)
    if "N_guide" in columns:
        a.plot(ang, kn(columns["N_guide"]), label="N_guide (guide, y)", lw=1.6, ls=":")
    a.axhline(0, color="0.6", lw=0.8)
    a.set_title("Joint forces (magnitudes; N_guide signed)")
    a.set_ylabel("force (kN)")
    _headroom(a)
    a.legend(loc="upper center", fontsize=8, ncol=3)


def _force_harmonics_panel(a, report: dict, k) -> None:
    """The foundation force's harmonic amplitudes, one bar a component and harmonic."""
    names = [q for q in ("F_found_x", "F_found_y") if _has(report, q)]
    w = 0.8 / max(1, len(names))
    amps = [np.array([h["amplitude"] for h in quantity(report, q)["harmonics"]]) / 1e3 for q in names]
    top = max((float(x.max()) for x in amps), default=0.0)
    for j, (name, amp) in enumerate(zip(names, amps)):
        bars = a.bar(k + (j - (len(names) - 1) / 2) * w, amp, w, label=name)
        _labels(a, bars, amp, top)
    a.set_title(
        f"Foundation force: harmonics of the crank frequency ({report['cycle']['crank_frequency_hz']:.3g} Hz)"
    )
    a.set_xlabel("harmonic k (frequency k x crank frequency)")
    a.set_ylabel("amplitude (kN)")
    a.set_xticks(k)
    a.legend(fontsize=9)
    a.grid(alpha=0.3, axis="y")


def _moment_harmonics_panel(a, report: dict, k) -> None:
    """The foundation moment's harmonic amplitudes."""
    if _has(report, "M_found_O"):
        amp = np.array([h["amplitude"] for h in quantity(report, "M_found_O")["harmonics"]])
        bars = a.bar(k, amp, 0.6, color="tab:green", label="M_found_O")
        _labels(a, bars, amp, float(amp.max()))
    a.set_title("Foundation moment about O: harmonics")
    a.set_xlabel("harmonic k")
    a.set_ylabel("amplitude (N*m)")
    a.set_xticks(k)
    a.grid(alpha=0.3, axis="y")


def _headroom(ax, frac: float = 0.3) -> None:
    lo, hi = ax.get_ylim()
    ax.set_ylim(lo, hi + frac * (hi - lo))


def _labels(ax, bars, values, top: float) -> None:
    """Value labels on the bars that are large enough to read (over 2 % of ``top``)."""
    labels = [f"{v:.3g}" if v > 0.02 * top else "" for v in values]
    ax.bar_label(bars, labels=labels, fontsize=8, padding=2)


def _has(report: dict, name: str) -> bool:
    return any(q["name"] == name for q in report["quantities"])


__all__ = [
    "N_HARMONICS",
    "Cycle",
    "LoadReportError",
    "harmonics",
    "resample",
    "last_cycle",
    "load_report",
    "quantity",
    "format_table",
    "write_json",
    "write_csv",
    "write_png",
]
