"""T-conorm specs: axioms, generator form == paper formula, n-ary aggregate, gradients, numerics.

Every test runs over ONE list of example settings (:data:`SETTINGS`) covering every registered
family with several parameters, including the domain edges. Values are evaluated with
``gendr.ops.numpy_ops`` (float64); the autograd/float32 checks use the torch ops namespace.

Tolerances (absolute, float64, on values in [0, 1]): identities that hold exactly up to rounding
(commutativity, neutral element, boundary) 1e-12; identities that compose several transcendental
functions (associativity, generator form vs binary formula, n-ary aggregate vs folds, De Morgan
against the independent T-norm table) 1e-9.
"""
from __future__ import annotations

import math
import re
import random

import numpy as np
import pytest

from gendr import TCONORMS, tconorm
from gendr.errors import ParameterError, UnknownNameError
from gendr.ops import numpy_ops as O
from gendr.tconorms import ARCHIMEDEAN, HARD_OR, MAX, MEAN, TConorm

# Formulas legitimately hit log(0) = -inf and 1/0 = inf at x = 1 (NumPy warns about it).
pytestmark = [pytest.mark.filterwarnings("ignore:divide by zero:RuntimeWarning"),
              pytest.mark.filterwarnings("ignore:overflow:RuntimeWarning")]

SETTINGS = [
    ("max", {}),
    ("or", {}),
    ("average", {}),  # not a T-conorm: its own tests below
    ("probabilistic", {}),
    ("einstein", {}),
    ("hamacher", {"p": 0.0}), ("hamacher", {"p": 0.3}), ("hamacher", {"p": 1.0}),
    ("hamacher", {"p": 2.0}), ("hamacher", {"p": 10.0}),
    ("frank", {"p": 0.01}), ("frank", {"p": 0.5}), ("frank", {"p": 2.0}), ("frank", {"p": 100.0}),
    ("yager", {"p": 0.5}), ("yager", {"p": 1.0}), ("yager", {"p": 2.0}), ("yager", {"p": 4.0}),
    ("aczel_alsina", {"p": 0.5}), ("aczel_alsina", {"p": 1.0}), ("aczel_alsina", {"p": 2.0}),
    ("aczel_alsina", {"p": 5.0}),
    ("dombi", {"p": 0.5}), ("dombi", {"p": 1.0}), ("dombi", {"p": 2.0}), ("dombi", {"p": 5.0}),
    ("schweizer_sklar", {"p": -0.1}), ("schweizer_sklar", {"p": -1.0}), ("schweizer_sklar", {"p": -2.0}),
    ("schweizer_sklar", {"p": -5.0}),
]
ALL = [tconorm(name, **kw) for name, kw in SETTINGS]
SOFT = [t for t in ALL if t.kind not in (HARD_OR, MEAN)]  # satisfy the axioms on all of [0, 1]
ARCH = [t for t in ALL if t.kind == ARCHIMEDEAN]


def _params(ts):
    return pytest.mark.parametrize("t", ts, ids=[t.label() for t in ts])


EXACT, COMPOSED = 1e-12, 1e-9

# 0, 1 and values crowding both ends, plus a regular grid
GRID = np.unique(np.concatenate([[0.0, 1e-12, 1e-6, 1e-3, 1 - 1e-3, 1 - 1e-6, 1.0],
                                 np.linspace(0.0, 1.0, 21)]))
A2, B2 = (m.ravel() for m in np.meshgrid(GRID, GRID, indexing="ij"))
INTERIOR = np.linspace(0.02, 0.98, 25)
AI, BI = (m.ravel() for m in np.meshgrid(INTERIOR, INTERIOR, indexing="ij"))


def S(t, a, b):
    return np.asarray(t.binary(O, np.asarray(a, float), np.asarray(b, float)), float)


def G(t, x):
    return np.asarray(t.generator(O, np.asarray(x, float)), float)


def Ginv(t, s):
    return np.asarray(t.generator_inverse(O, np.asarray(s, float)), float)


def test_settings_cover_every_family():
    assert {name for name, _ in SETTINGS} == set(TCONORMS)
    assert {t.kind for t in ALL} == {ARCHIMEDEAN, MAX, HARD_OR, MEAN}
    # every family is a T-conorm except the mean, and the mean is the only non-T-conorm
    assert {t.name for t in ALL if not t.is_tconorm} == {"average"}


# ------------------------------------------------------------------------------------------------
# T-conorm axioms of the paper's binary formula (max and every archimedean family, on [0, 1]²)
# ------------------------------------------------------------------------------------------------

@_params(SOFT)
def test_range_and_finite(t):
    v = S(t, A2, B2)
    assert np.all(np.isfinite(v))
    assert v.min() >= 0.0 and v.max() <= 1.0


@_params(SOFT)
def test_commutative(t):
    np.testing.assert_allclose(S(t, A2, B2), S(t, B2, A2), rtol=0, atol=EXACT)


