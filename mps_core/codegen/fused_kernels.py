"""One generated function per chart view: q̈ from (t, q, q̇), the scene's effects traced in.

An exact kernel (:mod:`mps_core.codegen.exact_kernels`) gives the kinematics, A and h of a chart view
as straight-line float code; the engine then asks each effect for its generalized force
through a :class:`~mps_core.dynamics.engine.Kinematics` and solves A q̈ = Q − h. Here the whole of it is
one function ``kernel(t, q…, q̇…) -> [q̈…]``:

* the exact kernel's body, as it is;
* the effects' generalized forces: each effect's ``generalized_force`` (or the virtual work of
  its ``loads``) is called once on a :class:`~mps_core.dynamics.engine.Kinematics` whose numbers are
  :class:`~mps_core.derivatives.tracing.Traced` (the kernel's positions, analogs, angular analogs, q̇ and
  t), with the engine's own summation and solve after it, so that the tape holds the same
  operations on floats in the same order (the result is the general path's q̈ bit for bit,
  but for the sign of a zero); the effect's parameters and the controls it reads are folded
  in as constants, and its comparisons become guards;
* the solve, and a finiteness check.

Only the effects the scene names are in the code, and only the branches of their laws taken
at the traced point. A ``live`` effect's values (an estimator's unknown inputs, changed in place
at every measurement) are not folded in: the code reads them from the effect's list at each
call (``_live0[k]``…, bound in the function's namespace), so such a function is its engine's
alone (the effects' fingerprint is None). Where a guard fails the function raises
:class:`~mps_core.derivatives.tracing.BranchChanged` (a guard of the kinematics) or
:class:`ForceLawBranch` (one of a force law); where the result is not finite it returns None:
the caller evaluates by the general path, which gives the answer or the error there.
An effect whose law does something a trace cannot hold (a call of ``math`` on the state, a
numpy array) leaves the view without a fused function.

With the seed's central differences the kinematics come from a central kernel (a stencil of
position points, :mod:`mps_core.codegen.kernels`), which stays a call of its own; what follows it, the
effects and the solve, is traced the same way into ``tail(t, q̇…, xl, jl, wl, A, h)`` reading
the central kernel's lists by index (:func:`central_tail`): the effects' calls one by one
become one generated call, with the same numbers.

The code depends on the effects' parameters and the controls at the time it is made: the
engine's :class:`~mps_core.model.effects.base.Version` moves at every assignment to them, and
the engine makes the function again when it has moved (each engine has its own counter).
"""

from __future__ import annotations

import math

import numpy as np

from ..caches import Memo
from ..derivatives.tracing import OPS, BranchChanged, Tape, Traced
from .emitter import COMPARE, INFIX, inline_once, kernel_key, live_lines, load
from .kernels import solve_given_h


class ForceLawBranch(BranchChanged):
    """A force law's guard failed (its kinematics held): the exact kernel still holds here."""


_CONSTANTS = Memo("codegen.fused_kernels.constants", 65536)


def _constant(code: str):
    """The float a code atom is (a literal), or None (a local's name)."""
    try:
        return _CONSTANTS[code]
    except KeyError:
        pass
    try:
        c = float(code)
    except ValueError:
        c = None
    return _CONSTANTS.keep(code, c)


class _Unhashable(Exception):
    pass


_ATOMS = frozenset((type(None), bool, int, float, str))


def _frozen(x):
    t = type(x)
    if t in _ATOMS:
        return x
    if t is tuple or t is list:
        return tuple([y if type(y) in _ATOMS else _frozen(y) for y in x])
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    if isinstance(x, (tuple, list)):
        return tuple(_frozen(y) for y in x)
    if isinstance(x, dict):
        return tuple(sorted((k, _frozen(v)) for k, v in x.items()))
    if isinstance(x, np.ndarray):
        return ("array", x.dtype.str, x.shape, x.tobytes())
    if getattr(type(x), "__dataclass_params__", None) is not None and type(x).__dataclass_params__.frozen:
        return x
    raise _Unhashable(type(x).__name__)


