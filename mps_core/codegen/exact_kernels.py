"""Exact-derivative kernels: the ``autodiff`` evaluation of one chart view as generated code.

The ``autodiff`` scheme of :mod:`mps_core.dynamics.engine` runs the chart's positions on second-order
jets (:mod:`mps_core.derivatives.jet`): exact, but every operation of every jet is a Python object and a
numpy call. For a chart whose ``flat`` positions can be traced (:mod:`mps_core.derivatives.tracing`) and
with at most two free coordinates, this module writes the same computation as straight-line
float code, once per (mechanism, chart view, traced program): forward-mode differentiation of
the traced program, each node carrying

* its value, its gradient ∂/∂q_i (n floats), and its first and second derivatives along q̇,
  d1 = Σ_i ∂_i · q̇_i and d2 = Σ_ij ∂_ij · q̇_i q̇_j (the convective part of its second time
  derivative, at q̈ = 0),

with known zeros and constants folded away. From the traced outputs (the points' coordinates)
the engine's linear map gives the named points, centres of mass and rotating bodies' link
vectors, and then, as in the jet evaluation,

* the angular analogs ω* = (r × ∂r)/|r|², and θ̈|q̈=0 = Im(r̈/r) − 2 Im(ṙ/r) Re(ṙ/r);
* A_ij = Σ m v*_G,i·v*_G,j + J ω*_i ω*_j and h_i = Σ m v*_G,i·G̈|q̈=0 + J ω*_i θ̈|q̈=0.

The kernel ``kernel(q…, q̇…)`` returns the positions, analogs and angular analogs at q (the
layout of :class:`~mps_core.dynamics.engine.Kinematics`), A (n = 1: a; n = 2: (a00, a01, a11)), h, and
θ̈|q̈=0 of every body. Where one of the trace's guards fails (the position function would take
another branch, or raise) it calls the position function at the point, which raises its own
error there, and otherwise raises :class:`~mps_core.derivatives.tracing.BranchChanged` (the caller
evaluates on jets).
"""

from __future__ import annotations

import json
import math

from ..caches import Memo
from ..derivatives.tracing import BranchChanged, TracingError, trace_at
from . import disk_cache
from .emitter import (
    COMPARE,
    MAX_N,
    Writer,
    function_key,
    inline_once,
    kernel_key,
    live_lines,
    load,
    view_arguments,
)


def trace_view(view, q):
    """(flat, tape, outputs, args, free): the chart's ``flat`` position function traced at
    ``q`` in ``view`` (:func:`~mps_core.derivatives.tracing.trace_at`); None where the chart has no
    ``flat`` positions, too many free coordinates, or a function that cannot be traced."""
    flat = getattr(view.chart, "flat", None)
    if flat is None or view.n > MAX_N:
        return None
    args, free = view_arguments(view, q)
    try:
        tape, outputs = trace_at(flat, args, free)
    except TracingError:
        return None
    return flat, tape, outputs, args, free


#: exact kernels by (the engine's tables and the view, the position function's key), for
#: engines made afresh (a benchmark's repeats, a batch): tried at q before a trace is made
_MADE = Memo("codegen.exact_kernels.made", 256)


def exact_kernel(engine, view, q):
    """The exact kernel of a chart view, traced at ``q`` (the point of the first evaluation),
    or None where the chart has no ``flat`` positions, too many free coordinates, or a position
    function that cannot be traced. A domain error of the position function at ``q`` goes to
    the caller (nothing is built; the next evaluation tries again). A kernel made before for
    the same tables, view and position function whose guards hold at ``q`` is taken again."""
    flat = getattr(view.chart, "flat", None)
    fkey = None if flat is None or view.n > MAX_N else function_key(flat)
    made_key = None if fkey is None else (kernel_key(engine, view), fkey)
    if made_key is not None:
        ql = [float(x) for x in q]
        for k in _MADE.get(made_key, ()):
            try:
                k(*ql, *[0.0] * view.n)
            except BranchChanged:
                continue
            return k
    kernel = _trace_and_load(engine, view, q)
    if kernel is not None and made_key is not None:
        known = _MADE.get(made_key)
        if known is None:
            known = _MADE.keep(made_key, [])
        known.insert(0, kernel)
        del known[8:]
    return kernel