@_params(SOFT)
def test_associative(t):
    rng = np.random.default_rng(0)
    a, b, c = rng.uniform(0, 1, (3, 400))
    # include exact ends
    edge = np.array([0.0, 1.0, 0.5, 1e-9, 1 - 1e-9])
    ea, eb, ec = (m.ravel() for m in np.meshgrid(edge, edge, edge, indexing="ij"))
    a, b, c = np.concatenate([a, ea]), np.concatenate([b, eb]), np.concatenate([c, ec])
    np.testing.assert_allclose(S(t, S(t, a, b), c), S(t, a, S(t, b, c)), rtol=0, atol=COMPOSED)


@_params(SOFT)
def test_monotone_in_each_argument(t):
    v = S(t, A2, B2).reshape(len(GRID), len(GRID))
    assert np.all(np.diff(v, axis=0) >= -EXACT), "not non-decreasing in a"
    assert np.all(np.diff(v, axis=1) >= -EXACT), "not non-decreasing in b"


@_params(SOFT)
def test_neutral_element_zero(t):
    np.testing.assert_allclose(S(t, GRID, np.zeros_like(GRID)), GRID, rtol=0, atol=EXACT)
    np.testing.assert_allclose(S(t, np.zeros_like(GRID), GRID), GRID, rtol=0, atol=EXACT)


@_params(SOFT)
def test_boundary_one(t):
    np.testing.assert_allclose(S(t, GRID, np.ones_like(GRID)), 1.0, rtol=0, atol=EXACT)
    np.testing.assert_allclose(S(t, np.ones_like(GRID), GRID), 1.0, rtol=0, atol=EXACT)


@_params(SOFT)
def test_between_max_and_one(t):
    # every T-conorm is >= max (the smallest T-conorm)
    assert np.all(S(t, A2, B2) >= np.maximum(A2, B2) - EXACT)


def test_max_is_max():
    t = tconorm("max")
    np.testing.assert_array_equal(S(t, A2, B2), np.maximum(A2, B2))
    ps = [np.array([0.1, 0.9, 0.0]), np.array([0.5, 0.2, 0.0]), np.array([0.3, 0.95, 1.0])]
    np.testing.assert_array_equal(t.aggregate(O, ps), np.max(ps, axis=0))


# ------------------------------------------------------------------------------------------------
# De Morgan with the dual T-norm, and the T-norm against the paper's T-norm table
# ------------------------------------------------------------------------------------------------

def _ref_tnorm(t, a, b):
    """The T-norm column of the paper's table, written independently of the T-conorm formulas."""
    p = t.kwargs.get("p")
    with np.errstate(all="ignore"):
        if t.name == "max":
            return np.minimum(a, b)
        if t.name == "probabilistic":
            return a * b
        if t.name == "einstein":
            return a * b / (2.0 - (a + b - a * b))
        if t.name == "hamacher":
            return a * b / (p + (1 - p) * (a + b - a * b))
        if t.name == "frank":
            return np.log1p((p ** a - 1) * (p ** b - 1) / (p - 1)) / np.log(p)
        if t.name == "yager":
            return np.maximum(0.0, 1 - ((1 - a) ** p + (1 - b) ** p) ** (1 / p))
        if t.name == "aczel_alsina":
            return np.exp(-((-np.log(a)) ** p + (-np.log(b)) ** p) ** (1 / p))
        if t.name == "dombi":
            return 1 / (1 + (((1 - a) / a) ** p + ((1 - b) / b) ** p) ** (1 / p))
        if t.name == "schweizer_sklar":
            return (a ** p + b ** p - 1) ** (1 / p)
    raise AssertionError(t.name)


@_params(SOFT)
def test_de_morgan_dual_tnorm(t):
    T = np.asarray(t.tnorm(O, A2, B2), float)
    np.testing.assert_allclose(T, 1.0 - S(t, 1.0 - A2, 1.0 - B2), rtol=0, atol=EXACT)
    # the other direction: S(a, b) = 1 − T(1 − a, 1 − b) (interior: 1 − (1 − a) != a in floats, and
    # S(a, b) with p < 1 has an infinite slope at 0)
    np.testing.assert_allclose(S(t, AI, BI), 1.0 - np.asarray(t.tnorm(O, 1.0 - AI, 1.0 - BI)),
                               rtol=0, atol=EXACT)
    # T-norm axioms: neutral element 1, T <= min, range
    np.testing.assert_allclose(np.asarray(t.tnorm(O, GRID, np.ones_like(GRID))), GRID, rtol=0, atol=EXACT)
    assert np.all(T <= np.minimum(A2, B2) + EXACT)
    assert np.all((T >= -EXACT) & (T <= 1 + EXACT))
    # and it is the T-norm of the paper's table
    np.testing.assert_allclose(np.asarray(t.tnorm(O, AI, BI)), _ref_tnorm(t, AI, BI), rtol=0, atol=COMPOSED)


# ------------------------------------------------------------------------------------------------
# The hard logical "or"
# ------------------------------------------------------------------------------------------------

