"""Reaction kernels: the joint reactions of one chart view as generated float code.

:func:`mps_core.dynamics.reactions.compute_reactions` builds, at every state, the exact kinematics on
jets, a Newton–Euler system ``E u = b`` (3 rows a body) in numpy and solves it by a constrained
least squares (an SVD and ``lstsq``). Everything in that system but the numbers is fixed by the
chart view and the structure: which joints carry load, where every entry of ``E`` sits, which
entries are ±1 and which are moment arms. A reaction kernel is that computation written out
once per (mechanism, chart view, traced program, length scale) as straight-line code on floats,
with known zeros and constants folded away:

1. the exact kinematics of the traced position function (the forward pass of
   :mod:`mps_core.codegen.exact_kernels`): the centres of mass, their analogs J_G and convective
   accelerations, the angular analogs ω* and θ̈ at q̈ = 0, the joints' points;
2. ``b`` per body from ``m a_G``, ``J α`` and the known loads (summed per body by
   :class:`~mps_core.codegen.load_sums.LoadSums`);
3. the least squares' leftover in closed form. Reactions do no work on admissible motions, so
   the columns of ``E`` span exactly the vectors r with ``J_bᵀ r = 0`` when E has full column
   rank and as many columns as rows less the degrees of freedom (J_b: the bodies' exact analogs,
   3 rows a body). The general path minimises ``|S r|`` (S: moment rows divided by the length
   scale) over r = b − E u under the whole-system balance ``C r = 0``; that is ``min |S r|``
   under ``J_bᵀ r = J_bᵀ b`` and ``C r = 0``, whose solution is ``r = S⁻² Mᵀ λ`` with
   ``(M S⁻² Mᵀ) λ = (0, J_bᵀ b)``, M = (C; J_bᵀ): a symmetric positive definite system of
   n + 3 unknowns, eliminated without pivoting;
4. u from ``E u = b − r`` (consistent by construction) by Gaussian elimination on the rows and
   in the pivot order that partial pivoting picks at the state the kernel is built at, with the
   sparsity of E folded in;
5. the frame's share, the foundation load, the residual norms and the balance check, as the
   general path computes them.

A kernel is built only where its premises hold at the building state (every unknown a joint
force or moment, no drive torque, columns + degrees of freedom = rows, ``J_bᵀ E = 0`` to
round-off, full column rank). At run time every pivot is guarded: one that falls below 10⁻⁶ of
its size at the building state (a singular position: the reactions are not unique there) raises
:class:`Fallback`, and so does a failed guard of the trace; the caller then takes the general
path, which reports the rank.
"""

from __future__ import annotations

import math
import re

import numpy as np

from ..caches import Memo
from ..derivatives.tracing import BranchChanged
from ..model.mechanism import FRAME
from .emitter import Writer, inline_once, kernel_key, live_lines, load
from .exact_kernels import Forward, angular, forward, linear_parts, trace_view
from .fused_kernels import LIVE
from .load_sums import LoadSums


class Fallback(ArithmeticError):
    """The kernel does not hold at this state: take the general path."""


def _fallback(*_):
    raise Fallback("reaction kernel: a pivot fell below its guard")


class _Folding(Forward):
    """:class:`~mps_core.codegen.exact_kernels.Forward` that also folds x − x to zero: every value
    a reaction kernel subtracts from itself is finite where the kernel holds (a position)."""

    def sub(self, a, b):
        if isinstance(a, str) and a == b:
            return None
        return super().sub(a, b)


#: relative size below which a pivot sends the state to the general path
PIVOT_GUARD = 1e-6


