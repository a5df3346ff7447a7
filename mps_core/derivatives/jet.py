"""Second-order forward-mode derivatives ("jets") for position functions.

A :class:`Jet` carries, for a quantity f(q) at a point q:

* ``val``  f(q);
* ``grad`` the gradient ∂f/∂q_i for every free coordinate (last axis, length n);
* ``d1``   the first directional derivative along a direction v: ∇f·v;
* ``d2``   the second directional derivative along v: vᵀ(∇²f)v.

With v = q̇ these are the velocity analogs (∂r/∂q), the velocity (ṙ at q̈ = 0 is ∇r·q̇) and the
convective acceleration (r̈ at q̈ = 0), all exact to round-off. Position functions written with
numpy ufuncs (``np.sin``, ``np.sqrt``, ``+``, ``*``, ``/``…) accept jets unchanged, because a jet
implements ``__array_ufunc__`` for the operations a closed-form linkage needs.

:func:`seed` at a single point gives :class:`ScalarJet` s: the same rules on Python floats
(the gradient a tuple), several times faster than numpy on length-2 arrays, which is what the
engine's exact-derivative scheme and every exact change of chart evaluate. Arrays of points
give array-valued :class:`Jet` s; the two mix (an array operand turns the result into a
:class:`Jet`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["Jet", "ScalarJet", "seed", "value_of"]


def _ex(a):
    """Give an array an axis to broadcast against a gradient's last axis."""
    a = np.asarray(a)
    return a[..., None] if a.ndim else a


class Jet:
    __slots__ = ("val", "grad", "d1", "d2")
    __array_priority__ = 1000

    def __init__(self, val, grad, d1, d2):
        self.val = val
        self.grad = grad
        self.d1 = d1
        self.d2 = d2

    # -- construction ----------------------------------------------------------------------
    @staticmethod
    def constant(value, n: int) -> Jet:
        if isinstance(value, _NUMBER) or (isinstance(value, np.ndarray) and value.ndim == 0):
            return ScalarJet(float(value), (0.0,) * n, 0.0, 0.0)
        value = np.asarray(value, dtype=float)
        z = np.zeros_like(value)
        return Jet(value, np.zeros(value.shape + (n,)), z, z)

    # -- elementary rules ------------------------------------------------------------------
    def _unary(self, f0, f1, f2) -> Jet:
        return Jet(f0, _ex(f1) * self.grad, f1 * self.d1, f2 * self.d1 * self.d1 + f1 * self.d2)

    def __neg__(self):
        return Jet(-self.val, -self.grad, -self.d1, -self.d2)

    def __pos__(self):
        return self

    def __add__(self, other):
        if isinstance(other, Jet):
            return Jet(self.val + other.val, self.grad + other.grad, self.d1 + other.d1, self.d2 + other.d2)
        return Jet(self.val + other, self.grad, self.d1, self.d2)

    __radd__ = __add__

    def __sub__(self, other):
        if isinstance(other, Jet):
            return Jet(self.val - other.val, self.grad - other.grad, self.d1 - other.d1, self.d2 - other.d2)
        return Jet(self.val - other, self.grad, self.d1, self.d2)

    def __rsub__(self, other):
        return Jet(other - self.val, -self.grad, -self.d1, -self.d2)

    def __mul__(self, other):
        if isinstance(other, Jet):
            a, b = self, other
            return Jet(
                a.val * b.val,
                _ex(a.val) * b.grad + _ex(b.val) * a.grad,
                a.val * b.d1 + b.val * a.d1,
                a.val * b.d2 + 2.0 * a.d1 * b.d1 + b.val * a.d2,
            )
        return Jet(self.val * other, _ex(other) * self.grad, self.d1 * other, self.d2 * other)

    __rmul__ = __mul__

    def reciprocal(self) -> Jet:
        r = 1.0 / self.val
        return self._unary(r, -r * r, 2.0 * r * r * r)

    def __truediv__(self, other):
        if isinstance(other, Jet):
            return self * other.reciprocal()
        return self * (1.0 / np.asarray(other, dtype=float))

    def __rtruediv__(self, other):
        return self.reciprocal() * other

    def __pow__(self, p):
        if p == 2:
            return self * self
        if isinstance(p, Jet):
            raise TypeError("a jet exponent is not supported")
        v = self.val
        return self._unary(v**p, p * v ** (p - 1), p * (p - 1) * v ** (p - 2))

    def sqrt(self) -> Jet:
        s = np.sqrt(self.val)
        f1 = 0.5 / s
        return self._unary(s, f1, -0.5 * f1 / self.val)

    def sin(self) -> Jet:
        s, c = np.sin(self.val), np.cos(self.val)
        return self._unary(s, c, -s)

    def cos(self) -> Jet:
        s, c = np.sin(self.val), np.cos(self.val)
        return self._unary(c, -s, -c)

    @staticmethod
    def arctan2(y, x) -> Jet:
        """Angle of the vector (x, y); both jets (or one a constant)."""
        if _scalar_like(y) and _scalar_like(x):
            return ScalarJet.arctan2(y, x)
        if not isinstance(y, Jet):
            y = Jet.constant(y, x.grad.shape[-1])
        if not isinstance(x, Jet):
            x = Jet.constant(x, y.grad.shape[-1])
        r2 = x.val * x.val + y.val * y.val
        num1 = x.val * y.d1 - y.val * x.d1
        num2 = x.val * y.d2 - y.val * x.d2
        dr2 = 2.0 * (x.val * x.d1 + y.val * y.d1)
        return Jet(
            np.arctan2(y.val, x.val),
            (_ex(x.val) * y.grad - _ex(y.val) * x.grad) / _ex(r2),
            num1 / r2,
            num2 / r2 - num1 * dr2 / (r2 * r2),
        )

    # -- numpy interoperability -------------------------------------------------------------
    _UFUNCS = {
        np.add: lambda a, b: a + b,
        np.subtract: lambda a, b: a - b,
        np.multiply: lambda a, b: a * b,
        np.true_divide: lambda a, b: a / b,
        np.negative: lambda a: -a,
        np.positive: lambda a: a,
        np.square: lambda a: a * a,
        np.sqrt: lambda a: a.sqrt(),
        np.sin: lambda a: a.sin(),
        np.cos: lambda a: a.cos(),
        np.arctan2: lambda y, x: Jet.arctan2(y, x),
    }

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        if method != "__call__" or kwargs:
            return NotImplemented
        rule = self._UFUNCS.get(ufunc)
        if rule is None:
            raise TypeError(f"mps_core.derivatives.jet: numpy ufunc {ufunc.__name__!r} has no jet rule")
        if len(inputs) == 2 and not isinstance(inputs[0], Jet):
            a, b = inputs
            if ufunc is np.add or ufunc is np.multiply:
                return rule(b, a)
            if ufunc is np.subtract:
                return b.__rsub__(a)
            if ufunc is np.true_divide:
                return b.__rtruediv__(a)
            if ufunc is np.arctan2:
                return Jet.arctan2(a, b)
        return rule(*inputs)

    def __repr__(self):
        return f"Jet(val={self.val!r}, grad={self.grad!r}, d1={self.d1!r}, d2={self.d2!r})"