def test_or_is_logical_or_on_crisp_inputs():
    t = tconorm("or")
    assert not t.differentiable
    crisp = np.array([0.0, 1.0])
    a, b, c = (m.ravel() for m in np.meshgrid(crisp, crisp, crisp, indexing="ij"))
    expect = np.logical_or(a > 0.5, b > 0.5).astype(float)
    np.testing.assert_array_equal(S(t, a, b), expect)
    # axioms on {0, 1}: commutative, associative, neutral 0, boundary 1, monotone (0 <= 1)
    np.testing.assert_array_equal(S(t, a, b), S(t, b, a))
    np.testing.assert_array_equal(S(t, S(t, a, b), c), S(t, a, S(t, b, c)))
    np.testing.assert_array_equal(S(t, crisp, np.zeros(2)), crisp)
    np.testing.assert_array_equal(S(t, crisp, np.ones(2)), np.ones(2))
    assert S(t, 0.0, 0.0) <= S(t, 1.0, 0.0) <= S(t, 1.0, 1.0)
    # De Morgan on crisp inputs: its dual is logical and
    np.testing.assert_array_equal(np.asarray(t.tnorm(O, a, b)), np.logical_and(a > 0.5, b > 0.5))


def test_or_on_soft_inputs_binarizes_at_one_half():
    t = tconorm("or")
    a = np.array([0.0, 0.49, 0.5, 0.2, 0.7, 0.3])
    b = np.array([0.0, 0.49, 0.0, 0.3, 0.1, 0.6])
    np.testing.assert_array_equal(S(t, a, b), [0, 0, 1, 0, 1, 1])
    ps = [np.array([0.1, 0.4, 0.0]), np.array([0.45, 0.6, 0.0]), np.array([0.2, 0.1, 0.5])]
    np.testing.assert_array_equal(t.aggregate(O, ps), [0.0, 1.0, 1.0])


# ------------------------------------------------------------------------------------------------
# Generators
# ------------------------------------------------------------------------------------------------

@_params(ARCH)
def test_generator_basics(t):
    assert float(G(t, 0.0)) == 0.0
    inner = GRID[(GRID > 0) & (GRID < 1)]
    g = G(t, inner)
    assert np.all(np.isfinite(g)) and np.all(g > 0)
    assert np.all(np.diff(g) > 0), "generator not strictly increasing"
    g1 = t.generator_at_one
    # the paper's families are strict (g(1) = inf) but Yager, nilpotent with g(1) = 1; a family
    # registered elsewhere (tests/test_extending.py) may be either
    if t.name in {name for name, _ in SETTINGS}:
        assert g1 == (1.0 if t.name == "yager" else math.inf)
    assert g1 > 0
    assert float(G(t, 1.0)) == g1
    # the inverse undoes the generator, including both ends
    np.testing.assert_allclose(Ginv(t, G(t, GRID)), GRID, rtol=0, atol=COMPOSED)
    assert float(Ginv(t, 0.0)) == 0.0
    assert float(Ginv(t, g1)) == 1.0


@_params(ARCH)
def test_odds_factor_means_log1p_of_c_times_the_odds(t):
    """Where a family gives an odds factor c (backends then sum its generator as log Π(1 + c·odds)),
    the generator is log(1 + c·x/(1 − x)); probabilistic (1), einstein (2) and hamacher p > 0 (p)
    give one, hamacher p = 0 (generator x/(1 − x)) does not."""
    assert (tconorm("probabilistic").odds_product_factor(), tconorm("einstein").odds_product_factor(),
            tconorm("hamacher", p=0.5).odds_product_factor(), tconorm("hamacher", p=0.0).odds_product_factor()) \
        == (1.0, 2.0, 0.5, None)
    c = t.odds_product_factor()
    if c is None:
        return
    inner = GRID[(GRID > 0) & (GRID < 1)]
    np.testing.assert_allclose(G(t, inner), np.log1p(c * inner / (1.0 - inner)), rtol=1e-12, atol=0)


@_params(ARCH)
def test_odds_generator_is_the_generator_in_terms_of_the_odds(t):
    """Where a family gives its generator in terms of the log-odds (backends evaluate Dombi's as
    exp(p·log odds) for distributions with closed-form odds), it equals the generator of x,
    relatively to 1e-12 over (0, 1); families without one say so."""
    if t.family.odds_generator is None:
        with pytest.raises(NotImplementedError, match=re.escape(t.label())):
            t.odds_generator(O, np.zeros(2))
        return
    inner = GRID[(GRID > 0) & (GRID < 1)]
    log_odds = np.log(inner) - np.log1p(-inner)
    np.testing.assert_allclose(t.odds_generator(O, log_odds), G(t, inner), rtol=1e-12, atol=0)


def test_dombi_has_a_generator_of_the_odds():
    assert [n for n in TCONORMS if TCONORMS[n].odds_generator is not None] == ["dombi"]


@_params(ARCH)
def test_generator_inverse_huge_arguments(t):
    g1 = t.generator_at_one
    s = np.array([0.0, 1e-300, 1e-12, 0.5, 1.0, 30.0, 800.0, 1e30, 1e300, math.inf])
    s = np.minimum(s, g1)
    x = Ginv(t, s)
    assert not np.any(np.isnan(x))
    assert np.all((x >= 0) & (x <= 1))
    assert np.all(np.diff(x) >= 0)
    assert x[-1] == 1.0