def reaction_kernel(
    engine,
    view,
    q,
    system,
    motion,
    columns,
    scale: float,
    from_kinematics: bool = False,
    masses: bool = False,
):
    """The reaction kernel of ``view`` (traced at ``q``), or None where its premises do not
    hold. ``engine``: a :class:`~mps_core.dynamics.engine.PartialSystems` of the mechanism (its maps);
    ``system`` and ``motion``: the general path's Newton–Euler system at q (its unknowns, their
    joints and the numbers the pivot order is chosen from) and the bodies' motion there;
    ``columns``: the output columns in order.

    ``from_kinematics``: the kernel reads the motion from an exact evaluation's kinematics
    (``fn(q…, q̇…, q̈…, xl, jl, wl, cv, loads)``: positions, analogs, angular analogs and
    ``cv``, θ̈ and the centres of mass' accelerations at q̈ = 0, as
    :class:`~mps_core.dynamics.engine.Kinematics` keeps them from an exact kernel) instead of running
    the traced position function forward itself; what the trace folds (zeros, constants) is
    folded the same. Only for exact kinematics: from central differences they would carry
    the scheme's error into every reaction.

    ``masses``: the bodies' masses and inertias are an argument (``fn(q…, q̇…, q̈…, masses,
    loads)``, ``masses`` the masses then the inertias in the mechanism's order) instead of the
    engine's, folded in: one kernel for scenes that differ in them (a batch's,
    :mod:`mps_core.run.batch`)."""
    traced = trace_view(view, q)
    if traced is None:
        return None
    flat, tape, outputs, args, free = traced
    sysm = system
    premises = _premises(engine.mechanism, sysm.E, motion, view.n, scale)
    if premises is None:
        return None
    s, order, pivots = premises
    key = (
        "reactions from kinematics" if from_kinematics else "reactions",
        "masses given" if masses else "masses folded",
        kernel_key(engine, view),
        tape.key(),
        tuple(outputs),
        tuple((j.name, j.point, j.receiver, j.giver, comp) for j, comp, _c in sysm.cols),
        tuple(columns),
        float(scale),
        tuple(order),
    )
    sizes = [float(abs(p) / s[r]) for p, r in zip(pivots, order)]
    kernel = load(
        key,
        lambda: _source(
            engine,
            view,
            tape,
            outputs,
            args,
            free,
            sysm,
            columns,
            scale,
            order,
            sizes,
            from_kinematics,
            masses,
        ),
        f"<reaction kernel{' from kinematics' if from_kinematics else ''} {view.name}>",
        flat,
        view.name,
        {"_fallback": _fallback},
        depends=tuple(sizes),  # the pivots' guards: the building state's (not in the key)
    )
    kernel.flat, kernel.chart = flat, view.name
    return kernel


def _premises(mech, E, motion, n: int, scale: float):
    """Whether the kernel's system holds at the building state: as many unknowns as the bodies'
    equations less the chart's coordinates, no joint that does work, a unique solution. Then
    (the rows' scales, the pivot order, the pivots); else None."""
    nb = len(mech.bodies)
    if E.shape[1] + n != 3 * nb:
        return None
    rows = motion.com_rows(mech)
    Jb = np.zeros((3 * nb, n))
    Jb[0::3] = motion.J[rows, 0]
    Jb[1::3] = motion.J[rows, 1]
    Jb[2::3] = motion.W
    s = np.ones(3 * nb)
    s[2::3] = 1.0 / scale
    if np.linalg.norm(Jb.T @ E) > 1e-9 * np.linalg.norm(Jb) * np.linalg.norm(E):
        return None  # a joint that does work: not this kernel's system
    sv = np.linalg.svd(s[:, None] * E, compute_uv=False)
    if sv[-1] <= 1e-9 * sv[0]:
        return None  # not unique at the building state
    order, pivots = _pivot_order(s[:, None] * E)
    return s, order, pivots


_ASSIGNED = re.compile(r"^    ([A-Za-z_][A-Za-z_0-9]*) = ")


def with_loads(kernel, sums):
    """One function ``fn(t, q…, q̇…, q̈…, xl, jl, wl, vl)`` (a kernel from kinematics:
    ``fn(t, q…, q̇…, q̈…, xl, jl, wl, cv, vl)``) that is the traced load sums ``sums``
    (:func:`~mps_core.codegen.load_sums.traced_sums`) followed by the reaction kernel ``kernel``
    on what they return: the two generated bodies one after the other (the sums' locals
    renamed), so the same operations on the same numbers, without the call, the list and its
    unpacking between them. Made once per pair. It raises what either raises. Sums that read a
    ``live`` effect's values (``_live{j}``, bound in their namespace) give a function that reads
    the same lists, made for them alone (never kept for another pair of the same code)."""
    lives = {k: v for k, v in sums.__globals__.items() if k.startswith(LIVE)}
    key = ("reactions with loads", kernel.serial, sums.serial)
    made = None if lives else _WITH_LOADS.get(key)
    if made is not None:
        return made
    made = load(
        ("reactions with loads", kernel.source, sums.source),
        lambda: _with_loads_source(kernel.source, sums.source),
        f"<reaction kernel with loads {kernel.chart}>",
        kernel.flat,
        kernel.chart,
        {"_fallback": _fallback, "tanh": math.tanh, "_Branch": BranchChanged, **lives},
    )
    return made if lives else _WITH_LOADS.keep(key, made)


