"""Tracing position functions into tapes (mps_core.derivatives.tracing)."""

from __future__ import annotations

import math

import pytest

from mps_core.derivatives.tracing import Tape, TracingError, trace_at


def _run(tape: Tape, outputs, inputs):
    """Evaluate a tape on floats (an independent reading of its nodes)."""
    import operator

    f = {
        "add": operator.add,
        "sub": operator.sub,
        "mul": operator.mul,
        "div": operator.truediv,
        "neg": operator.neg,
        "cos": math.cos,
        "sin": math.sin,
        "sqrt": math.sqrt,
    }
    vals = []
    for node in tape.nodes:
        if node[0] == "input":
            vals.append(inputs[node[1]])
        else:
            args = [vals[a] if isinstance(a, int) else a for a in node[1:]]
            vals.append(f[node[0]](*args))
    return [vals[o] if isinstance(o, int) else o for o in outputs]


def _fn(a, b, c, cos=math.cos, sin=math.sin, sqrt=math.sqrt):
    x = 2.0 * cos(a) - b / 3.0
    y = sqrt(c * c + 1.0) * sin(b) + (1 - a) / (b + 2)
    if not x * x > 0.0:
        raise ValueError("x")
    return (0.0, x, -y, x**2, c)


def test_a_tape_computes_what_the_function_computes():
    tape, outputs = trace_at(_fn, [0.3, 0.7, 5.0], {0: 0, 1: 1})
    assert outputs[0] == 0.0 and outputs[4] == 5.0  # constants stay constants
    for a, b in [(0.3, 0.7), (-1.0, 2.5), (2.0, -0.4)]:
        assert _run(tape, outputs, [a, b]) == pytest.approx(list(_fn(a, b, 5.0)), rel=1e-15)
    # c is no input: sqrt(c·c + 1) was computed on floats, and only its value recorded
    assert ("mul", math.sqrt(26.0), 6) in tape.nodes
    assert not any(node[0] == "sqrt" for node in tape.nodes)
    # one guard, with the outcome the traced point gave
    assert len(tape.guards) == 1 and tape.guards[0][1:] == ("gt", 0.0, True)


@pytest.mark.parametrize(
    "bad",
    [
        lambda a, cos=None, sin=None, sqrt=None: (math.sin(a),),
        lambda a, cos=None, sin=None, sqrt=None: (abs(a),),
        lambda a, cos=None, sin=None, sqrt=None: (1.0 if a else 0.0,),
        lambda a, cos=None, sin=None, sqrt=None: (a**3,),
        lambda a, cos=None, sin=None, sqrt=None: ("x",),
    ],
)
def test_what_a_tape_cannot_hold_is_refused(bad):
    with pytest.raises(TracingError):
        trace_at(bad, [0.5], {0: 0})


def test_the_function_s_own_errors_go_through():
    def fn(a, cos=None, sin=None, sqrt=None):
        if not a > 1.0:
            raise ArithmeticError("outside")
        return (a,)

    with pytest.raises(ArithmeticError, match="outside"):
        trace_at(fn, [0.5], {0: 0})