def _mp_generator(t, x):
    """High-precision reference of g(x) (mpmath, 50 digits), from the textbook formulas."""
    mp = pytest.importorskip("mpmath").mp
    with mp.workdps(50):
        x = mp.mpf(x)
        p = mp.mpf(t.kwargs["p"]) if "p" in t.kwargs else None
        n = t.name
        if n == "probabilistic":
            v = -mp.log(1 - x)
        elif n == "einstein":
            v = mp.log((1 + x) / (1 - x))
        elif n == "hamacher":
            v = x / (1 - x) if p == 0 else mp.log((p + (1 - p) * (1 - x)) / (1 - x))
        elif n == "frank":
            v = -mp.log((p ** (1 - x) - 1) / (p - 1))
        elif n == "yager":
            v = x ** p
        elif n == "aczel_alsina":
            v = (-mp.log(1 - x)) ** p
        elif n == "dombi":
            v = (x / (1 - x)) ** p
        elif n == "schweizer_sklar":
            v = (1 - x) ** p - 1
        else:
            raise AssertionError(n)
        return float(v)


@_params(ARCH)
@pytest.mark.parametrize("x", [1e-10, 0.3, 0.5, 0.7, 1 - 1e-12], ids=["1e-10", "0.3", "0.5", "0.7", "1-1e-12"])
def test_generator_high_precision(t, x):
    # log(1 − x) supplied accurately (1 − x is exact for this float x: Sterbenz)
    log1m = math.log(1.0 - x) if x > 0.5 else math.log1p(-x)
    g = float(np.asarray(t.generator(O, np.array(x), np.array(log1m))))
    ref = _mp_generator(t, x)
    assert math.isfinite(g)
    assert g == pytest.approx(ref, rel=1e-12, abs=1e-300)
    # and back
    assert float(Ginv(t, g)) == pytest.approx(x, rel=1e-11, abs=1e-300)


@_params(ARCH)
def test_generator_form_equals_binary_formula(t):
    g1 = t.generator_at_one
    lhs = Ginv(t, np.minimum(g1, G(t, A2) + G(t, B2)))
    np.testing.assert_allclose(lhs, S(t, A2, B2), rtol=0, atol=COMPOSED)


@pytest.mark.parametrize("p", [1e-300, 1e-30, 1e-10, 1e10, 1e30, 1e300])
def test_frank_generator_extreme_parameters(p):
    """frank's generator/inverse switch forms at a p-dependent point: accurate even for extreme p."""
    mp = pytest.importorskip("mpmath").mp
    t = tconorm("frank", p=p)
    for x in [1e-8, 0.01, 0.2, 0.5, 0.8, 0.99, 1 - 1e-9]:
        with mp.workdps(700):
            X, P = mp.mpf(x), mp.mpf(p)
            ref = float(-mp.log((P ** (1 - X) - 1) / (P - 1)))
        if ref == 0.0:  # underflows in float64 (p = 1e-300 and small x)
            continue
        log1m = math.log(1.0 - x) if x > 0.5 else math.log1p(-x)
        g = float(np.asarray(t.generator(O, np.array(x), np.array(log1m))))
        assert g == pytest.approx(ref, rel=1e-12), x
        assert float(Ginv(t, ref)) == pytest.approx(x, rel=1e-12, abs=1e-15), x
    assert float(Ginv(t, 0.0)) == 0.0 and float(Ginv(t, math.inf)) == 1.0


# ------------------------------------------------------------------------------------------------
# The n-ary aggregate
# ------------------------------------------------------------------------------------------------

@_params(SOFT)
def test_aggregate_equals_folded_binary(t):
    rng = np.random.default_rng(1)
    n, m = 7, 200
    ps = [rng.uniform(0, 1, m) ** 3 for _ in range(n)]  # skewed towards 0: the nilpotent yager unsaturated too
    ps[0][:10] = 0.0
    ps[1][10:12] = 1.0
    got = np.asarray(t.aggregate(O, ps))
    left = ps[0]
    for p in ps[1:]:
        left = S(t, left, p)
    np.testing.assert_allclose(got, left, rtol=0, atol=COMPOSED)
    order = list(range(n))
    random.Random(2).shuffle(order)
    assert order != list(range(n))
    shuffled = ps[order[0]]
    for k in order[1:]:
        shuffled = S(t, shuffled, ps[k])
    np.testing.assert_allclose(got, shuffled, rtol=0, atol=COMPOSED)
    # with log(1 − p) supplied
    got2 = np.asarray(t.aggregate(O, ps, [np.log1p(-p) for p in ps]))
    np.testing.assert_allclose(got2, got, rtol=0, atol=EXACT)


def test_aggregate_rejects_empty_and_mismatched():
    t = tconorm("probabilistic")
    with pytest.raises(ValueError):
        t.aggregate(O, [])
    with pytest.raises(ValueError):
        t.aggregate(O, [np.zeros(2), np.zeros(2)], [np.zeros(2)])


@pytest.fixture(scope="module")
def torch_ops():
    torch = pytest.importorskip("torch")
    mod = pytest.importorskip("gendr_torch.ops")
    return torch, mod.torch_ops