def _with_loads_source(kernel_source: str, sums_source: str) -> str:
    """Write the code of :func:`with_loads` from a reaction kernel's and a load sums' code."""
    head, unpack, *body = kernel_source.rstrip("\n").split("\n")
    targets, eq, rhs = unpack.strip().partition(" = ")
    if not (head.startswith("def kernel(") and head.endswith(", loads):") and eq and rhs == "loads"):
        raise ValueError("with_loads: not a reaction kernel's source")
    s_lines = sums_source.rstrip("\n").split("\n")[1:]
    ret = s_lines.pop()
    if not (ret.startswith("    return [") and ret.endswith("]")):
        raise ValueError("with_loads: not a load sums' source")
    local = {m.group(1) for line in s_lines if (m := _ASSIGNED.match(line))}
    rename = re.compile(r"\b(" + "|".join(sorted(local, key=len, reverse=True)) + r")\b") if local else None

    def renamed(line: str) -> str:
        return rename.sub(r"s_\1", line) if rename is not None else line

    params = head[len("def kernel(") : -len(", loads):")]
    names = [x.strip() for x in targets.split(",")]
    items = _top_level_items(renamed(ret[len("    return [") : -1]))
    if len(names) != len(items):
        raise ValueError("with_loads: the sums do not give the kernel's loads")
    ret = body.pop()
    # a load that is a number (gravity's, a zero) is written where it is read
    numbers = {a: x for a, x in zip(names, items) if _NUMBER.fullmatch(x)}
    if numbers:
        sub = re.compile(r"\b(" + "|".join(numbers) + r")\b")
        body = [sub.sub(lambda m: f"({numbers[m.group(1)]})", line) for line in body]
        ret = sub.sub(lambda m: f"({numbers[m.group(1)]})", ret)
    lines = [
        *(renamed(line) for line in s_lines),
        *(f"    {a} = {x}" for a, x in zip(names, items) if a not in numbers),
        *body,
    ]
    given = {x.strip() for x in params.split(",")}
    lists = ", ".join(x for x in ("xl", "jl", "wl", "vl") if x not in given)
    return (
        "\n".join([f"def kernel(t, {params}, {lists}):", *inline_once(live_lines(lines, ret) + [ret])]) + "\n"
    )


_WITH_LOADS = Memo("codegen.reaction_kernels.with_loads", 256)
_NUMBER = re.compile(r"-?(\d+\.\d*(e-?\d+)?|inf|nan)")


def _top_level_items(text: str) -> list[str]:
    """The comma-separated items of ``text`` outside parentheses and brackets."""
    items, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        if ch in "([":
            depth += 1
        elif ch in ")]":
            depth -= 1
        elif ch == "," and depth == 0:
            items.append(text[start:i].strip())
            start = i + 1
    items.append(text[start:].strip())
    return items


def _pivot_order(A: np.ndarray) -> tuple[list, list]:
    """Rows picked by partial pivoting, column by column, and the pivots (of A as given)."""
    A = A.copy()
    left = list(range(A.shape[0]))
    order, pivots = [], []
    for j in range(A.shape[1]):
        p = max(left, key=lambda i: abs(A[i, j]))
        order.append(p)
        pivots.append(A[p, j])
        left.remove(p)
        for i in left:
            if A[i, j] != 0.0:
                A[i] -= (A[i, j] / A[p, j]) * A[p]
    return order, pivots


