"""Figures of the benchmarks (matplotlib, imported only here; None where it is missing)."""

from __future__ import annotations

from pathlib import Path

from .common import PEERS

COLORS = {
    "linear-acceleration": "tab:blue",
    "la-iterated": "tab:cyan",
    "rk4": "tab:green",
    "rk6": "tab:pink",
    "rk8": "tab:olive",
    "dop853": "tab:red",
    "radau": "tab:purple",
    "peer": "black",
    "mujoco": "tab:brown",
}
MARKERS = {
    "central 1°": "v",
    "central 0.1°": "o",
    "central 0.01°": "s",
    "central 0.001°": "D",
    "autodiff": "*",
    "exact (sympy)": "x",
}
STYLES = {
    "central 1°": ":",
    "central 0.1°": "-",
    "central 0.01°": "--",
    "central 0.001°": "-.",
    "autodiff": "-",
    "exact (sympy)": "-",
}


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt


def plot_accuracy(name: str, res: dict, path: Path):
    """Left: max |φ − φ_ref| against CPU seconds per simulated second, one line per solver and
    derivative scheme (points: the step ladder or the tolerances). Right: the error of central
    differences as Δ shrinks (per evaluation and per run)."""
    plt = _pyplot()
    if plt is None:
        return None
    rows = res["rows"]
    delta = res["delta"]
    fig, axes = plt.subplots(
        1,
        2 if delta else 1,
        figsize=(15 if delta else 10, 6.5),
        gridspec_kw={"width_ratios": [2.2, 1]} if delta else None,
        squeeze=False,
    )
    ax = axes[0][0]
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["solver"], r["scheme"]), []).append(r)
    for (solver, scheme), rs in groups.items():
        rs = sorted(rs, key=lambda r: r["cpu_per_sim_s"])
        x = [r["cpu_per_sim_s"] for r in rs]
        y = [max(r["max_err_phi"], 1e-16) for r in rs]
        ax.loglog(
            x,
            y,
            STYLES.get(scheme, "-"),
            marker=MARKERS.get(scheme, "o"),
            color=COLORS.get(solver, "gray"),
            lw=2.2 if solver in PEERS else 1.2,
            ms=5,
            label=f"{solver}, {scheme}",
        )
    ax.set_xlabel("CPU seconds per simulated second (one core)")
    case = res.get("case")
    ref = res["reference"]
    t_end = f" over {case.t_end:g} s" if case is not None else ""
    upto = (
        "over the run"
        if case is None or ref.horizon >= case.t_end
        else f"up to t = {ref.horizon:.3g} s (the reference's horizon)"
    )
    ax.set_ylabel(f"max |φ − φ_ref| {upto} (rad)")
    ax.set_title(f"{name}{t_end}: work-precision\nreference: {res['reference'].label}", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="lower left")
    if delta:
        ax2 = axes[0][1]
        ds = [d for d in delta if d["delta_deg"] > 0]
        x = [d["delta_deg"] for d in ds]
        ax2.loglog(
            x, [d["max_rel_err_qdd"] for d in ds], "o-", label="max relative error of q̈ (one evaluation)"
        )
        ax2.loglog(
            x,
            [d["max_err_phi_rk4"] for d in ds],
            "s-",
            label=f"max |φ − φ_ref|, RK4 dt = {ds[0]['rk4_dt']:.3g} s",
        )
        exact = [d for d in delta if d["delta_deg"] == 0]
        if exact:
            ax2.axhline(
                exact[0]["max_err_phi_rk4"], color="gray", ls="--", label="same run, exact derivatives"
            )
        ax2.set_xlabel("virtual displacement Δ (degrees)")
        ax2.set_ylabel("error")
        ax2.set_title("central differences: O(Δ²), then round-off ~ ε/Δ²", fontsize=10)
        ax2.invert_xaxis()
        ax2.grid(True, which="both", alpha=0.3)
        ax2.legend(fontsize=7)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