@_params(ARCH)
def test_aggregate_gradient_is_generator_ratio(t, torch_ops):
    """∂A/∂p_k = g'(p_k)/g'(A), checked against central finite differences of the aggregate."""
    torch, T = torch_ops
    ps = np.array([0.01, 0.05, 0.03, 0.1])  # small enough that the nilpotent yager does not saturate

    def agg(v):
        return float(np.asarray(t.aggregate(O, [np.array(x) for x in v])))

    A = agg(ps)
    assert 0 < A < 1

    def gprime(x):
        xt = torch.tensor(x, dtype=torch.float64, requires_grad=True)
        t.generator(T, xt).backward()
        return xt.grad.item()

    exact = np.array([gprime(pk) / gprime(A) for pk in ps])
    h = 1e-6
    fd = np.array([(agg(ps + h * e) - agg(ps - h * e)) / (2 * h) for e in np.eye(len(ps))])
    np.testing.assert_allclose(exact, fd, rtol=1e-6, atol=1e-9)  # FD noise ~ 1e-16/h
    # autograd through the aggregate (torch ops) gives the same
    pt = [torch.tensor(x, dtype=torch.float64, requires_grad=True) for x in ps]
    t.aggregate(T, pt).backward()
    np.testing.assert_allclose([x.grad.item() for x in pt], exact, rtol=1e-9)


# ------------------------------------------------------------------------------------------------
# torch autograd and float32 safety at the special values
# ------------------------------------------------------------------------------------------------

X_SPECIAL = [0.0, 1e-30, 1e-8, 0.3, 0.5, 0.9, 1 - 1e-7, 1 - 1e-12, 1 - 1e-30, 1.0]


@_params(ARCH)
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_autograd_finite_at_special_values(t, dtype, torch_ops):
    torch, T = torch_ops
    dt = getattr(torch, dtype)
    x64 = np.array(X_SPECIAL)
    with np.errstate(divide="ignore"):
        l64 = np.where(x64 > 0.5, np.log(np.maximum(1.0 - x64, 0.0)), np.log1p(-x64))
    l64[-2] = math.log(1e-30)  # 1 − (1 − 1e-30) rounds to 0: supply the accurate value
    x = torch.tensor(x64, dtype=dt, requires_grad=True)
    l = torch.tensor(l64, dtype=dt, requires_grad=True)
    g = t.generator(T, x, l)
    assert g.dtype == dt
    assert not torch.isnan(g).any()
    # +inf only at x = 1, or (an overflow) where x rounds to 1 in the working dtype
    below_one = x.detach() < 1.0
    assert (g[below_one] < math.inf).all()
    if dtype == "float64":
        assert (g[:-1] < math.inf).all()
    assert g[-1].item() == t.generator_at_one
    gx, gl = torch.autograd.grad(g.sum(), (x, l), allow_unused=True)
    for gr in (gx, gl):
        assert gr is None or torch.isfinite(gr).all(), (gx, gl)

    # the inverse, from 0 up to g(1) (inf for strict families)
    s = torch.tensor([0.0, 1e-30, 1e-6, 0.5, 1.0, 30.0, 1e20, 1e30, math.inf], dtype=dt)
    s = torch.clamp(s, max=t.generator_at_one).requires_grad_(True)
    x_back = t.generator_inverse(T, s)
    assert x_back.dtype == dt
    assert ((x_back >= 0) & (x_back <= 1)).all()
    x_back.sum().backward()
    assert torch.isfinite(s.grad).all(), s.grad

    # the aggregate of a saturated pixel (one face at p = 1) and of an empty one (all 0)
    ps = [torch.tensor([1.0, 0.0, 0.4], dtype=dt, requires_grad=True),
          torch.tensor([0.3, 0.0, 0.2], dtype=dt, requires_grad=True)]
    ls = [torch.tensor([-math.inf, 0.0, math.log1p(-0.4)], dtype=dt, requires_grad=True),
          torch.log1p(-ps[1].detach()).requires_grad_(True)]
    A = t.aggregate(T, ps, ls)
    assert A[0].item() == 1.0 and A[1].item() == 0.0
    grads = torch.autograd.grad(A.sum(), ps + ls, allow_unused=True)
    for gr in grads:
        assert gr is None or torch.isfinite(gr).all(), grads


@_params(ARCH)
def test_float32_matches_float64(t, torch_ops):
    torch, T = torch_ops
    ps64 = [np.array([0.0, 0.05, 0.3, 0.6]), np.array([0.1, 0.2, 0.0, 0.25]), np.array([0.01, 0.0, 0.4, 0.1])]
    ref = np.asarray(t.aggregate(O, ps64))
    got = t.aggregate(T, [torch.tensor(p, dtype=torch.float32) for p in ps64])
    assert got.dtype == torch.float32
    np.testing.assert_allclose(got.numpy(), ref, rtol=2e-5, atol=1e-6)