class _Ops:
    """The arithmetic the steps of :func:`_source` write code with: the forward writer's
    operations (None a zero, floats folded), and the few built on them."""

    def __init__(self, fw, w):
        self.fw, self.w = fw, w
        self.add, self.sub, self.mul, self.neg = fw.add, fw.sub, fw.mul, fw.neg

    def div(self, a, p):
        return self.mul(a, self.fw.recip(p))

    def code(self, x) -> str:
        return "0.0" if x is None else self.fw._s(x)

    def guard(self, p, size) -> None:
        """A pivot's guard: the general path (``_fallback``) where |p| is not above its
        size's share."""
        if isinstance(p, float):
            if not abs(p) > PIVOT_GUARD * size:
                raise ValueError("reaction kernel: a constant pivot below its guard")
            return
        self.w.lines.append(f"    if not abs({p}) > {PIVOT_GUARD * size!r}: _fallback()")

    def dot(self, u, v, weights=None):
        acc = None
        for r in range(len(u)):
            x = self.mul(u[r], v[r])
            if weights is not None:
                x = self.mul(weights[r], x)
            acc = self.add(acc, x)
        return acc

    def norm(self, xs):
        acc = None
        for x in xs:
            acc = self.add(acc, self.mul(x, x))
        return None if acc is None else self.fw.call("sqrt", acc)


def _source(
    engine,
    view,
    tape,
    outputs,
    args,
    free,
    sysm,
    columns,
    scale,
    order,
    pivot_sizes,
    from_kinematics: bool = False,
    masses: bool = False,
) -> str:
    """The reaction kernel's code: the bodies' motion and Newton–Euler's right side b, the
    joints' columns E, the least squares' leftover r, E u = b − r by the building state's
    pivots, then what the frame receives and the checks (one step a function below)."""
    n = view.n
    w = Writer()
    names = engine.tables.names
    nb = len(engine.mechanism.bodies)
    offset = (
        engine.tables.offset.tolist()
        if engine.tables.offset is not None
        else [0.0] * (2 * engine.tables.npoints)
    )
    if from_kinematics:
        fw, pos, grad, d2, omega, theta2, unpack = _from_kinematics(
            engine, view, tape, outputs, args, free, w
        )
    else:
        fw, outs = forward(w, n, tape, outputs, args, free, _Folding)
        parts = linear_parts(engine, fw, outs)
        val, grad, _d1, d2 = parts
        omega, theta2 = angular(engine, fw, n, parts)
        unpack = None

        def pos(name):
            r = 2 * names[name]
            return (fw.add(val(r), offset[r] or None), fw.add(val(r + 1), offset[r + 1] or None))

    ops = _Ops(fw, w)
    if masses:
        given = [f"mb{k}" for k in range(nb)], [f"ib{k}" for k in range(nb)]
        w.lines.insert(0, f"    {', '.join(given[0] + given[1])} = masses")
    else:
        given = engine.tables.mass.tolist(), engine.tables.inertia.tolist()
    qs = [f"q{k}" for k in range(n)]
    vs = [f"vd{k}" for k in range(n)]
    accs = [f"a{k}" for k in range(n)]
    origin = pos("O") if "O" in names else (None, None)
    load_names = [f"l{c}{k}" for k in range(nb) for c in ("x", "y", "m")] + ["ffx", "ffy", "fmo", "mmot"]
    w.lines.insert(0, f"    {', '.join(load_names)} = loads")
    motion = _bodies_motion(ops, engine, given, pos, grad, d2, omega, theta2, accs, origin)
    E = _joint_columns(ops, engine.mechanism, sysm.cols, pos, motion["G"])
    res = _leftover(ops, motion, nb, n, scale)
    u = _solve_by_pivots(ops, E, motion["b"], res, order, pivot_sizes, len(sysm.cols))
    out, frame = _frame_receives(ops, sysm.cols, u, columns, pos, origin)
    _checks(ops, out, res, given, motion, frame)
    ret = (
        f"    return [{', '.join(ops.code(out[c]) for c in columns)}], "
        f"[{', '.join(ops.code(x) for x in res)}]"
    )
    if unpack is not None:  # the lists' numbers the code above reads
        w.lines[1:1] = unpack()
    lists = ["xl", "jl", "wl", "cv"] if from_kinematics else []
    lists += ["masses"] if masses else []
    return (
        f"def kernel({', '.join(qs + vs + accs + lists)}, loads):\n"
        + "\n".join(inline_once(live_lines(w.lines, ret) + [ret]))
        + "\n"
    )


