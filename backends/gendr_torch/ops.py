"""The ops namespace (see :mod:`gendr.ops`) for torch tensors: spec formulas run on it unchanged."""
from __future__ import annotations

import functools
import math

import torch

from gendr.errors import refuse_second_derivatives
from gendr.ops import select_both


def first_order_only(backward):
    """A custom Function's backward that has no second derivative: under ``create_graph=True`` it
    raises instead of returning a first derivative whose own derivative autograd would take as 0
    (torch's once_differentiable catches that only where the incoming gradient requires grad; a
    Hessian-vector product of sum(alpha · w) came back 20-50 % off, silently)."""
    @functools.wraps(backward)
    def checked(ctx, *grads):
        if torch.is_grad_enabled():  # (backward runs with grad mode on only under create_graph=True)
            refuse_second_derivatives(grads)
            with torch.no_grad():  # a constant zero incoming gradient: this part's second derivative is 0
                return backward(ctx, *grads)
        return backward(ctx, *grads)
    return checked


class _WithDerivative(torch.autograd.Function):
    """value(x) evaluated without autograd; its derivative is derivative(x)."""

    @staticmethod
    def forward(ctx, x, value, derivative):
        ctx.derivative = derivative
        ctx.save_for_backward(x)
        with torch.no_grad():
            return value(x)

    @staticmethod
    @first_order_only  # (its derivative is evaluated without a graph)
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        with torch.no_grad():
            return grad * ctx.derivative(x), None, None


def _sigmoid_slope(x):
    return torch.sigmoid(x) * torch.sigmoid(-x)


class _Sigmoid(torch.autograd.Function):
    """torch.sigmoid with the slope σ(x)·σ(−x) in reverse mode and in forward mode (torch.func.jvp:
    compile=True's gradient chain), where torch's own s·(1 − s) cancels in the far tail."""

    @staticmethod
    def forward(x):
        return torch.sigmoid(x)

    @staticmethod
    def setup_context(ctx, inputs, output):
        (x,) = inputs
        ctx.save_for_backward(x)
        ctx.save_for_forward(x)

    @staticmethod
    def backward(ctx, g):
        (x,) = ctx.saved_tensors
        return g * _sigmoid_slope(x)

    @staticmethod
    def jvp(ctx, x_t):
        (x,) = ctx.saved_tensors
        return x_t * _sigmoid_slope(x)


class _PowerOfPositive(torch.autograd.Function):
    """x**e for x > 0, its x-slope taken as ((g·y)·e)/x: 0 where the incoming g is 0, where
    pow's own backward, g·(e·x^(e−1)), gives 0·inf = NaN once the slope overflows (e < 1, tiny x)."""

    @staticmethod
    def forward(ctx, x, e):
        y = x ** e
        ctx.e = e
        ctx.save_for_backward(x, y, e if isinstance(e, torch.Tensor) else None)
        return y

    @staticmethod
    def backward(ctx, g):
        x, y, e_tensor = ctx.saved_tensors
        gy = g * y
        gx = gy * ctx.e / x if ctx.needs_input_grad[0] else None
        ge = (gy * torch.log(x)).sum_to_size(e_tensor.shape) if ctx.needs_input_grad[1] else None
        return gx, ge


class TorchOps:
    pi = math.pi
    inf = math.inf
    exp = staticmethod(torch.exp)
    log = staticmethod(torch.log)
    log1p = staticmethod(torch.log1p)
    expm1 = staticmethod(torch.expm1)
    sqrt = staticmethod(torch.sqrt)
    sin = staticmethod(torch.sin)
    cos = staticmethod(torch.cos)
    tan = staticmethod(torch.tan)
    atan = staticmethod(torch.atan)
    tanh = staticmethod(torch.tanh)
    erf = staticmethod(torch.erf)
    erfc = staticmethod(torch.erfc)
    lgamma = staticmethod(torch.lgamma)
    abs = staticmethod(torch.abs)

    # torch.sigmoid's backward s·(1 − s) loses F's tail: relative error 1e-3 at x = 30 (float64),
    # 0 from x = 37. The slope is taken as σ(x)·σ(−x) instead; the value stays torch.sigmoid's, so an
    # image does not depend on whether a gradient is taped (exp(logsigmoid) is subnormal where
    # torch.sigmoid is 0: the softmax blend then weighed faces that the forward alone left out).
    @staticmethod
    def sigmoid(x):
        return _Sigmoid.apply(x)

    # the default threshold 20 returns x beyond it, 2e-9 off; log1p(e^-40) is below x's ulp at 40
    @staticmethod
    def softplus(x):
        return torch.nn.functional.softplus(x, threshold=40.0)

    @staticmethod
    def power(x, e):
        if isinstance(e, torch.Tensor) or e < 1.0:
            return _PowerOfPositive.apply(x, e)
        return x ** e  # e >= 1: its slope e·x^(e−1) is finite wherever x**e is

    @staticmethod
    def minimum(a, b):
        if not isinstance(b, torch.Tensor):
            return torch.clamp(a, max=b)
        if not isinstance(a, torch.Tensor):
            return torch.clamp(b, max=a)
        return torch.minimum(a, b)

    @staticmethod
    def maximum(a, b):
        if not isinstance(b, torch.Tensor):
            return torch.clamp(a, min=b)
        if not isinstance(a, torch.Tensor):
            return torch.clamp(b, min=a)
        return torch.maximum(a, b)

    @staticmethod
    def where(c, a, b):
        return torch.where(c, a, b)  # accepts Python scalars for a or b

    @staticmethod
    def needs_grad(*xs):
        return any(isinstance(x, torch.Tensor) and x.requires_grad for x in xs)

    @staticmethod
    def branch(c, if_true, if_false, *args):
        return select_both(torch.where, c, if_true, if_false, args)

    @staticmethod
    def clamp(x, lo=None, hi=None):
        return torch.clamp(x, lo, hi)

    @staticmethod
    def full_like(x, v):
        return torch.full_like(x, v)

    @staticmethod
    def with_derivative(value, derivative, x):
        return _WithDerivative.apply(x, value, derivative)

    @staticmethod
    def detach(x):
        return x.detach() if isinstance(x, torch.Tensor) else x


torch_ops = TorchOps()