def test_accurate_log1m_keeps_float32_faces_near_one_distinct(torch_ops):
    """In float32, x = 1 − 1e-9 rounds to 1, but log(1 − x) supplied by the distribution keeps g finite."""
    torch, T = torch_ops
    for name, kw in [("probabilistic", {}), ("hamacher", {"p": 0.3}), ("frank", {"p": 2.0}),
                     ("schweizer_sklar", {"p": -2.0}), ("aczel_alsina", {"p": 2.0})]:
        t = tconorm(name, **kw)
        x = torch.tensor([1 - 1e-9], dtype=torch.float32)
        assert x.item() == 1.0
        g = t.generator(T, x, torch.tensor([math.log(1e-9)], dtype=torch.float32))
        assert torch.isfinite(g).all()
        assert g.item() == pytest.approx(_mp_generator(t, 1 - 1e-9), rel=1e-5)


# ------------------------------------------------------------------------------------------------
# Construction, errors, repr
# ------------------------------------------------------------------------------------------------

def test_repr_and_label():
    assert repr(tconorm("yager", p=2)) == "TConorm('yager(p=2)')"
    assert repr(tconorm("max")) == "TConorm('max')"
    assert tconorm(tconorm("dombi", p=0.5)).label() == "dombi(p=0.5)"
    assert isinstance(tconorm("or"), TConorm) and tconorm("or").kind == HARD_OR


def test_unknown_name_lists_valid_names():
    with pytest.raises(UnknownNameError) as e:
        tconorm("lukasiewicz_xyz")
    msg = str(e.value)
    assert "lukasiewicz_xyz" in msg
    for name in TCONORMS:
        assert name in msg


@pytest.mark.parametrize("name,kw,value", [
    ("yager", {"p": 0}, "0"),
    ("yager", {"p": -1.5}, "-1.5"),
    ("frank", {"p": 1}, "1"),
    ("frank", {"p": 0.0}, "0.0"),
    ("schweizer_sklar", {"p": 1}, "1"),
    ("schweizer_sklar", {"p": 0.0}, "0.0"),
    ("hamacher", {"p": -1}, "-1"),
    ("aczel_alsina", {"p": 0}, "0"),
    ("dombi", {"p": math.inf}, "inf"),
    ("dombi", {"p": "two"}, "'two'"),
])
def test_out_of_domain_parameter(name, kw, value):
    with pytest.raises(ParameterError) as e:
        tconorm(name, **kw)
    msg = str(e.value)
    assert "p=" + value in msg and name in msg


@pytest.mark.parametrize("name", ["hamacher", "frank", "yager", "aczel_alsina", "dombi", "schweizer_sklar"])
def test_missing_parameter(name):
    with pytest.raises(ParameterError, match="'p'"):
        tconorm(name)


def test_unexpected_parameter():
    with pytest.raises(ParameterError, match="'q'"):
        tconorm("einstein", q=1.0)
    with pytest.raises(ParameterError):
        tconorm(tconorm("max"), p=1.0)


# ------------------------------------------------------------------------------------------------
# average: the mean over the faces, NOT a T-conorm (docs/tconorms.md, "average")
# ------------------------------------------------------------------------------------------------

AVG = tconorm("average")


def test_average_is_flagged_and_streams():
    assert AVG.kind == MEAN and not AVG.is_tconorm and AVG.streams and AVG.differentiable
    assert all(t.is_tconorm for t in ALL if t.name != "average")
    assert repr(AVG) == "TConorm('average')" and AVG.label() == "average"


def test_average_binary_is_the_mean_of_two_and_self_dual():
    np.testing.assert_allclose(S(AVG, A2, B2), (A2 + B2) / 2, rtol=0, atol=EXACT)
    np.testing.assert_allclose(np.asarray(AVG.tnorm(O, A2, B2)), (A2 + B2) / 2, rtol=0, atol=EXACT)


def test_average_fails_the_tconorm_axioms_it_should_fail():
    """Commutative and monotone, but 0 is not neutral, 1 is not absorbing, not associative, and it
    lies between min and max (an averaging function), not above max."""
    a, b = AI, BI
    np.testing.assert_allclose(S(AVG, a, b), S(AVG, b, a), rtol=0, atol=EXACT)
    v = S(AVG, A2, B2).reshape(len(GRID), len(GRID))
    assert np.all(np.diff(v, axis=0) >= 0) and np.all(np.diff(v, axis=1) >= 0)
    assert np.abs(S(AVG, INTERIOR, 0.0 * INTERIOR) - INTERIOR).min() > 0.009   # S(a, 0) = a/2 != a
    assert np.abs(S(AVG, INTERIOR, 0.0 * INTERIOR + 1.0) - 1.0).min() > 0.009  # S(a, 1) != 1
    c = np.full_like(a, 0.9)
    assert np.abs(S(AVG, S(AVG, a, b), c) - S(AVG, a, S(AVG, b, c))).max() > 0.1  # not associative
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    m = S(AVG, a, b)
    assert np.all(m >= lo - EXACT) and np.all(m <= hi + EXACT)
    assert np.any(m < hi - 0.1)                                                   # below max: no "or"
    np.testing.assert_allclose(S(AVG, INTERIOR, INTERIOR), INTERIOR, rtol=0, atol=EXACT)  # idempotent


