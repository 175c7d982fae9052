"""``ops.branch``: the same values as a select of both sides, in every namespace; in Dr.Jit loop
kernels a real branch whose derivatives follow its ``args``. And Dr.Jit's softplus, written for
speed, equals its plain form log1p(exp(·)) bit for bit."""
from __future__ import annotations

import numpy as np
import pytest

import gendr
from gendr.grid import DISTRIBUTION_SETTINGS
from gendr.ops import numpy_ops, select_both

X = np.concatenate([-np.logspace(-6, 3, 300)[::-1], [0.0], np.logspace(-6, 3, 300)])
SMALL = np.linspace(-5.0, 5.0, 101)


def _sides(ops):
    def neg(x, y):
        return ops.exp(x) + y, x * 2.0

    def pos(x, y):
        return ops.log(ops.where(x > 0.0, x, 1.0)) - y, x * 3.0
    return neg, pos


def _check_branch(ops, x, to_np):
    neg, pos = _sides(ops)
    y = x * 0.5
    a, b = ops.branch(x > 0.0, pos, neg, x, y)
    xs = to_np(x)
    want_a = np.where(xs > 0, np.log(np.where(xs > 0, xs, 1.0)) - 0.5 * xs, np.exp(xs) + 0.5 * xs)
    # float64 throughout: the same formula in another library rounds alike to ~1e-16 (drjit exp/log may
    # differ in the last bits)
    np.testing.assert_allclose(to_np(a), want_a, rtol=1e-13, atol=1e-13)
    np.testing.assert_array_equal(to_np(b), np.where(xs > 0, 3.0 * xs, 2.0 * xs))
    single = ops.branch(x > 0.0, lambda x: x * 3.0, lambda x: x * 2.0, x)  # one array, not a tuple
    np.testing.assert_array_equal(to_np(single), to_np(b))


def test_numpy_and_torch_branch_select():
    _check_branch(numpy_ops, SMALL, np.asarray)
    torch = pytest.importorskip("torch")
    from gendr_torch.ops import torch_ops
    _check_branch(torch_ops, torch.tensor(SMALL), lambda t: t.numpy())


dr = pytest.importorskip("drjit")
from drjit.llvm.ad import Float, Float64, UInt32  # noqa: E402
from gendr_drjit.ops import DrJitOps  # noqa: E402


def test_drjit_branch_selects():
    _check_branch(DrJitOps(Float64), Float64(SMALL), lambda a: np.asarray(a, dtype=np.float64))


class _SelectBoth(DrJitOps):
    """Dr.Jit ops whose branch evaluates both sides and selects (what the formulas did before)."""

    def branch(self, c, if_true, if_false, *args):
        return select_both(self.where, c, if_true, if_false, args)


def _value_and_derivative(fn, T, x, in_loop):
    """(fn(x), d fn/dx) by forward-mode AD, evaluated or inside a symbolic loop (one lane per x)."""
    if not in_loop:
        xg = T(x)
        dr.enable_grad(xg)
        y = fn(xg)
        dr.forward_from(xg)
        return np.asarray(dr.detach(y), dtype=np.float64), np.asarray(dr.grad(y), dtype=np.float64)
    xs = T(x)

    def body(i, v, g):
        with dr.isolate_grad():
            xg = T(dr.gather(T, xs, i))
            dr.enable_grad(xg)
            y = fn(xg)
            dr.forward(xg, dr.ADFlag.ClearEdges)
            return i + 1, dr.detach(y), dr.grad(y)
    i0 = dr.arange(UInt32, len(x))
    _, v, g = dr.while_loop((i0, dr.zeros(T, len(x)), dr.zeros(T, len(x))), lambda i, v, g: i < i0 + 1, body)
    return np.asarray(v, dtype=np.float64), np.asarray(g, dtype=np.float64)


def _same(a, b):
    return bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))


def test_drjit_branch_differentiates_its_args_inside_loops():
    ops = DrJitOps(Float64)
    x = np.linspace(-2.0, 2.0, 41)

    def fn(x):
        return ops.branch(x > 0.0, lambda x: x * x, lambda x: 3.0 * x, x)
    for in_loop in (False, True):
        v, g = _value_and_derivative(fn, Float64, x, in_loop)
        np.testing.assert_array_equal(v, np.where(x > 0, x * x, 3 * x))
        np.testing.assert_array_equal(g, np.where(x > 0, 2 * x, 3.0))


@pytest.mark.parametrize("T", [Float, Float64], ids=["float32", "float64"])
@pytest.mark.parametrize("name,params,rev", DISTRIBUTION_SETTINGS,
                         ids=[f"{n}{p.get('shape', '')}{'+rev' if r else ''}" for n, p, r in DISTRIBUTION_SETTINGS])
def test_formulas_branch_exactly_like_select(T, name, params, rev):
    """Every grid distribution's (F, log(1 − F)) and their x-derivatives, as the renderer's loops
    evaluate them (inside a symbolic loop) and evaluated: equal to the select-both form, bit for bit
    (up to the sign of zero), so the branches change no result."""
    d = gendr.distribution(name, reversed=rev, **params)
    for k in (0, 1):
        for in_loop in (False, True):
            got = _value_and_derivative(lambda x: d.cdf_and_log_sf(DrJitOps(T), x)[k], T, X, in_loop)
            want = _value_and_derivative(lambda x: d.cdf_and_log_sf(_SelectBoth(T), x)[k], T, X, in_loop)
            assert _same(got[0], want[0]) and _same(got[1], want[1]), (k, in_loop)