def _bodies_motion(ops, engine, given, pos, grad, d2, omega, theta2, accs, origin) -> dict:
    """Each body's centre G (and G − O), its Jacobian, accelerations (ẍ_G, ÿ_G, θ̈) and
    angular rates' rows, and Newton–Euler's right side b = (m a − F, J α − M_G) a body.
    ``given``: the masses and the inertias (numbers, or the names of the arguments)."""
    add, sub, mul = ops.add, ops.sub, ops.mul
    names, n = engine.tables.names, len(accs)
    mass, inertia = given
    ox, oy = origin
    G, g, JG, aG, alpha, W = [], [], [], [], [], []
    b = []
    for k, body in enumerate(engine.mechanism.bodies):
        r = 2 * names[f"G_{body.name}"]
        Gx, Gy = pos(f"G_{body.name}")
        G.append((Gx, Gy))
        g.append((sub(Gx, ox), sub(Gy, oy)))
        jg = [[grad(r + c, i) for i in range(n)] for c in (0, 1)]
        JG.append(jg)
        a = []
        for c in (0, 1):
            acc = d2(r + c)
            for i in range(n):
                acc = add(acc, mul(jg[c][i], accs[i]))
            a.append(acc)
        aG.append(a)
        wk = [omega.get((k, i)) for i in range(n)]
        W.append(wk)
        al = theta2.get(k)
        for i in range(n):
            al = add(al, mul(wk[i], accs[i]))
        alpha.append(al)
        lx, ly, lm = f"lx{k}", f"ly{k}", f"lm{k}"
        # the loads' moment about G from theirs about O: M_G = M_O − (G − O) × F
        mG = sub(lm, sub(mul(g[k][0], ly), mul(g[k][1], lx)))
        b += [sub(mul(mass[k], a[0]), lx), sub(mul(mass[k], a[1]), ly), sub(mul(inertia[k], al), mG)]
    return {"G": G, "g": g, "JG": JG, "aG": aG, "alpha": alpha, "W": W, "b": b}