def _trace_and_load(engine, view, q):
    traced = trace_view(view, q)
    if traced is None:
        return None
    flat, tape, outputs, args, free = traced
    key = ("exact", kernel_key(engine, view), tape.key(), tuple(outputs))
    kernel = load(
        key,
        lambda: _source(engine, view, tape, outputs, args, free, key),
        f"<exact kernel {view.name}>",
        flat,
        view.name,
    )
    kernel.key = key
    kernel.parts = lambda: kernel_parts(engine, view, tape, outputs, args, free, key)
    return kernel


class Forward:
    """Code for one node's (value, gradient, d1, d2); each component is None (zero), a float
    (a constant) or a local's name."""

    def __init__(self, w: Writer, n: int):
        self.w, self.n = w, n
        #: locals that are the negation of another: folded where IEEE arithmetic makes it
        #: exact (−(−x) = x, a + (−x) = a − x, a − (−x) = a + x, c·(−x) = (−c)·x)
        self.negs: dict = {}

    # -- components ------------------------------------------------------------------------
    @staticmethod
    def _s(x) -> str:
        return repr(x) if isinstance(x, float) else x

    def add(self, a, b):
        if a is None or a == 0.0:
            return b
        if b is None or b == 0.0:
            return a
        if isinstance(a, float) and isinstance(b, float):
            return a + b
        negs = self.negs
        if isinstance(b, str) and b in negs:
            return self.sub(a, negs[b])
        if isinstance(a, str) and a in negs:
            return self.sub(b, negs[a])
        a, b = sorted((self._s(a), self._s(b)))  # a + b == b + a exactly
        return self.w.let(f"{a} + {b}")

    def sub(self, a, b):
        if b is None or b == 0.0:
            return a
        if a is None or a == 0.0:
            return self.neg(b)
        if isinstance(a, float) and isinstance(b, float):
            return a - b
        if isinstance(b, str) and b in self.negs:
            return self.add(a, self.negs[b])
        return self.w.let(f"{self._s(a)} - {self._s(b)}")

    def neg(self, a):
        if a is None:
            return None
        if isinstance(a, float):
            return -a
        if a in self.negs:
            return self.negs[a]
        name = self.w.let(f"-{a}")
        if name != a:
            self.negs[name] = a
        return name

    def mul(self, a, b):
        if a is None or b is None or a == 0.0 or b == 0.0:
            return None
        if isinstance(a, float) and isinstance(b, float):
            return a * b
        if a == 1.0:
            return b
        if b == 1.0:
            return a
        if a == -1.0:
            return self.neg(b)
        if b == -1.0:
            return self.neg(a)
        if isinstance(b, float):
            a, b = b, a
        elif not isinstance(a, float) and b < a:
            a, b = b, a  # a·b == b·a exactly
        negs = self.negs
        if b in negs:
            if isinstance(a, float):
                return self.mul(-a, negs[b])  # c·(−x) == (−c)·x exactly
            if a in negs:
                return self.mul(negs[a], negs[b])  # (−x)·(−y) == x·y exactly
        return self.w.let(f"{self._s(a)} * {self._s(b)}")

    def call(self, fn: str, a):
        if isinstance(a, float):
            return getattr(math, fn)(a)
        return self.w.let(f"{fn}({a})")

    def recip(self, a):
        if isinstance(a, float):
            return 1.0 / a
        return self.w.let(f"1.0 / {a}")

    # -- nodes -------------------------------------------------------------------------------
    def constant(self, c: float):
        return (c, [None] * self.n, None, None)

    def node(self, op: str, x, y=None):
        add, sub, mul, neg = self.add, self.sub, self.mul, self.neg
        va, ga, d1a, d2a = x
        if op in ("add", "sub"):
            f = add if op == "add" else sub
            vb, gb, d1b, d2b = y
            return (f(va, vb), [f(p, r) for p, r in zip(ga, gb)], f(d1a, d1b), f(d2a, d2b))
        if op == "neg":
            return (neg(va), [neg(p) for p in ga], neg(d1a), neg(d2a))
        if op == "mul":
            vb, gb, d1b, d2b = y
            v = mul(va, vb)
            g = [add(mul(p, vb), mul(va, r)) for p, r in zip(ga, gb)]
            d1 = add(mul(d1a, vb), mul(va, d1b))
            d2 = add(add(mul(d2a, vb), mul(2.0, mul(d1a, d1b))), mul(va, d2b))
            return (v, g, d1, d2)
        if op == "div":
            vb, gb, d1b, d2b = y
            ib = self.recip(vb)
            u = mul(va, ib)
            if isinstance(vb, float) or (all(r is None for r in gb) and d1b is None and d2b is None):
                return (u, [mul(p, ib) for p in ga], mul(d1a, ib), mul(d2a, ib))
            # u = a/b: u' = (a' − u b')/b, u'' = (a'' − 2 u' b' − u b'')/b
            g = [mul(sub(p, mul(u, r)), ib) for p, r in zip(ga, gb)]
            d1 = mul(sub(d1a, mul(u, d1b)), ib)
            d2 = mul(sub(sub(d2a, mul(2.0, mul(d1, d1b))), mul(u, d2b)), ib)
            return (u, g, d1, d2)
        if op in ("cos", "sin"):
            c, s = self.call("cos", va), self.call("sin", va)
            if op == "cos":
                v, dv, ddv = c, neg(s), neg(c)  # f, f', f''
            else:
                v, dv, ddv = s, c, neg(s)
            g = [mul(dv, p) for p in ga]
            d1 = mul(dv, d1a)
            d2 = add(mul(dv, d2a), mul(ddv, mul(d1a, d1a)))
            return (v, g, d1, d2)
        if op == "sqrt":
            r = self.call("sqrt", va)
            ir = self.recip(r)
            ih = mul(0.5, ir)
            g = [mul(p, ih) for p in ga]
            d1 = mul(d1a, ih)
            # r'' = (½a'' − r'²)/r
            d2 = mul(sub(mul(0.5, d2a), mul(d1, d1)), ir)
            return (r, g, d1, d2)
        raise TracingError(f"operation {op!r}")


