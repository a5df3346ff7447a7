"""Scalar kernels: the central-difference evaluation of one chart view as generated Python code.

For the small charts a linkage integrates (one or two free coordinates) the arithmetic of an
evaluation is a few hundred floating-point operations; numpy's per-call cost, not the
arithmetic, is what the array code of :mod:`mps_core.dynamics.engine` pays. A kernel does the same
computation on Python floats, in straight-line code written once per (mechanism, chart view,
Δ) from the engine's own tables, so nothing in it is specific to a mechanism:

* the chart's ``flat`` position function at each point of the stencil (the same stencil, with
  the same displacements);
* the analogs at the stencil's base points as differences ``(r(q + Δe_i) − r(q − Δe_i))/2Δ_i``
  of the points' coordinates, mapped to the centres of mass and the rotating bodies' link
  vectors by the nonzero entries of the engine's linear map (terms with a zero coefficient, and
  the fixed points' coordinates, are left out of the code);
* the angular analogs ω* = (r × v*)/|r|² of the rotating bodies;
* the mass matrix at every base point: A_ij = Σ m v*_G,i·v*_G,j + J ω*_i ω*_j.

Written from a trace of ``flat`` (:mod:`mps_core.derivatives.tracing`) the kernel also has the position
function's program inline at each stencil point, with its constant outputs folded in, instead
of calling it; the calling kernel remains for points where the trace does not hold.

``kernel(q…, q̇…)`` returns the positions, analogs and angular analogs at q (flat lists, the
layout of :class:`~mps_core.dynamics.engine.Kinematics`), A at q (n = 1: a; n = 2: (a00, a01, a11)),
the velocity terms h by central differences of A (the array code's formulas, written out) and
the angular analogs at the other base points (for the bodies' convective angular
accelerations by the same central differences, which reports use); the engine adds the
generalized forces and the solve. The
numbers are those of the array code up to the order of floating-point operations (a test
compares them to round-off).
"""

from __future__ import annotations

import math

import numpy as np

from ..derivatives.stencil import stencil
from ..derivatives.tracing import TracingError, trace_at
from .emitter import (
    COMPARE,
    INFIX,
    MAX_N,
    Writer,
    inline_once,
    kernel_key,
    live_lines,
    load,
    view_arguments,
)


def _lin(coefs, var) -> str | None:
    """Σ coef·var(k) over the nonzero coefficients, as code (None when all are zero)."""
    terms = []
    for k, c in enumerate(coefs):
        if c == 0.0:
            continue
        v = var(k)
        if v is None:
            continue
        if c == 1.0:
            terms.append(("+", v))
        elif c == -1.0:
            terms.append(("-", v))
        else:
            terms.append(("+", f"{float(c)!r} * {v}"))
    if not terms:
        return None
    out = terms[0][1] if terms[0][0] == "+" else f"-{terms[0][1]}"
    for sign, v in terms[1:]:
        out += f" {sign} {v}"
    return out


def central_kernel(engine, view, plan, q=None):
    """The kernel of a chart view for ``engine`` (central differences), or None where the chart
    has no ``flat`` positions or too many free coordinates.

    Without ``q`` the kernel calls ``flat`` at each stencil point. With ``q`` (a point of the
    chart's domain) ``flat`` is traced there (:mod:`mps_core.derivatives.tracing`) and its program written
    out at each stencil point instead: the same operations without the calls, the constant
    outputs (fixed points) folded in. Where a stencil point fails one of the trace's guards,
    that kernel calls ``flat`` there (its own domain error) or raises
    :class:`~mps_core.derivatives.tracing.BranchChanged` (the caller then uses the calling kernel).
    None where ``flat`` cannot be traced."""
    flat = getattr(view.chart, "flat", None)
    n = view.n
    if flat is None or n > MAX_N:
        return None
    traced = None
    if q is not None:
        args, free = view_arguments(view, q)
        try:
            traced = trace_at(flat, args, free)
        except TracingError:
            return None
        key = (kernel_key(engine, view, plan), traced[0].key(), tuple(traced[1]))
    else:
        key = kernel_key(engine, view, plan)
    return load(key, lambda: _source(engine, view, plan, traced), f"<kernel {view.name}>", flat, view.name)