def _joint_columns(ops, mech, cols, pos, G) -> list:
    """E, column by column: each joint force's components (and moments) in the Newton–Euler
    rows of the bodies that receive and give it (the general path's _System, as code)."""
    add, sub, mul = ops.add, ops.sub, ops.mul
    nrow = 3 * len(mech.bodies)
    body_row = {bd.name: 3 * k for k, bd in enumerate(mech.bodies)}
    E = [[None] * len(cols) for _ in range(nrow)]
    for c, (j, comp, _col) in enumerate(cols):
        for body, sign in ((j.receiver, 1.0), (j.giver, -1.0)):
            if body == FRAME:
                continue
            r0 = body_row[body]
            if comp == "m":
                E[r0 + 2][c] = add(E[r0 + 2][c], sign)
                continue
            px, py = pos(j.point)
            Gx, Gy = G[r0 // 3]
            dx, dy = sub(px, Gx), sub(py, Gy)
            if comp == "x":
                E[r0][c] = add(E[r0][c], sign)
                E[r0 + 2][c] = add(E[r0 + 2][c], mul(-sign, dy))
            else:
                E[r0 + 1][c] = add(E[r0 + 1][c], sign)
                E[r0 + 2][c] = add(E[r0 + 2][c], mul(sign, dx))
    return E


def _leftover(ops, motion, nb: int, n: int, scale: float) -> list:
    """The least squares' leftover r = S⁻² Mᵀ λ with (M S⁻² Mᵀ) λ = (0, 0, 0, J_bᵀ b): M's
    rows the rigid motions of the whole and the mechanism's own, by Cholesky's steps."""
    add, sub, mul, neg, fw = ops.add, ops.sub, ops.mul, ops.neg, ops.fw
    g, JG, W, b = motion["g"], motion["JG"], motion["W"], motion["b"]
    nrow = 3 * nb
    wt = [1.0, 1.0, scale * scale] * nb
    Mrows = []
    Mrows.append([1.0 if r % 3 == 0 else None for r in range(nrow)])
    Mrows.append([1.0 if r % 3 == 1 else None for r in range(nrow)])
    Mrows.append([x for k in range(nb) for x in (neg(g[k][1]), g[k][0], 1.0)])
    for i in range(n):
        Mrows.append([x for k in range(nb) for x in (JG[k][0][i], JG[k][1][i], W[k][i])])
    K = len(Mrows)
    Gm = [[ops.dot(Mrows[i], Mrows[j], wt) if j >= i else None for j in range(K)] for i in range(K)]
    rhs = [None, None, None] + [ops.dot(Mrows[3 + i], b) for i in range(n)]
    diag = [Gm[i][i] for i in range(K)]
    for k in range(K):
        p, dk = Gm[k][k], diag[k]
        if not (isinstance(p, float) and isinstance(dk, float)):
            ops.w.lines.append(f"    if not {fw._s(p)} > 1e-12 * {fw._s(dk)}: _fallback()")
        elif not p > 1e-12 * dk:
            raise ValueError("reaction kernel: a constant pivot below its guard")
        ip = fw.recip(p)
        for i in range(k + 1, K):
            f = mul(Gm[k][i], ip)  # symmetric: G[i][k] = G[k][i]
            if f is None:
                continue
            for jj in range(i, K):
                Gm[i][jj] = sub(Gm[i][jj], mul(f, Gm[k][jj]))
            rhs[i] = sub(rhs[i], mul(f, rhs[k]))
    lam = [None] * K
    for k in reversed(range(K)):
        acc = rhs[k]
        for jj in range(k + 1, K):
            acc = sub(acc, mul(Gm[k][jj], lam[jj]))
        lam[k] = ops.div(acc, Gm[k][k]) if acc is not None else None
    res = []
    for r in range(nrow):
        acc = None
        for a in range(K):
            acc = add(acc, mul(Mrows[a][r], lam[a]))
        res.append(mul(wt[r], acc))
    return res


def _solve_by_pivots(ops, E, b, res, order, pivot_sizes, m: int) -> list:
    """u from E u = b − r: elimination down the pivot rows in the building state's order
    (each pivot guarded), then back substitution."""
    sub, mul, fw = ops.sub, ops.mul, ops.fw
    Ew = [list(row) for row in E]
    y = [sub(b[r], res[r]) for r in range(len(E))]
    later = list(order)
    for jcol, p in enumerate(order):
        later.remove(p)
        piv = Ew[p][jcol]
        ops.guard(piv, pivot_sizes[jcol])
        ip = fw.recip(piv)
        for i in later:
            f = mul(Ew[i][jcol], ip)
            if f is None:
                continue
            for c in range(jcol + 1, m):
                Ew[i][c] = sub(Ew[i][c], mul(f, Ew[p][c]))
            y[i] = sub(y[i], mul(f, y[p]))
    u: list = [None] * m
    for jcol in reversed(range(m)):
        p = order[jcol]
        acc = y[p]
        for c in range(jcol + 1, m):
            acc = sub(acc, mul(Ew[p][c], u[c]))
        u[jcol] = ops.div(acc, Ew[p][jcol]) if acc is not None else None
    return u


def _frame_receives(ops, cols, u, columns, pos, origin) -> tuple[dict, tuple]:
    """The columns' values, and what the frame receives through the joints (force and moment
    about O), with the foundation load: that plus the effects' own frame reactions."""
    add, sub, mul = ops.add, ops.sub, ops.mul
    ox, oy = origin
    out = dict.fromkeys(columns, None)
    RFx = RFy = RM = None
    for (j, comp, col), val_u in zip(cols, u):
        out[col] = val_u
        sign = 1.0 if j.receiver == FRAME else (-1.0 if j.giver == FRAME else 0.0)
        if sign == 0.0:
            continue
        if comp == "m":
            RM = add(RM, mul(sign, val_u))
            continue
        px, py = pos(j.point)
        px, py = sub(px, ox), sub(py, oy)
        f = mul(sign, val_u)
        if comp == "x":
            RFx = add(RFx, f)
            RM = sub(RM, mul(py, f))
        else:
            RFy = add(RFy, f)
            RM = add(RM, mul(px, f))
    out["M_motor"] = "mmot"
    out["F_found_x"] = add(RFx, "ffx")
    out["F_found_y"] = add(RFy, "ffy")
    out["M_found_O"] = add(RM, "fmo")
    return out, (RFx, RFy, RM)


def _checks(ops, out, res, given, motion, frame) -> None:
    """The checks' columns: the leftover's force and moment norms, and the balance of the
    whole (the momenta's rates against the loads and what the frame gives)."""
    add, sub, mul = ops.add, ops.sub, ops.mul
    nrow = len(res)
    mass, inertia = given
    g, aG, alpha = motion["g"], motion["aG"], motion["alpha"]
    RFx, RFy, RM = frame
    out["residual_force_N"] = ops.norm([res[r] for r in range(nrow) if r % 3 != 2])
    out["residual_moment_Nm"] = ops.norm([res[r] for r in range(2, nrow, 3)])
    pdx = pdy = hdot = None
    ex = ey = emo = None
    for k in range(len(mass)):
        mx, my = mul(mass[k], aG[k][0]), mul(mass[k], aG[k][1])
        pdx, pdy = add(pdx, mx), add(pdy, my)
        hdot = add(hdot, sub(mul(g[k][0], my), mul(g[k][1], mx)))
        hdot = add(hdot, mul(inertia[k], alpha[k]))
        ex, ey, emo = add(ex, f"lx{k}"), add(ey, f"ly{k}"), add(emo, f"lm{k}")
    bx, by = sub(pdx, sub(ex, RFx)), sub(pdy, sub(ey, RFy))
    out["balance_residual_N"] = ops.norm([bx, by])
    bm = sub(hdot, sub(emo, RM))
    out["balance_residual_Nm"] = (
        None if bm is None else abs(bm) if isinstance(bm, float) else ops.w.let(f"abs({bm})")
    )


def _from_kinematics(engine, view, tape, outputs, args, free, w):
    """What :func:`_source` reads of the bodies' motion, as code reading an exact evaluation's
    kinematics lists (unpacked into locals ``kx…``, ``kj…``, ``kw…``, ``kc…``): (fw, pos,
    grad, d2, omega, theta2, ``unpack()``: the unpacking lines of the numbers read so far).
    The trace runs forward once, here, into code that is thrown away: where it gives a zero
    or a constant, so does this; elsewhere the list's number, the same to round-off."""
    n = view.n
    mech = engine.mechanism
    names = engine.tables.names
    nb = len(mech.bodies)
    NP = engine.tables.npoints
    offset = engine.tables.offset.tolist() if engine.tables.offset is not None else [0.0] * (2 * NP)
    fw0, outs = forward(Writer(), n, tape, outputs, args, free, _Folding)
    parts0 = linear_parts(engine, fw0, outs)
    val0, grad0, _d10, d20 = parts0
    omega0, theta20 = angular(engine, fw0, n, parts0)
    com = {2 * names[f"G_{b.name}"]: k for k, b in enumerate(mech.bodies)}
    used: dict = {"kx": set(), "kj": set(), "kw": set(), "kc": set()}

    def read(traced, prefix, i):
        if traced is None or isinstance(traced, float):
            return traced  # a zero or a constant of the trace
        used[prefix].add(i)
        return f"{prefix}{i}"

    def pos(name):
        r = 2 * names[name]
        return tuple(read(fw0.add(val0(r + c), offset[r + c] or None), "kx", r + c) for c in (0, 1))

    def grad(row, i):
        return read(grad0(row, i), "kj", row * n + i)

    def d2(row):
        k = com.get(row - row % 2)
        if k is None:
            raise ValueError(
                "reaction kernel from kinematics: a convective acceleration other than a centre of mass's"
            )
        return read(d20(row), "kc", nb + 2 * k + row % 2)

    omega = {key: read(x, "kw", key[0] * n + key[1]) for key, x in omega0.items()}
    theta2 = {k: read(x, "kc", k) for k, x in theta20.items()}

    def unpack():
        """The lists into locals (one statement each: the unused ones are ``_``)."""
        sizes = {"kx": ("xl", 2 * NP), "kj": ("jl", 2 * NP * n), "kw": ("wl", nb * n), "kc": ("cv", 3 * nb)}
        out = []
        for prefix, (arg, size) in sizes.items():
            if used[prefix]:
                targets = [f"{prefix}{i}" if i in used[prefix] else "_" for i in range(size)]
                out.append(f"    {', '.join(targets)} = {arg}")
        return out

    return _Folding(w, n), pos, grad, d2, omega, theta2, unpack


__all__ = ["Fallback", "reaction_kernel", "LoadSums", "PIVOT_GUARD"]