def forward(w: Writer, n: int, tape, outputs, args, free, cls=None) -> tuple:
    """(fw, outs): code of the traced program run forward on (value, gradient, d1, d2), the
    guards written as soon as their operands exist; ``outs`` are the traced outputs' tuples.
    The generated function's arguments are ``q0…`` and ``vd0…`` (q̇). ``cls``: the
    :class:`Forward` (sub)class that writes the code."""
    fw = (cls or Forward)(w, n)
    qs = [f"q{k}" for k in range(n)]
    vs = [f"vd{k}" for k in range(n)]  # q̇ (v0, v1, … are the writer's locals)
    # the position function's arguments as code, for a failed guard's call
    call = [qs[free[pos]] if pos in free else repr(a) for pos, a in enumerate(args)]
    # guards are written as soon as their operands exist
    pending: dict[int, list[tuple]] = {}
    for g in tape.guards:
        a, op, b, outcome = g
        last = max([x for x in (a, b) if isinstance(x, int)], default=-1)
        pending.setdefault(last, []).append(g)
    vals: list = []

    def operand(x):
        return fw.constant(x) if isinstance(x, float) else vals[x]

    for i, node in enumerate(tape.nodes):
        if node[0] == "input":
            k = node[1]
            vals.append((qs[k], [1.0 if j == k else None for j in range(n)], vs[k], None))
        else:
            vals.append(fw.node(node[0], *[operand(x) for x in node[1:]]))
        for a, op, b, outcome in pending.get(i, ()):
            va, vb = operand(a)[0], operand(b)[0]
            if isinstance(va, float) and isinstance(vb, float):
                continue
            test = f"{fw._s(va)} {COMPARE[op]} {fw._s(vb)}"
            # "not (a > b)" also catches NaN
            w.lines.append(f"    if {'not ' if outcome else ''}{test}: _miss({', '.join(call)})")
    return fw, [operand(x) for x in outputs]


