"""Jets give exact first and second directional derivatives of closed-form position functions."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mps_core.derivatives.jet import Jet, seed


def f(q):
    x, y = q
    return np.sqrt(2.0 + np.sin(x) * y) / (1.5 + np.cos(y)) - 3.0 * x * x + np.arctan2(y, 1.0 + x * x)


def fd_derivatives(q, v, h=1e-4):
    q = np.asarray(q, float)
    g = np.array([(f(q + h * e) - f(q - h * e)) / (2 * h) for e in np.eye(2)])
    d2 = (f(q + h * v) - 2 * f(q) + f(q - h * v)) / h**2
    return g, d2


@settings(max_examples=40, deadline=None)
@given(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-2, 2), st.floats(-2, 2))
def test_jet_matches_finite_differences(x, y, vx, vy):
    q, v = np.array([x, y]), np.array([vx, vy])
    j = f(seed(q, v))
    g, d2 = fd_derivatives(q, v)
    assert np.isclose(j.val, f(q), rtol=1e-14, atol=1e-14)
    assert np.allclose(j.grad, g, rtol=1e-6, atol=1e-7)
    assert np.isclose(j.d1, g @ v, rtol=1e-6, atol=1e-7)
    assert np.isclose(j.d2, d2, rtol=1e-4, atol=1e-5)


def test_jet_exact_on_polynomial():
    q, v = np.array([0.3, -0.7]), np.array([1.5, 2.0])
    x, y = seed(q, v)
    p = x * x * y + 2.0 * y - 1.0
    # p = x^2 y + 2y - 1: grad = (2xy, x^2 + 2); d2 along v = 2 y vx^2 + 4 x vx vy
    assert np.allclose(p.grad, [2 * 0.3 * -0.7, 0.09 + 2.0], rtol=0, atol=1e-15)
    assert np.isclose(p.d2, 2 * -0.7 * 1.5**2 + 4 * 0.3 * 1.5 * 2.0, rtol=0, atol=1e-14)


def test_jet_with_array_values_and_constants():
    q = np.array([[0.1, 0.2], [0.3, 0.4]])
    v = np.ones_like(q)
    x, y = seed(q, v)
    z = 2.0 - x + np.ones(2) * y
    assert z.val.shape == (2,) and z.grad.shape == (2, 2)
    assert isinstance(Jet.constant(1.0, 2), Jet)