def _unit(x) -> bool:
    """x is the constant 1.0 (an operand: a node's index, int, or a constant, float)."""
    return isinstance(x, float) and x == 1.0


def _inline(w: Writer, tape, outputs, inputs: list, call: list) -> list:
    """Code for one call of a traced function: ``inputs`` the traced arguments as code (by input
    number), ``call`` the whole argument list as code (for a failed guard's call). Returns the
    outputs, each a local's name or a float."""
    vals: list = []
    pending: dict = {}
    for g in tape.guards:
        last = max([x for x in (g[0], g[2]) if isinstance(x, int)], default=-1)
        pending.setdefault(last, []).append(g)

    def code(x):
        v = vals[x] if isinstance(x, int) else x
        return repr(v) if isinstance(v, float) else v

    for i, node in enumerate(tape.nodes):
        op = node[0]
        if op == "input":
            vals.append(inputs[node[1]])
        elif op == "mul" and _unit(node[1]) and isinstance(node[2], int):
            vals.append(vals[node[2]])  # 1.0·x is x, bit for bit (NaN, ±inf too)
        elif op == "mul" and _unit(node[2]) and isinstance(node[1], int):
            vals.append(vals[node[1]])
        elif op in INFIX:
            vals.append(w.let(f"{code(node[1])} {INFIX[op]} {code(node[2])}"))
        elif op == "neg":
            vals.append(w.let(f"-{code(node[1])}"))
        else:
            vals.append(w.let(f"{op}({code(node[1])})"))
        for a, cmp, b, outcome in pending.get(i, ()):
            test = f"{code(a)} {COMPARE[cmp]} {code(b)}"
            # "not (a > b)" also catches NaN
            w.lines.append(f"    if {'not ' if outcome else ''}{test}: _miss({', '.join(call)})")
    return [vals[o] if isinstance(o, int) else o for o in outputs]


def _source(engine, view, plan, traced=None) -> str:
    """The kernel's Python source (see the module's docstring).

    The differences are left unscaled inside: ω̃ = (r × Δr)/|r|² and A_ij = Σ m ΔG_i·ΔG_j +
    J ω̃_i ω̃_j are scaled once by 1/2Δ_i (1/(4Δ_iΔ_j) for A); equal products (centres of mass
    at the same point) are summed with their masses added. One step a function: the stencil's
    positions, each stencil base's angular analogs and A, the lists at q, the velocity terms."""
    n = view.n
    w = Writer()
    qs = [f"q{k}" for k in range(n)]
    st = _Stencil(engine, view, plan, w, _positions(engine, view, plan, w, qs, traced))
    omegas, out_A = [], []
    for b in range(1 + 2 * n):
        om = _angular_analogs(st, b)
        omegas.append(om)
        out_A.append(_mass_matrix(st, b, om))
    xl, jl, wls = _lists_at_q(st, omegas)
    A_out = _velocity_terms(w.lines, out_A, plan.inv2d, n)
    vds = [f"vd{k}" for k in range(n)]
    ret = f"    return [{', '.join(xl)}], [{', '.join(jl)}], {wls[0]}, {A_out}, _h, [{', '.join(wls[1:])}]"
    return (
        f"def kernel({', '.join(qs + vds)}):\n"
        + "\n".join(inline_once(live_lines(w.lines, ret) + [ret]))
        + "\n"
    )


def _positions(engine, view, plan, w, qs, traced) -> list:
    """The stencil's positions: P[s][k] the point coordinate k at stencil point s (a local's
    name, or a float where the position function gives a constant)."""
    n, npts = view.n, engine.tables.npts
    offsets = stencil(n)[0]
    d = plan.d.tolist()
    args_free = {i: k for k, i in enumerate(view.free)}
    P = []
    for s, off in enumerate(offsets.tolist()):
        args, inputs = [], []
        for ci in range(view.chart.size):
            if ci in args_free:
                k = args_free[ci]
                o = off[k] * d[k]
                a = qs[k] if o == 0.0 else f"{qs[k]} + {o!r}"
                if traced is not None:
                    a = w.let(a)
                    inputs.append(a)
                args.append(a)
            else:
                args.append(repr(float(view._template[ci])))
        if traced is None:
            names = [f"p{s}_{k}" for k in range(2 * npts)]
            w.lines.append(f"    {', '.join(names)}, = F({', '.join(args)})")
            P.append(names)
        else:
            P.append(_inline(w, traced[0], traced[1], inputs, args))
    return P


