"""The array-ops namespace that spec formulas are written against.

Every distribution and T-conorm formula in ``gendr`` is a plain Python function ``f(ops, x, ...)``
that touches its arrays only through arithmetic operators (``+ - * / **``, unary ``-``, comparisons)
and the functions of an *ops namespace*. A backend supplies one namespace for its array type
(``gendr_torch.ops.TorchOps``, ...), so each formula exists once. :class:`NumpyOps` here evaluates
the formulas in float64 NumPy for the spec layer itself (culling radii, tests, plots).

Members every namespace provides (all elementwise, broadcasting like NumPy):

=================  =========================================================================
``exp log log1p expm1 sqrt sin cos tan atan tanh erf erfc lgamma abs``  the usual functions
``softplus(x)``    ``log(1 + exp(x))`` without overflow
``sigmoid(x)``     ``1 / (1 + exp(-x))`` without overflow
``power(x, e)``    ``x**e`` for ``x > 0`` and ``e`` a Python float or a learnable scalar array
                   (``x = 0`` only for a Python float ``e > 1``: 0, slope 0); where the incoming
                   gradient is 0 the gradient is 0, also where the slope e·x^(e−1) overflows
``where(c, a, b)`` select; ``c`` is a boolean array; ``a``/``b`` arrays or Python floats
``branch(c, if_true, if_false, *args)``  ``where(c, if_true(*args), if_false(*args))`` for two
                   callables returning an array or a tuple of arrays (selected entry by entry); a
                   backend may skip a callable where no entry needs it (Dr.Jit: a branch that SIMD
                   packets jump over). Differentiable inputs must come in through ``args``: what a
                   callable reads from its closure is a constant to Dr.Jit inside loop kernels
``minimum maximum`` elementwise
``clamp(x, lo, hi)`` elementwise, ``lo``/``hi`` Python floats or None
``full_like(x, v)`` an array shaped like ``x`` filled with the Python float ``v``
``pi inf``         Python floats
``detach(x)``      ``x`` without gradient tracking (NumPy: ``x`` itself)
``needs_grad(*xs)`` whether a gradient may flow through any of ``xs`` (NumPy: False), so that a
                   formula guarding its gradient can skip the guard's second evaluation
``with_derivative(value, derivative, x)``  ``value(x)`` whose derivative w.r.t. ``x`` is
                   ``derivative(x)``; the backend must not differentiate through ``value`` (used
                   where ``value`` is an iterative series, e.g. the incomplete gamma function)
=================  =========================================================================

Formulas must stay differentiable under autograd: where a branch not taken can be inf/NaN, feed it a
safe argument first (``x_safe = where(c, x, 1.0)``) so that its gradient is not NaN.
"""
from __future__ import annotations

import functools
import math

import numpy as np

_erf = np.frompyfunc(math.erf, 1, 1)
_erfc = np.frompyfunc(math.erfc, 1, 1)
_lgamma = np.frompyfunc(math.lgamma, 1, 1)


def _f64(fn):
    return lambda x: np.asarray(fn(np.asarray(x, dtype=np.float64)), dtype=np.float64)


def quiet_numpy(method):
    """Decorate a spec method ``(self, ops, ...)``: under NumPy ops, overflow and division by zero do
    not warn. Their ±inf (and the 0 after it) are what the formulas mean — a strict generator at
    p = 1 is +inf, a density at |x| = 1e300 underflows through an inf — and the public NumPy calls
    should not look broken at such arguments. NaN (an invalid operation) still warns."""
    @functools.wraps(method)
    def call(self, ops, *args, **kwargs):
        if isinstance(ops, NumpyOps):
            with np.errstate(divide="ignore", over="ignore"):
                return method(self, ops, *args, **kwargs)
        return method(self, ops, *args, **kwargs)
    return call


def select_both(where, c, if_true, if_false, args):
    """``branch`` by evaluating both callables and selecting (NumPy, torch)."""
    a, b = if_true(*args), if_false(*args)
    if isinstance(a, tuple):
        return tuple(where(c, u, v) for u, v in zip(a, b))
    return where(c, a, b)


class NumpyOps:
    """float64 NumPy implementation of the ops namespace (no autodiff)."""

    pi = math.pi
    inf = math.inf
    exp = staticmethod(np.exp)
    log = staticmethod(np.log)
    log1p = staticmethod(np.log1p)
    expm1 = staticmethod(np.expm1)
    sqrt = staticmethod(np.sqrt)
    sin = staticmethod(np.sin)
    cos = staticmethod(np.cos)
    tan = staticmethod(np.tan)
    atan = staticmethod(np.arctan)
    tanh = staticmethod(np.tanh)
    abs = staticmethod(np.abs)
    minimum = staticmethod(np.minimum)
    maximum = staticmethod(np.maximum)
    erf = staticmethod(_f64(_erf))
    erfc = staticmethod(_f64(_erfc))
    lgamma = staticmethod(_f64(_lgamma))

    power = staticmethod(np.power)

    @staticmethod
    def softplus(x):
        return np.logaddexp(0.0, x)

    @staticmethod
    def sigmoid(x):
        x = np.asarray(x, dtype=np.float64)
        return np.exp(-np.logaddexp(0.0, -x))

    @staticmethod
    def where(c, a, b):
        return np.where(c, a, b)

    @staticmethod
    def branch(c, if_true, if_false, *args):
        return select_both(np.where, c, if_true, if_false, args)

    @staticmethod
    def clamp(x, lo=None, hi=None):
        return np.clip(x, lo, hi)

    @staticmethod
    def full_like(x, v):
        return np.full_like(np.asarray(x, dtype=np.float64), v)

    @staticmethod
    def with_derivative(value, derivative, x):
        return value(x)

    @staticmethod
    def detach(x):
        return x

    @staticmethod
    def needs_grad(*xs):
        return False

    @staticmethod
    def asarray(x):
        return np.asarray(x, dtype=np.float64)


numpy_ops = NumpyOps()