def test_average_aggregate_divides_by_the_face_count():
    rng = np.random.default_rng(3)
    ps = [rng.uniform(0, 1, 50) for _ in range(5)]
    np.testing.assert_allclose(np.asarray(AVG.aggregate(O, ps)), np.mean(ps, axis=0), rtol=0, atol=EXACT)
    # faces that do not reach the pixel count as 0, but still count in F
    np.testing.assert_allclose(np.asarray(AVG.aggregate(O, ps, n_faces=8)), np.sum(ps, axis=0) / 8, rtol=0, atol=EXACT)
    # the mean of two is binary(); folding binary() is NOT the n-ary mean (not associative)
    fold = ps[0]
    for p in ps[1:]:
        fold = S(AVG, fold, p)
    assert np.abs(fold - np.mean(ps, axis=0)).max() > 1e-2
    # the streaming form the backends use: pair_term = p, from_sum = Σ/F (F = 0 faces: 0, no NaN)
    s = sum(AVG.pair_term(O, p) for p in ps)
    np.testing.assert_allclose(np.asarray(AVG.from_sum(O, s, 5)), np.mean(ps, axis=0), rtol=0, atol=EXACT)
    assert float(AVG.from_sum(O, np.float64(0.0), 0)) == 0.0


def test_average_aggregate_gradient_is_one_over_f(torch_ops):
    import torch
    ps = [torch.tensor([0.0, 0.3, 1.0], dtype=torch.float64, requires_grad=True) for _ in range(3)]
    A = AVG.aggregate(torch_ops, ps, n_faces=6)
    grads = torch.autograd.grad(A.sum(), ps)
    for g in grads:  # also at p = 0 and p = 1: a face with p = 1 does not saturate the mean
        assert torch.equal(g, torch.full((3,), 1.0 / 6.0, dtype=torch.float64))


def test_average_typed_errors():
    with pytest.raises(ParameterError, match="'p'.*no parameters"):
        tconorm("average", p=1.0)
    with pytest.raises(UnknownNameError, match="average"):
        tconorm("averag")
    with pytest.raises(ValueError, match="n_faces"):
        AVG.aggregate(O, [np.zeros(2), np.zeros(2)], n_faces=1)   # fewer faces than terms
    with pytest.raises(ValueError, match="n_faces"):
        AVG.aggregate(O, [np.zeros(2)], n_faces=2.0)
    with pytest.raises(ValueError, match="n_faces"):
        tconorm("probabilistic").aggregate(O, [np.zeros(2)], n_faces=3)  # T-conorms do not depend on F
    with pytest.raises(ValueError, match="no additive generator"):
        AVG.generator(O, np.zeros(2))
    with pytest.raises(ValueError, match="no additive generator"):
        tconorm("max").generator_at_one
    with pytest.raises(ValueError, match="not a sum"):
        tconorm("max").pair_term(O, np.zeros(2))


def test_average_is_not_in_the_paper_grid():
    from gendr import paper_grid
    grid = paper_grid()
    assert len(grid) == 1242 and all(i.tconorm.name != "average" and i.tconorm.is_tconorm for i in grid)


