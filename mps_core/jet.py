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
"""

from __future__ import annotations

import numpy as np

__all__ = ["Jet", "seed", "value_of"]


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
    def constant(value, n: int) -> "Jet":
        value = np.asarray(value, dtype=float)
        z = np.zeros_like(value)
        return Jet(value, np.zeros(value.shape + (n,)), z, z)

    # -- elementary rules ------------------------------------------------------------------
    def _unary(self, f0, f1, f2) -> "Jet":
        return Jet(f0, _ex(f1) * self.grad, f1 * self.d1, f2 * self.d1 * self.d1 + f1 * self.d2)

    def __neg__(self):
        return Jet(-self.val, -self.grad, -self.d1, -self.d2)

    def __pos__(self):
        return self

    def __add__(self, other):
        if isinstance(other, Jet):
            return Jet(self.val + other.val, self.grad + other.grad, self.d1 + other.d1,
                       self.d2 + other.d2)
        return Jet(self.val + other, self.grad, self.d1, self.d2)

    __radd__ = __add__

    def __sub__(self, other):
        if isinstance(other, Jet):
            return Jet(self.val - other.val, self.grad - other.grad, self.d1 - other.d1,
                       self.d2 - other.d2)
        return Jet(self.val - other, self.grad, self.d1, self.d2)

    def __rsub__(self, other):
        return Jet(other - self.val, -self.grad, -self.d1, -self.d2)

    def __mul__(self, other):
        if isinstance(other, Jet):
            a, b = self, other
            return Jet(a.val * b.val,
                       _ex(a.val) * b.grad + _ex(b.val) * a.grad,
                       a.val * b.d1 + b.val * a.d1,
                       a.val * b.d2 + 2.0 * a.d1 * b.d1 + b.val * a.d2)
        return Jet(self.val * other, _ex(other) * self.grad, self.d1 * other, self.d2 * other)

    __rmul__ = __mul__

    def reciprocal(self) -> "Jet":
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
        return self._unary(v ** p, p * v ** (p - 1), p * (p - 1) * v ** (p - 2))

    def sqrt(self) -> "Jet":
        s = np.sqrt(self.val)
        f1 = 0.5 / s
        return self._unary(s, f1, -0.5 * f1 / self.val)

    def sin(self) -> "Jet":
        s, c = np.sin(self.val), np.cos(self.val)
        return self._unary(s, c, -s)

    def cos(self) -> "Jet":
        s, c = np.sin(self.val), np.cos(self.val)
        return self._unary(c, -s, -c)

    @staticmethod
    def arctan2(y, x) -> "Jet":
        """Angle of the vector (x, y); both jets (or one a constant)."""
        if not isinstance(y, Jet):
            y = Jet.constant(y, x.grad.shape[-1])
        if not isinstance(x, Jet):
            x = Jet.constant(x, y.grad.shape[-1])
        r2 = x.val * x.val + y.val * y.val
        num1 = x.val * y.d1 - y.val * x.d1
        num2 = x.val * y.d2 - y.val * x.d2
        dr2 = 2.0 * (x.val * x.d1 + y.val * y.d1)
        return Jet(np.arctan2(y.val, x.val),
                   (_ex(x.val) * y.grad - _ex(y.val) * x.grad) / _ex(r2),
                   num1 / r2,
                   num2 / r2 - num1 * dr2 / (r2 * r2))

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
            raise TypeError(f"mps_core.jet: numpy ufunc {ufunc.__name__!r} has no jet rule")
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


def seed(q, v) -> list[Jet]:
    """Jets of the coordinates themselves at q, differentiated along v (both length n)."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    n = q.shape[-1]
    eye = np.eye(n)
    zero = np.zeros_like(q[..., 0])
    return [Jet(q[..., i], np.broadcast_to(eye[i], q.shape[:-1] + (n,)), v[..., i], zero)
            for i in range(n)]


def value_of(x):
    """The plain value of a jet or number."""
    return x.val if isinstance(x, Jet) else x