def linear_parts(engine, fw: Forward, outs):
    """(val, grad, d1, d2): functions of a row of the engine's linear map (pairs of names,
    links, check) giving the code of that row's value, i-th gradient, d1 and d2."""
    M = engine.tables.MT.T

    def lin(row, part):
        """Σ M[row, k] · part of output k."""
        acc = None
        for k, c in enumerate(M[row].tolist()):
            if c != 0.0:
                acc = fw.add(acc, fw.mul(float(c), part(outs[k])))
        return acc

    return (
        lambda row: lin(row, lambda o: o[0]),
        lambda row, i: lin(row, lambda o: o[1][i]),
        lambda row: lin(row, lambda o: o[2]),
        lambda row: lin(row, lambda o: o[3]),
    )


def angular(engine, fw: Forward, n: int, parts) -> tuple[dict, dict]:
    """({(body, i): ω*_i}, {body: θ̈ at q̈ = 0}) of the rotating bodies, as code, from their
    link vectors' rows (``parts``: :func:`linear_parts`)."""
    val, grad, d1, d2 = parts
    add, sub, mul = fw.add, fw.sub, fw.mul
    NP = engine.tables.npoints
    omega = {}
    theta2 = {}
    for j, k in enumerate(engine.tables.rot):
        r = 2 * NP + 2 * j
        rx, ry = val(r), val(r + 1)
        irr = fw.recip(add(mul(rx, rx), mul(ry, ry)))
        for i in range(n):
            gx, gy = grad(r, i), grad(r + 1, i)
            omega[k, i] = mul(sub(mul(rx, gy), mul(ry, gx)), irr)
        ax, ay = d1(r), d1(r + 1)
        w1 = mul(sub(mul(rx, ay), mul(ry, ax)), irr)
        dot1 = mul(add(mul(rx, ax), mul(ry, ay)), irr)
        bx, by = d2(r), d2(r + 1)
        theta2[k] = sub(mul(sub(mul(rx, by), mul(ry, bx)), irr), mul(2.0, mul(w1, dot1)))
    return omega, theta2


def _source(engine, view, tape, outputs, args, free, key=None) -> str:
    lines, xl, jl, wl, A, h, conv = kernel_parts(engine, view, tape, outputs, args, free, key)
    n = view.n
    qs = [f"q{k}" for k in range(n)]
    vs = [f"vd{k}" for k in range(n)]
    A_out = A[0] if n == 1 else f"({A[0]}, {A[1]}, {A[2]})"
    ret = (
        f"    return [{', '.join(xl)}], [{', '.join(jl)}], [{', '.join(wl)}], {A_out}, "
        f"[{', '.join(h)}], [{', '.join(conv)}]"
    )
    return (
        f"def kernel({', '.join(qs + vs)}):\n" + "\n".join(inline_once(live_lines(lines, ret) + [ret])) + "\n"
    )


#: kernel_parts by the exact kernel's key
_PARTS = Memo("codegen.exact_kernels.parts", 1024)