@pytest.mark.parametrize("rev", [False, True])
@pytest.mark.parametrize("shift", [0.0, 0.7])
def test_shared_evaluation_equals_the_separate_functions(rev, shift):
    """gamma's cdf_and_log_sf (one evaluation through the family's cdf_and_logs) equals cdf and
    log_sf computed separately, reversed and shifted too."""
    d = gendr.distribution("gamma", shape=2.0, reversed=rev, shift=shift)
    F, log_sf = d.cdf_and_log_sf(numpy_ops, X)
    np.testing.assert_array_equal(F, d.cdf(numpy_ops, X))
    np.testing.assert_array_equal(log_sf, d.log_sf(numpy_ops, X))


def test_cdf_and_logs_requires_accurate_logs():
    from gendr.distributions import DistributionFamily
    with pytest.raises(ValueError, match="'mine'.*accurate_logs"):
        DistributionFamily("mine", lambda ops, x: x, lambda ops, x: x, support=lambda: (0.0, 1.0),
                           tails=("bounded", "bounded"), cdf_and_logs=lambda ops, x: (x, x, x))


@pytest.mark.parametrize("T", [Float, Float64], ids=["float32", "float64"])
def test_drjit_softplus_equals_log1p_of_exp(T):
    """softplus(x) = max(x, 0) + log1p(e^(−|x|)) without log1p's special cases (its argument lies in
    [0, 1]): values and forward derivatives, evaluated and inside a loop, and reverse-mode
    gradients equal the form through ``ops.log1p``, bit for bit, ±inf and NaN included."""
    ops = DrJitOps(T)

    def plain(x):
        pos = x >= 0.0
        l = ops.log1p(dr.exp(dr.select(pos, -x, x)))
        return dr.select(pos, x + l, l)
    x = np.concatenate([X, SMALL, [np.inf, -np.inf, np.nan, -0.0, 88.0, -104.0, 1e30, -1e30]])
    for in_loop in (False, True):
        got = _value_and_derivative(ops.softplus, T, x, in_loop)
        want = _value_and_derivative(plain, T, x, in_loop)
        assert _same(got[0], want[0]) and _same(got[1], want[1]), in_loop
    grads = []
    for fn in (ops.softplus, plain):
        xg = T(x)
        dr.enable_grad(xg)
        dr.backward(dr.sum(fn(xg) * T(np.linspace(-1.0, 2.0, len(x)))))
        grads.append(np.asarray(dr.grad(xg), dtype=np.float64))
    assert _same(*grads)


def test_needs_grad_and_the_single_evaluation_of_guarded_generators():
    """``needs_grad`` is True exactly where a gradient can flow (torch requires_grad, Dr.Jit AD);
    without one, a guarded generator (Schweizer–Sklar's expm1(p·log(1 − x))) is evaluated once, to
    the values of the twice-evaluated gradient guard, inf where it overflows included."""
    torch = pytest.importorskip("torch")
    from gendr_torch.ops import torch_ops
    assert not numpy_ops.needs_grad(np.ones(3), 1.0)
    t = torch.ones(3)
    assert not torch_ops.needs_grad(t, 1.0) and torch_ops.needs_grad(t, t.clone().requires_grad_(True))
    x = torch.tensor([0.0, 1e-8, 0.3, 0.9, 1.0 - 1e-7, 1.0], dtype=torch.float64)
    ss = gendr.tconorm("schweizer_sklar", p=-4.0)
    lg = torch.log1p(-x).requires_grad_(True)  # the generator reads log(1 − x)
    with_grad = ss.generator(torch_ops, x, lg)
    without = ss.generator(torch_ops, x, torch.log1p(-x))
    assert torch.equal(with_grad.detach(), without) and torch.isinf(without[-1])
    with_grad.sum().backward()
    assert torch.isfinite(lg.grad).all() and lg.grad[-1] == 0.0
    dr_ = pytest.importorskip("drjit")
    from drjit.llvm.ad import Float64
    from gendr_drjit.ops import DrJitOps
    d = Float64(x.numpy())
    assert not DrJitOps(Float64).needs_grad(d, 1.0)
    dr_.enable_grad(d)
    assert DrJitOps(Float64).needs_grad(1.0, d)


@pytest.mark.parametrize("family,p", [("schweizer_sklar", -4.0), ("aczel_alsina", 4.0), ("dombi", 4.0)])
def test_a_learnable_p_keeps_the_guard_where_the_inputs_need_no_gradient(family, p):
    """A generator that overflows and reads a learnable p: its p-gradient stays finite (zero where
    the generator is inf) also when x and log(1 − x) carry no gradient (the single evaluation
    would give 0·inf = NaN there)."""
    torch = pytest.importorskip("torch")
    from gendr_torch.ops import torch_ops
    pt = torch.tensor(p, dtype=torch.float64, requires_grad=True)
    t = gendr.tconorm(family, p=pt)
    x = torch.tensor([0.1, 0.6, 1.0 - 1e-12, 1.0], dtype=torch.float64)
    g = t.generator(torch_ops, x, torch.log1p(-x))
    assert torch.isinf(g[-1])
    g[torch.isfinite(g)].sum().backward()
    assert torch.isfinite(pt.grad)