_FINGERPRINTS = Memo("codegen.fused_kernels.fingerprints", 4096)


#: attributes of an effect that are not what a trace folds in: the controls (taken apart) and
#: the counters watching it (:class:`~mps_core.model.effects.base.Watched`)
_NOT_STATE = ("controls", "_watchers")


def _state_of(obj) -> dict:
    return {k: v for k, v in vars(obj).items() if k != "_watchers"}


def fingerprint(effects):
    """Everything a trace of ``effects`` can fold in: each effect's class and attributes and
    the controls it reads, as a number (the same for equal effects, never given to others);
    None where an attribute is something else (a mutable object), or an effect is ``live``
    (its code reads that engine's values): the code is not shared between engines then."""
    if any(getattr(e, "live", False) for e in effects):
        return None
    try:
        out = []
        for e in effects:
            attrs = vars(e)
            c = attrs.get("controls")
            out.append(
                (
                    type(e),
                    tuple(sorted((k, _frozen(v)) for k, v in attrs.items() if k not in _NOT_STATE)),
                    None if c is None else _frozen(_state_of(c)),
                )
            )
    except _Unhashable:
        return None
    key = tuple(out)
    number = _FINGERPRINTS.get(key)
    if number is None:
        _FINGERPRINT_SERIAL[0] += 1  # numbers stay unique past a clear: they only grow
        number = _FINGERPRINTS.keep(key, _FINGERPRINT_SERIAL[0])
    return number


_FINGERPRINT_SERIAL = [0]


#: fused functions by (exact kernel's key, effects' fingerprint), for engines made afresh
#: (a benchmark's repeats, a batch): tried at the state before a trace is made
_MADE = Memo("codegen.fused_kernels.made", 256)


def reuse_or_make(engine, view, exact, t, ql, vl, kinematics, virtual_work):
    """A fused function for ``view`` at (t, q, q̇): one made before for the same kinematics
    and the same effects whose guards hold here, else a new one (:func:`fused_kernel`)."""
    fp = engine.fingerprint()
    return _reused(
        _MADE,
        None if fp is None else (exact.serial, fp),
        lambda k: k(t, *ql, *vl),
        lambda: fused_kernel(engine, view, exact, t, ql, vl, kinematics, virtual_work),
    )


def _reused(cache: Memo, key, trial, make):
    """A function kept in ``cache`` under ``key`` whose ``trial(fn)`` holds here (no failed
    guard, a result), else ``make()``'s, kept there first (up to eight a key)."""
    for k in cache.get(key, ()) if key is not None else ():
        try:
            if trial(k) is not None:
                return k
        except (BranchChanged, ArithmeticError, ValueError):
            continue
    made = make()
    if made is not None and key is not None:
        known = cache.get(key)
        if known is None:
            known = cache.keep(key, [])
        if all(k.source != made.source for k in known):
            known.insert(0, made)
            del known[8:]
    return made


def input_slot(tape, slots: list):
    """``slot(code, value)``: a new input of ``tape``, read as ``code`` in the generated
    function (kept in ``slots``), traced at ``value``."""

    def slot(code: str, value: float):
        tape.nodes.append(("input", len(slots)))
        slots.append(code)
        return Traced(tape, len(tape.nodes) - 1, float(value))

    return slot


#: the prefix of the names a ``live`` effect's list of values is bound under in a generated
#: function's namespace (``_live0``, ``_live1``…)
LIVE = "_live"


def live_inputs(effect, slot, lives: dict) -> list:
    """Return a ``live`` effect's values as inputs of a trace (read ``_live{j}[k]`` at each call),
    its list bound in ``lives`` under ``_live{j}`` for the function's namespace."""
    name = f"{LIVE}{len(lives)}"
    lives[name] = effect.values
    return [slot(f"{name}[{k}]", v) for k, v in enumerate(effect.values)]