def kernel_parts(engine, view, tape, outputs, args, free, key=None) -> tuple:
    """(lines, xl, jl, wl, A, h, conv): the exact kernel's body (its code lines) and, as code
    (a local's name or a float literal), each number it returns: the positions, analogs and
    angular analogs (the layout of :class:`~mps_core.dynamics.engine.Kinematics`), A's entries
    (n = 1: a; n = 2: a00, a01, a11), h, and θ̈ at q̈ = 0 of every body followed by every
    centre of mass's (ẍ, ÿ) at q̈ = 0. Kept by ``key`` (in the process, and on disk:
    :mod:`~mps_core.codegen.disk_cache`)."""
    if key is not None and key in _PARTS:
        return _PARTS[key]
    entry = None if key is None else disk_cache.entry("exact kernel parts", key)
    parts = None if entry is None else _parts_from(entry.read())
    if parts is None:
        parts = _parts(engine, view, tape, outputs, args, free)
        disk_cache.COUNTS["generated"] += 1
        if entry is not None:
            entry.write([json.dumps(parts).encode()])
    if key is not None:
        _PARTS.keep(key, parts)
    return parts


def _parts_from(items) -> tuple | None:
    """Return kernel_parts from a disk cache entry's items (seven lists of code), or None."""
    if items is None or len(items) != 1:
        return None
    try:
        parts = json.loads(items[0])
    except ValueError:
        return None
    if not (
        isinstance(parts, list)
        and len(parts) == 7
        and all(isinstance(p, list) and all(isinstance(x, str) for x in p) for p in parts)
    ):
        return None
    return tuple(parts)


def _parts(engine, view, tape, outputs, args, free) -> tuple:
    n = view.n
    w = Writer()
    fw, outs = forward(w, n, tape, outputs, args, free)
    val, grad, d1, d2 = linear_parts(engine, fw, outs)

    NP = engine.tables.npoints
    mech = engine.mechanism

    def code(x):
        return "0.0" if x is None else fw._s(x)

    add, mul = fw.add, fw.mul
    rot = engine.tables.rot
    mass, inertia = engine.tables.mass.tolist(), engine.tables.inertia.tolist()
    nb = len(mech.bodies)
    omega, theta2 = angular(engine, fw, n, (val, grad, d1, d2))
    com = [2 * engine.tables.names[f"G_{b.name}"] for b in mech.bodies]

    def weighted(pairs):
        """Σ c·x·y over (c, x, y), equal products once with their weights added."""
        terms: dict = {}
        for c, x, y in pairs:
            if c == 0.0 or x is None or y is None:
                continue
            key = tuple(sorted((fw._s(x), fw._s(y))))
            if key in terms:
                terms[key] = (terms[key][0] + c, x, y)
            else:
                terms[key] = (c, x, y)
        acc = None
        for c, x, y in terms.values():
            acc = add(acc, mul(c, mul(x, y)))
        return acc

    A = {}
    h = []
    for i in range(n):
        h.append(
            weighted(
                [(mass[k], grad(com[k] + c, i), d2(com[k] + c)) for k in range(nb) for c in (0, 1)]
                + [(inertia[k], omega.get((k, i)), theta2[k]) for k in rot]
            )
        )
        for jj in range(i, n):
            A[i, jj] = weighted(
                [(mass[k], grad(com[k] + c, i), grad(com[k] + c, jj)) for k in range(nb) for c in (0, 1)]
                + [(inertia[k], omega.get((k, i)), omega.get((k, jj))) for k in rot]
            )
    offset = engine.tables.offset.tolist() if engine.tables.offset is not None else [0.0] * (2 * NP)
    xl = [code(add(val(r), offset[r] or None)) for r in range(2 * NP)]
    jl = [code(grad(2 * r + c, i)) for r in range(NP) for c in (0, 1) for i in range(n)]
    wl = [code(omega.get((k, i))) for k in range(nb) for i in range(n)]
    # θ̈ at q̈ = 0 of every body, then the centres of mass' accelerations at q̈ = 0 (x, y a
    # body): the motion a reaction kernel reads from the kinematics (computed for h anyway)
    conv = [code(theta2.get(k)) for k in range(nb)] + [
        code(d2(com[k] + c)) for k in range(nb) for c in (0, 1)
    ]
    A_out = [code(A[0, 0])] if n == 1 else [code(A[0, 0]), code(A[0, 1]), code(A[1, 1])]
    return (list(w.lines), xl, jl, wl, A_out, [code(x) for x in h], conv)