_NUMBER = (float, int)


def _scalar_like(x) -> bool:
    """A scalar jet, or a plain number (a constant of any jet)."""
    return (
        x.__class__ is ScalarJet
        or isinstance(x, _NUMBER)
        or (isinstance(x, (np.ndarray, np.generic)) and np.ndim(x) == 0 and not isinstance(x, Jet))
    )


def _div(a, b):
    """a / b with numpy's IEEE rules (±inf, nan) where b is zero."""
    try:
        return a / b
    except ZeroDivisionError:
        with np.errstate(divide="ignore", invalid="ignore"):
            return float(np.float64(a) / np.float64(b))


def _call(f, npf, v):
    """math's f(v), or numpy's where math refuses (inf, a negative square root): nan, ±inf."""
    try:
        return f(v)
    except ValueError:
        with np.errstate(invalid="ignore"):
            return float(npf(v))


def _gscale(f, g):
    """f·g for a gradient tuple (the common n = 1, 2 unrolled)."""
    n = len(g)
    if n == 2:
        return (f * g[0], f * g[1])
    if n == 1:
        return (f * g[0],)
    return tuple([f * x for x in g])


def _gadd(a, b):
    if len(a) == 2:
        return (a[0] + b[0], a[1] + b[1])
    return tuple([x + y for x, y in zip(a, b)])


def _gsub(a, b):
    if len(a) == 2:
        return (a[0] - b[0], a[1] - b[1])
    return tuple([x - y for x, y in zip(a, b)])


def _glin(p, a, q, b):
    """p·a + q·b for gradient tuples a, b."""
    if len(a) == 2:
        return (p * a[0] + q * b[0], p * a[1] + q * b[1])
    return tuple([p * x + q * y for x, y in zip(a, b)])