def fused_kernel(engine, view, exact, t: float, ql: list, vl: list, kinematics, virtual_work):
    """The fused function of ``view`` (whose exact kernel is ``exact``), with the effects
    traced at (t, q, q̇); None where one of them cannot be traced or the point gives no
    finite q̈ (the next state tries again). ``kinematics`` and ``virtual_work``: the engine's
    :class:`~mps_core.dynamics.engine.Kinematics` and :func:`~mps_core.dynamics.engine.virtual_work`."""
    lines, xl, jl, wl, A, h, _conv = exact.parts()
    n = view.n
    try:
        xv, jv, wv, Av, hv, _cv = exact(*ql, *vl)
    except (BranchChanged, ArithmeticError, ValueError):
        return None
    Av = [Av] if n == 1 else list(Av)

    tape = Tape()
    slots: list[str] = []

    def slot(code: str, value: float):
        c = _constant(code)
        if c is not None:
            return c
        tape.nodes.append(("input", len(slots)))
        slots.append(code)
        return Traced(tape, len(tape.nodes) - 1, float(value))

    tt = slot("t", t)
    tv = [slot(f"vd{k}", vl[k]) for k in range(n)]
    txl = [slot(c, v) for c, v in zip(xl, xv)]
    tjl = [slot(c, v) for c, v in zip(jl, jv)]
    twl = [slot(c, v) for c, v in zip(wl, wv)]
    tA = [slot(c, v) for c, v in zip(A, Av)]
    th = [slot(c, v) for c, v in zip(h, hv)]
    lives: dict[str, list] = {}
    traced = _trace_forces(engine, n, tt, tv, (txl, tjl, twl), tA, th, kinematics, virtual_work, slot, lives)
    if traced is None:
        return None
    Q, Qnc, qdd = traced
    outputs = [_node(x) for x in qdd]
    forces = [_node(x) for x in Q + Qnc]
    key = ("fused", exact.key, tape.key(), tuple(slots), tuple(outputs), tuple(forces))
    extra = {"tanh": math.tanh, "_Branch": ForceLawBranch, **lives}
    accel = load(
        key,
        lambda: _source(n, lines, tape, slots, outputs),
        f"<fused kernel {view.name}>",
        view.chart.flat,
        view.name,
        extra,
    )
    parts = (xl, jl, wl, A, h, _conv)
    accel.full = load(
        key + ("full",),
        lambda: _source(n, lines, tape, slots, outputs, forces, parts),
        f"<fused evaluation {view.name}>",
        view.chart.flat,
        view.name,
        extra,
    )
    return accel


def _node(x):
    return x.index if isinstance(x, Traced) else float(x)


def _trace_forces(engine, n, tt, tv, lists, tA, th, kinematics, virtual_work, slot, lives):
    """(Q, Q_nc, q̈) traced: the engine's ``_forces`` and ``solve_given_h`` on kinematics made
    of traced numbers (t, q̇, the lists of positions, analogs and angular analogs; A and h),
    the same operations in the same order; None where a law cannot be traced or q̈ is not
    finite at the traced point. A ``live`` effect's values are inputs read as ``_live{j}[k]``
    (``slot(code, value)`` makes them), its list put in ``lives`` under ``_live{j}`` for the
    function's namespace."""
    kin = kinematics(tt, None, None, engine.tables.names, bodies=engine.tables.body_index, lists=lists, v=tv)
    try:
        Q = [0.0] * n
        Qc = [0.0] * n
        for fast, e, conservative in engine.effect_paths():
            if getattr(e, "live", False):
                Qe = virtual_work(e.live_loads(tt, kin, live_inputs(e, slot, lives)), kin)
            else:
                Qe = fast(tt, kin) if fast is not None else virtual_work(e.loads(tt, kin), kin)
            if Qe is not None:
                acc = Qc if conservative else Q
                for i in range(n):
                    acc[i] += Qe[i]
        Qnc = Q
        Q = [a + b for a, b in zip(Q, Qc)]
        qdd = solve_given_h(tA[0] if n == 1 else tuple(tA), th, Q)
        for x in qdd:
            v = x.value if isinstance(x, Traced) else x
            if not math.isfinite(v):
                return None
    except Exception:
        return None
    return Q, Qnc, qdd


