"""Tracing a chart's ``flat`` position function into a tape of arithmetic.

Tracing (:func:`trace_at`) calls ``flat`` once with :class:`Traced` numbers for the free coordinates, and with
``cos``, ``sin`` and ``sqrt`` that record themselves (``flat`` takes these three as arguments
for this reason). The result is the straight-line program the function runs at that point: a
:class:`Tape` of operations (``+ - * /``, negation, ``cos``, ``sin``, ``sqrt``) on earlier
nodes and float constants (and ``tanh``, for the force laws of effects traced the same way),
the outputs (nodes or constants) and the guards: every comparison
the function made, with the outcome it had. Code generated from the tape is the function's own
only where the guards hold; where one fails, the function must be asked again (a domain check
that now fails raises there, as it should).

Anything else a traced number meets (``math.sin`` on it, ``abs``, a truth test, ``float()``)
raises :class:`TracingError`: such a function is not traced, and its callers keep the general
path.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable
from typing import Any

#: the operations a tape holds: name -> (arity, evaluation on floats)
OPS: dict[str, tuple[int, Callable[..., Any]]] = {
    "add": (2, operator.add),
    "sub": (2, operator.sub),
    "mul": (2, operator.mul),
    "div": (2, operator.truediv),
    "neg": (1, operator.neg),
    "cos": (1, math.cos),
    "sin": (1, math.sin),
    "sqrt": (1, math.sqrt),
    "tanh": (1, math.tanh),
}

_COMPARE: dict[str, Callable[[Any, Any], bool]] = {
    "gt": operator.gt,
    "ge": operator.ge,
    "lt": operator.lt,
    "le": operator.le,
    "eq": operator.eq,
    "ne": operator.ne,
}


class TracingError(TypeError):
    """The function does something a tape cannot hold."""


class BranchChanged(Exception):
    """A traced program does not hold at this point (a comparison came out otherwise)."""


class Tape:
    """Nodes in the order they were computed: ``("input", k)`` for the k-th traced argument, or
    ``(op, a)`` / ``(op, a, b)`` with each operand a node index (int) or a constant (float).
    ``guards``: (node or constant, comparison, node or constant, outcome)."""

    def __init__(self):
        self.nodes: list[tuple] = []
        self.guards: list[tuple] = []

    def _push(self, node: tuple, value: float) -> Traced:
        self.nodes.append(node)
        return Traced(self, len(self.nodes) - 1, value)

    def key(self) -> tuple:
        """Everything generated code depends on, hashable."""
        return tuple(self.nodes), tuple(self.guards)


def _operand(tape: Tape, x):
    """(operand as stored, its value at the traced point)."""
    if isinstance(x, Traced):
        if x.tape is not tape:
            raise TracingError("numbers of two different traces met")
        return x.index, x.value
    if isinstance(x, (int, float)) and not isinstance(x, bool):
        return float(x), float(x)
    raise TracingError(f"a traced number met {type(x).__name__}")


class Traced:
    """A number inside a trace: its node on the tape and its value at the traced point."""

    __slots__ = ("tape", "index", "value")

    def __init__(self, tape: Tape, index: int, value: float):
        self.tape, self.index, self.value = tape, index, value

    def _binary(self, op, other, reverse=False):
        a, va = _operand(self.tape, self)
        try:
            b, vb = _operand(self.tape, other)
        except TracingError:
            return NotImplemented
        if reverse:
            a, va, b, vb = b, vb, a, va
        return self.tape._push((op, a, b), OPS[op][1](va, vb))

    def __add__(self, o):
        return self._binary("add", o)

    def __radd__(self, o):
        return self._binary("add", o, True)

    def __sub__(self, o):
        return self._binary("sub", o)

    def __rsub__(self, o):
        return self._binary("sub", o, True)

    def __mul__(self, o):
        return self._binary("mul", o)

    def __rmul__(self, o):
        return self._binary("mul", o, True)

    def __truediv__(self, o):
        return self._binary("div", o)

    def __rtruediv__(self, o):
        return self._binary("div", o, True)

    def __neg__(self):
        return self.tape._push(("neg", self.index), -self.value)

    def __pos__(self):
        return self

    def __pow__(self, p):
        if p == 2:
            return self * self
        raise TracingError(f"a traced number raised to {p!r}")

    def _compare(self, op, other, reverse=False):
        a, va = _operand(self.tape, self)
        b, vb = _operand(self.tape, other)
        if reverse:
            a, va, b, vb = b, vb, a, va
        outcome = bool(_COMPARE[op](va, vb))
        self.tape.guards.append((a, op, b, outcome))
        return outcome

    def __gt__(self, o):
        return self._compare("gt", o)

    def __ge__(self, o):
        return self._compare("ge", o)

    def __lt__(self, o):
        return self._compare("lt", o)

    def __le__(self, o):
        return self._compare("le", o)

    def __eq__(self, o):
        try:
            return self._compare("eq", o)
        except TracingError:
            return NotImplemented

    def __ne__(self, o):
        try:
            return self._compare("ne", o)
        except TracingError:
            return NotImplemented

    def __bool__(self):
        raise TracingError("a traced number's truth value")

    def __float__(self):
        raise TracingError("a traced number converted to float")

    __index__ = __int__ = __float__

    def __abs__(self):
        raise TracingError("abs() of a traced number")

    __hash__ = None  # type: ignore[assignment]  # a traced number is unhashable, like a list


def _unary(name):
    fn = OPS[name][1]

    def f(x):
        if x.__class__ is Traced:
            return x.tape._push((name, x.index), fn(x.value))
        return fn(x)

    f.__name__ = name
    return f


#: the functions ``flat`` gets while traced; also what a force law calls (on floats they are
#: math's own), so that tracing an effect folds its law in (:mod:`mps_core.codegen.fused_kernels`)
cos, sin, sqrt, tanh = _unary("cos"), _unary("sin"), _unary("sqrt"), _unary("tanh")


def trace_at(fn, args, free: dict) -> tuple[Tape, list]:
    """Trace ``fn`` at ``args`` (floats), with the arguments ``free`` names ({position: input
    number}) traced. Returns (tape, outputs): each output a node index or a constant (float).
    Raises :class:`TracingError` where ``fn`` cannot be traced; errors ``fn`` itself raises at
    this point (a domain error) go to the caller."""
    tape = Tape()
    call: list[Traced | float] = []
    for pos, a in enumerate(args):
        if pos in free:
            call.append(tape._push(("input", free[pos]), float(a)))
        else:
            call.append(float(a))
    try:
        out = fn(*call, cos=cos, sin=sin, sqrt=sqrt)
    except TypeError as exc:
        if isinstance(exc, TracingError):
            raise
        raise TracingError(str(exc)) from None
    outputs: list[int | float] = []
    for x in out:
        if isinstance(x, Traced):
            outputs.append(x.index)
        elif isinstance(x, (int, float)) and not isinstance(x, bool):
            outputs.append(float(x))
        else:
            raise TracingError(f"an output of type {type(x).__name__}")
    return tape, outputs
