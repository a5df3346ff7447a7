"""An exact kernel's code run on arrays: the kinematics of many scenes in one call (and a
reaction kernel's, :mod:`mps_core.codegen.reaction_kernels`, the same way).

An exact kernel (:mod:`mps_core.codegen.exact_kernels`) is straight-line arithmetic on floats
with ``cos``, ``sin`` and ``sqrt`` and, where the position function branches, a guard that
calls ``_miss``. The same text, its guards made to test every element, runs on numpy arrays
of one value per scene: ``kernel(q…, q̇…)`` then returns, element by element, what the float
kernel returns for each scene (a float where a number is the same for all, e.g. a fixed
point's coordinate). What a batch reads of it is the kinematics (positions, analogs, angular
analogs, and the bodies' θ̈ and the centres of mass's accelerations at q̈ = 0): A and h in
the kernel's return hold the first scene's masses, folded in as constants, so a batch whose
scenes differ in their masses forms A and h itself from the kinematics.

A guard that fails for any scene raises :class:`ArrayBranchChanged`: some scene left the
branch the kernel was traced on (the caller runs the scenes another way).
"""

from __future__ import annotations

import ast
import re

import numpy as np

from ..caches import Memo
from ..derivatives.tracing import BranchChanged
from .emitter import made

__all__ = ["ArrayBranchChanged", "array_kernel"]


class ArrayBranchChanged(BranchChanged):
    """A guard of an array kernel failed for at least one scene."""


#: ``    if [not ]test: _miss(args)``, the guard line of the kernels' writers (a reaction
#: kernel's pivots: ``_fallback()``)
_GUARD = re.compile(r"^(\s*)if (not )?(.+): (_miss|_fallback)\(.*\)$")

_CODE = Memo("codegen.array_kernels.code", 256)


def _array_source(source: str) -> str:
    out = []
    for line in source.splitlines():
        m = _GUARD.match(line)
        if m is None:
            out.append(line)
        elif m.group(2):  # the test must hold everywhere (a NaN fails it)
            out.append(f"{m.group(1)}if not _all({m.group(3)}): _miss()")
        else:  # the test must fail everywhere
            out.append(f"{m.group(1)}if _any({m.group(3)}): _miss()")
    return "\n".join(out) + "\n"


def _without(source: str, drop: tuple) -> str:
    """A kernel's straight-line code with the return tuple's places ``drop`` made None (a
    place ``(i, j)``: item j of the list at place i), and the assignments that only they read
    left out (the guards, and what they read, stay)."""
    tree = ast.parse(source)
    fn = tree.body[0]
    assert isinstance(fn, ast.FunctionDef)
    ret = fn.body[-1]
    assert isinstance(ret, ast.Return) and isinstance(ret.value, ast.Tuple)
    for place in drop:
        if isinstance(place, tuple):
            i, j = place
            items = ret.value.elts[i]
            assert isinstance(items, ast.List)
            items.elts[j] = ast.Constant(None)
        else:
            ret.value.elts[place] = ast.Constant(None)
    needed = {node.id for node in ast.walk(ret) if isinstance(node, ast.Name)}
    body: list[ast.stmt] = []
    for stmt in reversed(fn.body[:-1]):
        target = stmt.targets[0] if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 else None
        if isinstance(target, ast.Name) and target.id not in needed:
            continue
        body.append(stmt)
        needed |= {node.id for node in ast.walk(stmt) if isinstance(node, ast.Name)}
    fn.body = [*reversed(body), ret]
    return ast.unparse(tree) + "\n"


def _miss():
    raise ArrayBranchChanged("a scene left the branch of the kernel")


def array_kernel(kernel, drop: tuple = ()):
    """The array form of an exact kernel (see the module's docstring); ``drop``: the places
    of its return tuple that the caller does not read, or ``(place, item)`` of a list there
    (None there, and nothing computed for them alone)."""
    key = (kernel.source, drop)
    code = _CODE.get(key)
    if code is None:

        def source() -> str:
            out = _array_source(kernel.source)
            return _without(out, drop) if drop else out

        code = _CODE.keep(key, made(("array kernel",) + key, source, "<array kernel>")[0])
    namespace = {
        "cos": np.cos,
        "sin": np.sin,
        "sqrt": np.sqrt,
        "_all": np.all,
        "_any": np.any,
        "_miss": _miss,
        "_fallback": _miss,
    }
    exec(code, namespace)
    return namespace["kernel"]