#: central tails by (the engine's tables and the view, the effects' fingerprint): the ones
#: made before, tried at the state before a trace is made (a command and back, an engine
#: made afresh for the same scene)
_TAILS = Memo("codegen.fused_kernels.tails", 256)


def reuse_or_make_tail(engine, view, t: float, vl: list, parts, kinematics, virtual_work):
    """A central tail (:func:`central_tail`) for ``view`` whose guards hold at this state:
    one made before for the same tables, view and effects, else a new one."""
    fp = engine.fingerprint()
    xl, jl, wl, A, h, _wb = parts
    return _reused(
        _TAILS,
        None if fp is None else (kernel_key(engine, view), fp),
        lambda k: k(t, *vl, xl, jl, wl, A, h),
        lambda: central_tail(engine, view, t, vl, parts, kinematics, virtual_work),
    )


def central_tail(engine, view, t: float, vl: list, parts, kinematics, virtual_work):
    """For central differences: ``tail(t, q̇…, xl, jl, wl, A, h) -> (Q, Q_nc, q̈)``, the
    effects' generalized forces and the solve traced at the central kernel's output ``parts``
    (xl, jl, wl, A, h, wb) as :func:`fused_kernel` traces them after an exact kernel (the same
    operations in the same order as the engine's ``_forces`` and ``solve_given_h``), reading
    the kernel's lists by index; it returns None where q̈ is not finite and raises
    :class:`ForceLawBranch` where a law's guard fails. None where it cannot be made (n > 2,
    a law a trace cannot hold). The central kernel itself stays a call of its own: this
    function replaces the effects' calls one by one."""
    n = view.n
    if n > 2:
        return None
    xv, jv, wv, Av, hv, _wb = parts
    tape = Tape()
    slots: list[str] = []
    slot = input_slot(tape, slots)
    tt = slot("t", t)
    tv = [slot(f"vd{k}", vl[k]) for k in range(n)]
    txl = [slot(f"xl[{i}]", x) for i, x in enumerate(xv)]
    tjl = [slot(f"jl[{i}]", x) for i, x in enumerate(jv)]
    twl = [slot(f"wl[{i}]", x) for i, x in enumerate(wv)]
    tA = [slot("A", Av)] if n == 1 else [slot(f"A[{i}]", x) for i, x in enumerate(Av)]
    th = [slot(f"h[{i}]", x) for i, x in enumerate(hv)]
    lives: dict[str, list] = {}
    traced = _trace_forces(engine, n, tt, tv, (txl, tjl, twl), tA, th, kinematics, virtual_work, slot, lives)
    if traced is None:
        return None
    Q, Qnc, qdd = traced
    outputs = [_node(x) for x in qdd]
    forces = [_node(x) for x in Q + Qnc]
    return load(
        ("central tail", n, tape.key(), tuple(slots), tuple(outputs), tuple(forces)),
        lambda: _tail_source(n, tape, slots, outputs, forces),
        f"<effects and solve {view.name}>",
        None,
        view.name,
        {"tanh": math.tanh, "_Branch": ForceLawBranch, **lives},
    )


def _tail_source(n, tape, slots, outputs, forces) -> str:
    """Write the central tail's code (:func:`central_tail`): the traced tape, the finiteness check of
    q̈ (``outputs``' nodes), and (Q, Q_nc, q̈) returned (``forces``: Q's and Q_nc's nodes)."""
    body: list = []
    code = emit_tape(body, tape, slots)
    out = [code(x) for x in outputs]
    check = " or ".join(f"{x} - {x} != 0.0" for x in out if not _is_float(x))
    if check:
        body.append(f"    if {check}: return None")
    fq = [code(x) for x in forces]
    ret = f"    return [{', '.join(fq[:n])}], [{', '.join(fq[n:])}], [{', '.join(out)}]"
    vs = [f"vd{k}" for k in range(n)]
    return (
        f"def kernel(t, {', '.join(vs)}, xl, jl, wl, A, h):\n"
        + "\n".join(inline_once(live_lines(body, ret) + [ret]))
        + "\n"
    )