class ScalarJet(Jet):
    """A jet at a single point: ``val``, ``d1``, ``d2`` are floats and the gradient is the tuple
    ``g`` (``grad`` gives it as an array). The same rules as :class:`Jet`, in the same order of
    operations, on Python floats: a position function of n = 1 or 2 coordinates runs several
    times faster than on length-n arrays. Mixed with an array or an array-valued jet it defers
    to :class:`Jet`'s rules."""

    __slots__ = ("g",)

    def __init__(self, val, g, d1, d2):
        self.val = val
        self.g = g
        self.d1 = d1
        self.d2 = d2

    @property
    def grad(self) -> np.ndarray:
        return np.array(self.g)

    @staticmethod
    def _number(o):
        """o as a float if it is a plain number (not a jet, not an array of size > 1), else None."""
        if isinstance(o, _NUMBER):
            return o
        if isinstance(o, (np.ndarray, np.generic)) and np.ndim(o) == 0:
            return float(o)
        return None

    # -- elementary rules ------------------------------------------------------------------
    def _unary(self, f0, f1, f2) -> ScalarJet:
        d1 = self.d1
        return ScalarJet(f0, _gscale(f1, self.g), f1 * d1, f2 * d1 * d1 + f1 * self.d2)

    def __neg__(self):
        return ScalarJet(-self.val, _gscale(-1.0, self.g), -self.d1, -self.d2)

    def __add__(self, other):
        if other.__class__ is ScalarJet:
            return ScalarJet(
                self.val + other.val, _gadd(self.g, other.g), self.d1 + other.d1, self.d2 + other.d2
            )
        o = other if isinstance(other, _NUMBER) else self._number(other)
        if o is not None:
            return ScalarJet(self.val + o, self.g, self.d1, self.d2)
        return Jet.__add__(self, other)

    __radd__ = __add__

    def __sub__(self, other):
        if other.__class__ is ScalarJet:
            return ScalarJet(
                self.val - other.val, _gsub(self.g, other.g), self.d1 - other.d1, self.d2 - other.d2
            )
        o = other if isinstance(other, _NUMBER) else self._number(other)
        if o is not None:
            return ScalarJet(self.val - o, self.g, self.d1, self.d2)
        return Jet.__sub__(self, other)

    def __rsub__(self, other):
        o = other if isinstance(other, _NUMBER) else self._number(other)
        if o is not None:
            return ScalarJet(o - self.val, _gscale(-1.0, self.g), -self.d1, -self.d2)
        return Jet.__rsub__(self, other)

    def __mul__(self, other):
        if other.__class__ is ScalarJet:
            av, bv, ad1, bd1 = self.val, other.val, self.d1, other.d1
            return ScalarJet(
                av * bv,
                _glin(av, other.g, bv, self.g),
                av * bd1 + bv * ad1,
                av * other.d2 + 2.0 * ad1 * bd1 + bv * self.d2,
            )
        o = other if isinstance(other, _NUMBER) else self._number(other)
        if o is not None:
            return ScalarJet(self.val * o, _gscale(o, self.g), self.d1 * o, self.d2 * o)
        return Jet.__mul__(self, other)

    __rmul__ = __mul__

    def reciprocal(self) -> ScalarJet:
        r = _div(1.0, self.val)
        return self._unary(r, -r * r, 2.0 * r * r * r)

    def __truediv__(self, other):
        if other.__class__ is ScalarJet:
            return self * other.reciprocal()
        o = other if isinstance(other, _NUMBER) else self._number(other)
        if o is not None:
            return self * _div(1.0, float(o))
        return Jet.__truediv__(self, other)

    def __pow__(self, p):
        if p == 2:
            return self * self
        if isinstance(p, Jet):
            raise TypeError("a jet exponent is not supported")
        v = np.float64(self.val)
        with np.errstate(all="ignore"):
            f = (v**p, p * v ** (p - 1), p * (p - 1) * v ** (p - 2))
        return self._unary(*(float(x) for x in f))

    def sqrt(self) -> ScalarJet:
        v = self.val
        s = _call(math.sqrt, np.sqrt, v)
        f1 = _div(0.5, s)
        return self._unary(s, f1, _div(-0.5 * f1, v))

    def sin(self) -> ScalarJet:
        v = self.val
        s, c = _call(math.sin, np.sin, v), _call(math.cos, np.cos, v)
        return self._unary(s, c, -s)

    def cos(self) -> ScalarJet:
        v = self.val
        s, c = _call(math.sin, np.sin, v), _call(math.cos, np.cos, v)
        return self._unary(c, -s, -c)

    @staticmethod
    def arctan2(y, x) -> ScalarJet:
        if y.__class__ is not ScalarJet:
            y = Jet.constant(y, len(x.g))
        if x.__class__ is not ScalarJet:
            x = Jet.constant(x, len(y.g))
        xv, yv, xd1, yd1 = x.val, y.val, x.d1, y.d1
        r2 = xv * xv + yv * yv
        num1 = xv * yd1 - yv * xd1
        num2 = xv * y.d2 - yv * x.d2
        dr2 = 2.0 * (xv * xd1 + yv * yd1)
        return ScalarJet(
            math.atan2(yv, xv),
            tuple([_div(xv * a - yv * b, r2) for a, b in zip(y.g, x.g)]),
            _div(num1, r2),
            _div(num2, r2) - _div(num1 * dr2, r2 * r2),
        )


def seed(q, v) -> list[Jet]:
    """Jets of the coordinates themselves at q, differentiated along v (both length n).

    For one point (q of shape (n,)) these are :class:`ScalarJet`; for arrays of points
    (q of shape (..., n)) array-valued :class:`Jet`.
    """
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    n = q.shape[-1]
    if q.ndim == 1 and v.shape == q.shape:
        ql, vl = q.tolist(), v.tolist()
        return [
            ScalarJet(ql[i], tuple([1.0 if k == i else 0.0 for k in range(n)]), vl[i], 0.0) for i in range(n)
        ]
    eye = np.eye(n)
    zero = np.zeros_like(q[..., 0])
    return [Jet(q[..., i], np.broadcast_to(eye[i], q.shape[:-1] + (n,)), v[..., i], zero) for i in range(n)]


def value_of(x):
    """The plain value of a jet or number."""
    return x.val if isinstance(x, Jet) else x