class _Stencil:
    """A chart view's stencil written as code: values of M's rows at a stencil point and their
    unscaled central differences, each a local (or None for a zero)."""

    def __init__(self, engine, view, plan, w, P):
        self.engine, self.n, self.w, self.P = engine, view.n, w, P
        _offsets, self.plus, self.minus = stencil(view.n)
        self.inv2d = plan.inv2d
        self.M = engine.tables.MT.T  # rows: pairs (x, y) of names, links, check
        fixed = {engine.tables.names[p] for p in getattr(engine.mechanism, "fixed_points", ())}
        self.moving = {k for k in range(2 * engine.tables.npts) if k // 2 not in fixed}

    def diff(self, b, i, row):
        """Unscaled analog 2Δ_i·∂r/∂q_i of M's row at base b (a local's name, or None)."""
        P, w = self.P, self.w

        def var(k):
            a, c = P[self.plus[b, i]][k], P[self.minus[b, i]][k]
            if k not in self.moving:
                return None
            if isinstance(a, float) and isinstance(c, float):
                return None if a == c else repr(a - c)
            return w.let(
                f"{a!r} - {c}"
                if isinstance(a, float)
                else f"{a} - {c!r}"
                if isinstance(c, float)
                else f"{a} - {c}"
            )

        e = _lin(self.M[row], var)
        return None if e is None else w.let(e)

    def value(self, b, row):
        P = self.P

        def var(k):
            a = P[b][k]
            if isinstance(a, float):
                return None if a == 0.0 else repr(a)
            return a

        e = _lin(self.M[row], var)
        return None if e is None else self.w.let(e)

    def scaled(self, x, i):
        return "0.0" if x is None else self.w.let(f"{x} * {self.inv2d[i]!r}")


def _angular_analogs(st: _Stencil, b: int) -> dict:
    """At stencil base b, each rotating body's unscaled angular analogs ω̃ (body, i)."""
    w, NP = st.w, st.engine.tables.npoints
    om = {}
    for j, k in enumerate(st.engine.tables.rot):
        r = 2 * NP + 2 * j
        rx, ry = st.value(b, r) or "0.0", st.value(b, r + 1) or "0.0"
        irr = w.let(f"1.0 / ({rx} * {rx} + {ry} * {ry})")
        for i in range(st.n):
            jx, jy = st.diff(b, i, r), st.diff(b, i, r + 1)
            if jx is None and jy is None:
                continue
            if jx is None:
                cross = f"{rx} * {jy}"
            elif jy is None:
                cross = f"-{ry} * {jx}"
            else:
                cross = f"{rx} * {jy} - {ry} * {jx}"
            om[k, i] = w.let(f"({cross}) * {irr}")
    return om


def _mass_matrix(st: _Stencil, b: int, om: dict) -> list:
    """At stencil base b, A's upper entries (row by row), scaled."""
    engine, n, inv2d = st.engine, st.n, st.inv2d
    mech, rot = engine.mechanism, engine.tables.rot
    mass, inertia = engine.tables.mass.tolist(), engine.tables.inertia.tolist()
    com_rows = [engine.tables.names[f"G_{body.name}"] for body in mech.bodies]
    entries = []
    for i in range(n):
        for jj in range(i, n):
            terms: dict = {}
            for k in range(len(mech.bodies)):
                r = 2 * com_rows[k]
                if mass[k] != 0.0:
                    for c in (0, 1):
                        a1, a2 = st.diff(b, i, r + c), st.diff(b, jj, r + c)
                        if a1 is not None and a2 is not None:
                            key = (a1, a2)
                            terms[key] = terms.get(key, 0.0) + mass[k]
                if k in rot and inertia[k] != 0.0:
                    w1, w2 = om.get((k, i)), om.get((k, jj))
                    if w1 is not None and w2 is not None:
                        terms[w1, w2] = terms.get((w1, w2), 0.0) + inertia[k]
            body = " + ".join(f"{c!r} * {x} * {y}" for (x, y), c in terms.items())
            entries.append(st.w.let(f"({body or '0.0'}) * {inv2d[i] * inv2d[jj]!r}"))
    return entries


def _lists_at_q(st: _Stencil, omegas: list) -> tuple[list, list, list]:
    """Positions, analogs and angular analogs at q (the stencil's base 0), and the angular
    analogs' lists of every base."""
    engine, n, NP = st.engine, st.n, st.engine.tables.npoints
    rot, nbodies = engine.tables.rot, len(engine.mechanism.bodies)
    xl = []
    offset = engine.tables.offset.tolist() if engine.tables.offset is not None else None
    for r in range(2 * NP):
        e = st.value(0, r) or "0.0"
        if offset is not None and offset[r] != 0.0:
            e = f"{e} + {offset[r]!r}"
        xl.append(e)
    jl = [st.scaled(st.diff(0, i, 2 * r + c), i) for r in range(NP) for c in (0, 1) for i in range(n)]

    def omega_list(om):
        return (
            "["
            + ", ".join(
                st.scaled(om.get((k, i)), i) if k in rot else "0.0" for k in range(nbodies) for i in range(n)
            )
            + "]"
        )

    return xl, jl, [omega_list(om) for om in omegas]


def _velocity_terms(L: list, out_A: list, inv2d, n: int) -> str:
    """The velocity terms from A's central differences, written to ``L``: h_i = Σ_jk ∂_k A_ij
    q̇_j q̇_k − ½ Σ_jk ∂_i A_jk q̇_j q̇_k, r_kj = Σ_l ∂_k A_jl q̇_l; A at q, as returned."""
    c = [repr(x) for x in inv2d]
    if n == 1:
        L.append(f"    _d = ({out_A[1][0]} - {out_A[2][0]}) * {c[0]}")
        L.append("    _h = [0.5 * _d * vd0 * vd0]")
        return out_A[0][0]
    for k in range(2):
        p, m = out_A[1 + 2 * k], out_A[2 + 2 * k]
        L.append(
            f"    _d{k}00, _d{k}01, _d{k}11 = ({p[0]} - {m[0]}) * {c[k]}, "
            f"({p[1]} - {m[1]}) * {c[k]}, ({p[2]} - {m[2]}) * {c[k]}"
        )
    L += [
        "    _r00 = _d000 * vd0 + _d001 * vd1",
        "    _r01 = _d001 * vd0 + _d011 * vd1",
        "    _r10 = _d100 * vd0 + _d101 * vd1",
        "    _r11 = _d101 * vd0 + _d111 * vd1",
        "    _h = [_r00 * vd0 + _r10 * vd1 - 0.5 * (_r00 * vd0 + _r01 * vd1), "
        "_r01 * vd0 + _r11 * vd1 - 0.5 * (_r10 * vd0 + _r11 * vd1)]",
    ]
    return f"({', '.join(out_A[0])})"


def solve_given_h(A, h, Q) -> list:
    """q̈ from A (n = 1: a; n = 2: (a00, a01, a11)), h and Q, on floats; NaN where A is
    singular."""
    if len(h) == 1:
        try:
            return [(Q[0] - h[0]) / A]
        except ZeroDivisionError:
            return [math.nan]
    a00, a01, a11 = A
    r0, r1 = Q[0] - h[0], Q[1] - h[1]
    det = a00 * a11 - a01 * a01
    try:
        return [(r0 * a11 - a01 * r1) / det, (a00 * r1 - a01 * r0) / det]
    except ZeroDivisionError:
        return [math.nan, math.nan]


def as_matrix(A, n: int) -> np.ndarray:
    if n == 1:
        return np.array([[A]])
    a00, a01, a11 = A
    return np.array([[a00, a01], [a01, a11]])
