"""The ops namespace (see :mod:`gendr.ops`) for Dr.Jit arrays: spec formulas run on it unchanged.

One namespace per floating-point type (``DrJitOps(Float)``): the accuracy switches of ``erfc``
depend on the precision. Works on flat arrays and inside symbolic loops (``dr.while_loop``), with
or without AD.

Functions that Dr.Jit 1.5 lacks (``log1p``, ``expm1``, ``erfc``, ``softplus``, ``sigmoid``) are
built here, accurate in their own precision (a few ulp; ``erfc`` relative error < 1e-7 in float32,
< 1e-11 in float64) with exact analytic derivatives. ``with_derivative`` evaluates ``value`` on the
detached argument and attaches ``derivative`` as a linear term ``d·(x − detach(x))`` (value exactly
``value(x)``, gradient ``derivative(x)``; valid inside symbolic loops, where a ``dr.CustomOp``
cannot be used). Where that derivative is not finite the gradient reported is 0.
"""
from __future__ import annotations

import math

import drjit as dr

_INV_SQRT_PI = 1.0 / math.sqrt(math.pi)


def _lin(value, deriv, x):
    """``value`` (computed from detach(x)) with the derivative ``deriv`` w.r.t. ``x`` attached."""
    if not dr.grad_enabled(x):
        return value
    xd = dr.detach(x)
    delta = dr.select(dr.isfinite(xd), x - xd, 0.0)
    return value + dr.select(dr.isfinite(deriv), deriv, 0.0) * delta


class DrJitOps:
    """Ops namespace for one Dr.Jit float type (e.g. ``drjit.llvm.ad.Float64``)."""

    pi = math.pi
    inf = math.inf

    def __init__(self, Float):
        self.Float = Float
        self.double = dr.type_v(Float) == dr.VarType.Float64
        # erfc: 1 − erf below the switch, Laplace's continued fraction above (see module docstring)
        self._erfc_switch, self._erfc_depth = (3.0, 30) if self.double else (2.0, 14)

    # --- plain elementwise functions ----------------------------------------------------------
    exp = staticmethod(dr.exp)
    log = staticmethod(dr.log)
    sqrt = staticmethod(dr.sqrt)
    sin = staticmethod(dr.sin)
    cos = staticmethod(dr.cos)
    tan = staticmethod(dr.tan)
    atan = staticmethod(dr.atan)
    tanh = staticmethod(dr.tanh)
    erf = staticmethod(dr.erf)
    lgamma = staticmethod(dr.lgamma)
    abs = staticmethod(dr.abs)
    detach = staticmethod(dr.detach)

    def _f(self, x):
        return x if isinstance(x, self.Float) else self.Float(x)

    def power(self, x, e):
        if not isinstance(e, dr.ArrayBase) and float(e).is_integer():
            return x ** e  # Dr.Jit multiplies: exact
        # not dr.power: its exp2 returns −inf for results in [2^−1024, 2^−1023.5) (float64, LLVM)
        pos = x > 0.0
        return dr.select(pos, dr.exp(e * dr.log(dr.select(pos, x, 1.0))), 0.0)

    def minimum(self, a, b):
        return dr.minimum(a, b)

    def maximum(self, a, b):
        return dr.maximum(a, b)

    def where(self, c, a, b):
        if not isinstance(a, dr.ArrayBase) and not isinstance(b, dr.ArrayBase):
            a = self.Float(a)
        return dr.select(c, a, b)

    @staticmethod
    def needs_grad(*xs):
        return any(isinstance(x, dr.ArrayBase) and dr.grad_enabled(x) for x in xs)

    def branch(self, c, if_true, if_false, *args):
        # a symbolic conditional: in a loop kernel, a SIMD packet (or GPU warp) none of whose lanes
        # takes a side jumps over it; lanes get exactly what the select of both would give them.
        # (AD follows only ``args`` into it, not the callables' closures.)
        if not isinstance(c, dr.ArrayBase):
            return if_true(*args) if c else if_false(*args)
        many = []

        def side(fn):
            def run(*a):
                r = fn(*a)
                many.append(isinstance(r, tuple))
                return tuple(self._f(v) for v in r) if many[-1] else (self._f(r),)
            return run
        args = tuple(self._f(a) for a in args)
        out = dr.if_stmt(args, c, side(if_true), side(if_false), mode="symbolic")
        return tuple(out) if many[0] else out[0]

    def clamp(self, x, lo=None, hi=None):
        # selects, not minimum/maximum: at x == lo (or hi) the gradient passes, as torch.clamp's does
        if lo is not None:
            x = dr.select(x < lo, lo, x)
        if hi is not None:
            x = dr.select(x > hi, hi, x)
        return x

    def full_like(self, x, v):
        return dr.full(type(x), v, dr.width(x))

    # --- functions Dr.Jit does not have -----------------------------------------------------------
    def log1p(self, x):
        # log(u) − ((u − 1) − x)/u with u = 1 + x: accurate to ~1 ulp, exact derivative under AD
        x = self._f(x)
        u = 1.0 + x
        special = (u == 0.0) | (u == math.inf)
        us = dr.select(special, 2.0, u)
        xs = dr.select(special, 1.0, x)
        r = dr.log(us) - ((us - 1.0) - xs) / us
        return dr.select(special, dr.select(u == 0.0, -math.inf, math.inf), r)

    def expm1(self, x):
        # Kahan: (u − 1)·x / log(u), u = e^x; derivative e^x = expm1(x) + 1
        x = self._f(x)
        xd = dr.detach(x)
        u = dr.exp(xd)
        um1 = u - 1.0
        ok = (um1 != 0.0) & (um1 != -1.0) & (u != math.inf)
        us = dr.select(ok, u, 2.0)
        v = dr.select(ok, (us - 1.0) * xd / dr.log(us), dr.select(um1 == 0.0, xd, um1))
        return _lin(v, u, x)

    def erfc(self, x):
        x = self._f(x)
        xd = dr.detach(x)
        tail = xd > self._erfc_switch

        def fraction(xd):
            z = dr.select(tail, xd, self._erfc_switch + 1.0)
            t = z
            for k in range(self._erfc_depth, 0, -1):
                t = z + (0.5 * k) / t
            return dr.exp(-z * z) * _INV_SQRT_PI / t
        v = self.branch(tail, fraction, lambda xd: 1.0 - dr.erf(xd), xd)
        return _lin(v, (-2.0 * _INV_SQRT_PI) * dr.exp(-xd * xd), x)

    def sigmoid(self, x):
        x = self._f(x)
        pos = x >= 0.0
        e = dr.exp(dr.select(pos, -x, x))  # e^(−|x|) <= 1 (no overflow; derivative ±e at 0 too)
        r = 1.0 / (1.0 + e)
        return dr.select(pos, r, e * r)

    def softplus(self, x):
        x = self._f(x)
        pos = x >= 0.0
        e = dr.exp(dr.select(pos, -x, x))
        # log1p(e) for e = e^(−|x|) in [0, 1] (or NaN): u is never 0 or inf, so log1p's special
        # cases and their selects drop out (the logistic loops −2 to −11 %, same values and derivatives)
        u = 1.0 + e
        l = dr.log(u) - ((u - 1.0) - e) / u
        return dr.select(pos, x + l, l)

    def with_derivative(self, value, derivative, x):
        x = self._f(x)
        xd = dr.detach(x)
        v = value(xd)
        if not dr.grad_enabled(x):
            return v
        return _lin(v, derivative(xd), x)