@_params(ALL)
def test_numpy_evaluation_warns_of_nothing(t):
    """A coverage of exactly 1 saturates strict T-conorms: their generators are +inf there by
    design (log(1 − 1) = −inf), which NumPy evaluation returns without RuntimeWarnings."""
    import warnings
    p = np.array([0.0, 1e-300, 0.5, 1.0 - 1e-16, 1.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        t.binary(O, p, p[::-1])
        t.aggregate(O, np.stack([p, p[::-1]]))
        if t.kind == ARCHIMEDEAN:
            t.generator_inverse(O, t.generator(O, p))


def test_frank_near_p_1_against_60_digit_arithmetic():
    """Frank's inverse generator used 1/p − 1, which cancels near p = 1 (relative error ~1e-16/|p − 1|):
    at p = 1 − 1e-9 a render's ∂/∂p was −46.8 instead of −0.018. Against mpmath (60 digits), the
    n-ary S(x) = 1 − log_p(1 + Π(p^(1−xᵢ) − 1)/(p − 1)^(n−1)) and its p-derivative, float64."""
    import mpmath
    torch = pytest.importorskip("torch")
    from gendr_torch.ops import torch_ops
    xs = [0.00237, 0.2409, 9.7e-5, 0.2409]

    def exact(p):
        p = mpmath.mpf(p)
        prod = mpmath.fprod([p ** (1 - mpmath.mpf(x)) - 1 for x in xs]) / (p - 1) ** (len(xs) - 1)
        return 1 - mpmath.log(1 + prod) / mpmath.log(p)
    with mpmath.workdps(60):
        for p0 in (1 - 1e-9, 1 - 1e-6, 1 + 1e-6, 1 + 1e-9):
            p = torch.tensor(p0, dtype=torch.float64, requires_grad=True)
            a = tconorm("frank", p=p).aggregate(torch_ops, [torch.tensor(x, dtype=torch.float64) for x in xs])
            (dp,) = torch.autograd.grad(a, p)
            assert float(a) == pytest.approx(float(exact(p0)), rel=1e-12, abs=0)
            assert float(dp) == pytest.approx(float(mpmath.diff(exact, mpmath.mpf(p0))), rel=1e-5)


@pytest.mark.parametrize("p0", [0.0, 1e-300, 1e-12, 1e-6, 1e-3, 0.5, 4.0])
def test_hamacher_learnable_p_near_zero_against_high_precision_arithmetic(p0):
    """The n-ary Hamacher aggregate is A = r/(1 + r), r = (Π(1 + p·oᵢ) − 1)/p (oᵢ = xᵢ/(1 − xᵢ), the
    odds), r = Σ oᵢ at p = 0, where ∂A/∂p = ((Σoᵢ)² − Σoᵢ²)/2/(1 + r)². A learnable p had ∂A/∂p = 0 at
    p = 0 (the Hamacher sum's generator has no p), a relative error of 1e-3 at p = 1e-12, and 7e283
    at p = 1e-300. Value and
    ∂/∂p against mpmath (800 digits: p² down to 1e-600), float64:
    odds 1e-5 … 2.3: relative 1e-12 (measured ≤ 3e-15). With an odds of 1e12 (x = 1 − 1e-12) the
    backends' form, Σ∂g/∂p·∂A/∂s + ∂g⁻¹/∂p, cancels: terms of size ~0.5 give a derivative of 3e-12,
    so absolute 1e-15 (~10 ulp of those terms; measured ≤ 2e-16). With an x = 1: A = 1, ∂A/∂p = 0."""
    import mpmath
    torch = pytest.importorskip("torch")
    from gendr_torch.ops import torch_ops

    def exact(xs, p):  # (A, ∂A/∂p)
        o = [mpmath.mpf(x) / (1 - mpmath.mpf(x)) for x in xs]
        if p == 0:
            r, dr = mpmath.fsum(o), (mpmath.fsum(o) ** 2 - mpmath.fsum(v * v for v in o)) / 2
        else:
            p = mpmath.mpf(p)
            prod = mpmath.fprod(1 + p * v for v in o)
            r = (prod - 1) / p
            dr = (prod * mpmath.fsum(v / (1 + p * v) for v in o) * p - (prod - 1)) / p ** 2
        return float(r / (1 + r)), float(dr / (1 + r) ** 2)

    moderate = [1e-5, 0.2409, 0.7]
    cases = [(moderate, 1e-12, 0.0), (moderate + [1.0 - 1e-12], 0.0, 1e-15), (moderate + [1.0], None, None)]
    for xs, rtol, atol in cases:
        if rtol is None:
            a_want, dp_want, rtol, atol = 1.0, 0.0, 0.0, 0.0
        else:
            with mpmath.workdps(800):
                a_want, dp_want = exact(xs, p0)
        p = torch.tensor(p0, dtype=torch.float64, requires_grad=True)
        a = tconorm("hamacher", p=p).aggregate(torch_ops, [torch.tensor(x, dtype=torch.float64) for x in xs])
        (dp,) = torch.autograd.grad(a, p)
        assert float(a) == pytest.approx(a_want, rel=1e-12, abs=0), xs
        assert float(dp) == pytest.approx(dp_want, rel=rtol, abs=atol), xs
        # the float setting's value (the unscaled generator) agrees
        with np.errstate(divide="ignore"):
            a_float = tconorm("hamacher", p=p0).aggregate(O, [np.array(x) for x in xs])
        assert float(a_float) == pytest.approx(a_want, rel=1e-12, abs=0), xs


@pytest.mark.parametrize("p0", [0.0, 1e-6, 0.5])
def test_hamacher_learnable_p_float32_finite(p0):
    """float32, learnable p at and near 0, odds from 1e-5 to overflow (x = 1, l = −inf; l = −200,
    beyond float32's exp): value and ∂A/∂p finite, within float32 rounding of float64's."""
    torch = pytest.importorskip("torch")
    from gendr_torch.ops import torch_ops
    xs, ls = [1e-5, 0.3, 0.999, 1.0], [math.log1p(-1e-5), math.log1p(-0.3), math.log1p(-0.999), -200.0]
    out = {}
    for dt in (torch.float32, torch.float64):
        p = torch.tensor(p0, dtype=dt, requires_grad=True)
        t = tconorm("hamacher", p=p)
        parts = [torch.tensor(v, dtype=dt) for v in xs[:3]], [torch.tensor(v, dtype=dt) for v in ls[:3]]
        a = t.aggregate(torch_ops, *parts)
        (dp,) = torch.autograd.grad(a, p)
        g = t.generator(torch_ops, torch.tensor(xs[3], dtype=dt), torch.tensor(ls[3], dtype=dt))
        assert math.isfinite(float(a)) and math.isfinite(float(dp)), (dt, float(a), float(dp))
        assert float(g) > 1e30 if p0 == 0.0 else math.isfinite(float(g)), (p0, float(g))
        out[dt] = float(a), float(dp)
    assert out[torch.float32][0] == pytest.approx(out[torch.float64][0], rel=1e-6)
    assert out[torch.float32][1] == pytest.approx(out[torch.float64][1], rel=1e-4, abs=1e-6)