def emit_tape(body: list, tape, slots: list):
    """Append to ``body`` the float code of a traced tape: each node once (constants folded,
    x + 0, x·1 and x·0 folded; the inputs are the code of ``slots``), each guard as soon as its
    operands exist, raising ``_Branch`` where it fails. Returns ``code(x)``: the code (a local,
    an input's code or a float literal) of a node index or constant."""
    names: dict = {}
    vals: list = []

    def s(x) -> str:
        return repr(x) if isinstance(x, float) else x

    def let(expr: str) -> str:
        name = names.get(expr)
        if name is None:
            name = names[expr] = f"f{len(names)}"
            body.append(f"    {name} = {expr}")
        return name

    def operand(x):
        return x if isinstance(x, float) else vals[x]

    pending: dict = {}
    for g in tape.guards:
        a, op, b, outcome = g
        last = max([x for x in (a, b) if isinstance(x, int)], default=-1)
        pending.setdefault(last, []).append(g)
    for i, node in enumerate(tape.nodes):
        op = node[0]
        if op == "input":
            vals.append(slots[node[1]])
        else:
            xs = [operand(x) for x in node[1:]]
            if all(isinstance(x, float) for x in xs):
                vals.append(OPS[op][1](*xs))
            elif op == "add" and any(isinstance(x, float) and x == 0.0 for x in xs):
                vals.append(xs[1] if isinstance(xs[0], float) and xs[0] == 0.0 else xs[0])
            elif op == "mul" and any(isinstance(x, float) and x == 0.0 for x in xs):
                vals.append(0.0)  # the inputs are finite where the guards hold
            elif op == "mul" and any(isinstance(x, float) and x == 1.0 for x in xs):
                vals.append(xs[1] if isinstance(xs[0], float) and xs[0] == 1.0 else xs[0])
            elif op in INFIX:
                vals.append(let(f"{s(xs[0])} {INFIX[op]} {s(xs[1])}"))
            elif op == "neg":
                vals.append(let(f"-{s(xs[0])}"))
            else:
                vals.append(let(f"{op}({s(xs[0])})"))
        for a, op, b, outcome in pending.get(i, ()):
            va, vb = operand(a), operand(b)
            if isinstance(va, float) and isinstance(vb, float):
                continue
            test = f"{s(va)} {COMPARE[op]} {s(vb)}"
            body.append(f"    if {'not ' if outcome else ''}{test}: raise _Branch()")
    return lambda x: s(operand(x))


def _source(n, lines, tape, slots, outputs, forces=None, parts=None) -> str:
    """The fused function's code: q̈ alone, or with ``forces`` (Q and Q_nc's nodes) and the
    kernel's ``parts`` the whole evaluation: (positions, analogs, angular analogs, A, h,
    θ̈ at q̈ = 0, Q, Q_nc, q̈), the lists of :meth:`PartialSystems._exact_kernel_solve`."""
    body = list(lines)
    code = emit_tape(body, tape, slots)
    out = [code(x) for x in outputs]
    check = " or ".join(f"{x} - {x} != 0.0" for x in out if not _is_float(x))
    if check:
        body.append(f"    if {check}: return None")
    qs = [f"q{k}" for k in range(n)]
    vs = [f"vd{k}" for k in range(n)]
    head = f"def kernel({', '.join(['t'] + qs + vs)}):\n"
    if forces is None:
        ret = f"    return [{', '.join(out)}]"
    else:
        xl, jl, wl, A, h, conv = parts
        fq = [code(x) for x in forces]
        groups = [xl, jl, wl, A, h, conv, fq[:n], fq[n:], out]
        items = [f"[{', '.join(g)}]" for g in groups]
        items[3] = A[0] if n == 1 else f"({', '.join(A)})"
        ret = f"    return {', '.join(items)}"
    return head + "\n".join(inline_once(live_lines(body, ret) + [ret])) + "\n"


def _is_float(code: str) -> bool:
    return _constant(code) is not None
