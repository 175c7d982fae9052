"""docs/architecture.md's claim: a new distribution or T-conorm is one registry entry and nothing
else changes. Two families that gendr does not have are registered here exactly as that page shows
(an asymmetric triangular distribution with a validated parameter, the Sugeno–Weber T-conorm; set
into the registries as ``Registry.add`` would) and
must then work everywhere a built-in one does: the spec calls, the culling radius, ``gendr list``,
the torch fast path against the naive float64 reference and the Dr.Jit backend against torch
(the tolerances of tests/test_renderer_reference.py and tests/test_drjit_parity.py), forward and
backward, plain, reversed and squared, for both RGB blends."""
from __future__ import annotations

import math

import numpy as np
import pytest

import gendr
from gendr.distributions import BOUNDED, DISTRIBUTIONS, DistributionFamily
from gendr.ops import numpy_ops
from gendr.params import Constraint, Param
from gendr.tconorms import ARCHIMEDEAN, TCONORMS, TConormFamily

OPEN_UNIT = Constraint("in (-1, 1)", lambda v: math.isfinite(v) and -1.0 < v < 1.0)
ABOVE_MINUS_ONE_NOT_ZERO = Constraint("> -1 and != 0", lambda v: math.isfinite(v) and v > -1.0 and v != 0.0)


def _triangular_cdf(ops, x, mode):
    t = ops.clamp(x, -1.0, 1.0)
    return ops.where(t <= mode, (t + 1.0) * (t + 1.0) / (2.0 * (1.0 + mode)),
                     1.0 - (1.0 - t) * (1.0 - t) / (2.0 * (1.0 - mode)))


def _triangular_pdf(ops, x, mode):
    t = ops.clamp(x, -1.0, 1.0)  # 0 outside [-1, 1]: t = ±1 there
    return ops.where(t <= mode, (t + 1.0) / (1.0 + mode), (1.0 - t) / (1.0 - mode))


TRIANGULAR = DistributionFamily(
    "test_triangular", _triangular_cdf, _triangular_pdf,
    support=lambda mode: (-1.0, 1.0), tails=(BOUNDED, BOUNDED),
    params=(Param("mode", OPEN_UNIT, doc="the peak of the density"),),
    doc="Triangular on [−1, 1] with its peak at mode (a test family).",
)

# S(a, b) = min(1, a + b + λab), λ > −1: generator log(1 + λx)/log(1 + λ), nilpotent (g(1) = 1)
SUGENO_WEBER = TConormFamily(
    "test_sugeno_weber", ARCHIMEDEAN,
    binary=lambda ops, a, b, p: ops.clamp(a + b + p * a * b, None, 1.0),
    params=(Param("p", ABOVE_MINUS_ONE_NOT_ZERO, doc="λ"),),
    # (exactly 1 at x = 1: NumPy's SIMD log1p may differ from math.log1p by an ulp, e.g. with AVX-512)
    generator=lambda ops, x, log1m_x, p: ops.where(x >= 1.0, 1.0, ops.log1p(p * x) / math.log1p(p)),
    # exactly 1 at g(1), as the numerical contract of gendr/tconorms.py asks (expm1(log 3)/2 < 1)
    generator_inverse=lambda ops, s, p: ops.where(s >= 1.0, ops.full_like(s, 1.0), ops.expm1(s * math.log1p(p)) / p),
    generator_at_one=lambda p: 1.0,
    doc="Sugeno–Weber (a test family).",
)


@pytest.fixture(scope="module", autouse=True)
def registered():
    with pytest.MonkeyPatch.context() as mp:  # each entry removed again, whatever fails
        mp.setitem(DISTRIBUTIONS, TRIANGULAR.name, TRIANGULAR)
        mp.setitem(TCONORMS, SUGENO_WEBER.name, SUGENO_WEBER)
        yield
    assert TRIANGULAR.name not in DISTRIBUTIONS and SUGENO_WEBER.name not in TCONORMS


def test_the_spec_calls_validate_and_derive_the_culling_radius():
    d = gendr.distribution("test_triangular", mode=0.3)
    with pytest.raises(gendr.ParameterError, match="mode=1.5"):
        gendr.distribution("test_triangular", mode=1.5)
    with pytest.raises(gendr.ParameterError, match="p=-2"):
        gendr.tconorm("test_sugeno_weber", p=-2.0)
    with pytest.raises(ValueError, match="registered twice"):
        DISTRIBUTIONS.add(TRIANGULAR)
    # F(q) = eps on the left branch: (q + 1)^2 / 2.6 = eps, so the radius is τ·(1 − sqrt(2.6·eps))
    eps, tau = 1e-4, 0.05
    assert d.culling_distance(eps, tau) == pytest.approx(tau * (1.0 - math.sqrt(2.6 * eps)), rel=1e-9)
    sq = gendr.distribution("test_triangular", mode=0.3, squared=True)
    assert sq.culling_distance(eps, tau) == pytest.approx(math.sqrt(tau * (1.0 - math.sqrt(2.6 * eps))), rel=1e-9)
    x = np.linspace(-1.5, 1.5, 61)
    rev = gendr.distribution("test_triangular", mode=0.3, reversed=True)
    np.testing.assert_allclose(rev.cdf(numpy_ops, x), 1.0 - d.cdf(numpy_ops, -x), atol=1e-15)


def test_the_t_conorm_aggregates_like_its_binary_fold():
    t = gendr.tconorm("test_sugeno_weber", p=2.0)
    ps = np.random.default_rng(0).uniform(0.0, 0.3, size=(5, 40))
    fold = ps[0]
    for p in ps[1:]:
        fold = np.minimum(1.0, fold + p + 2.0 * fold * p)
    np.testing.assert_allclose(t.aggregate(numpy_ops, ps), fold, rtol=1e-12, atol=1e-15)


def test_gendr_list_shows_them(capsys):
    from gendr.cli import main
    assert main(["list", "distributions"]) == 0
    assert "test_triangular" in capsys.readouterr().out
    assert main(["list", "tconorms"]) == 0
    assert "test_sugeno_weber" in capsys.readouterr().out


CASES = [dict(reversed=False, squared=False, blend=None, eps=0.0),
         dict(reversed=True, squared=False, blend="softmax", eps=1e-3),
         dict(reversed=False, squared=True, blend="hard", eps=1e-3)]


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"rev{int(c['reversed'])}-sq{int(c['squared'])}-{c['blend']}")
def test_torch_fast_path_matches_the_naive_reference(case):
    from test_renderer_reference import assert_close, run_both
    dist = gendr.distribution("test_triangular", mode=0.3, reversed=case["reversed"], squared=case["squared"])
    fast, ref, fg, rg = run_both(dist, gendr.tconorm("test_sugeno_weber", p=2.0), blend=case["blend"],
                                 eps=case["eps"], camera_kind="perspective")
    assert float(fast[..., 3].max()) > 0.5  # the scene is covered, not an empty image compared twice
    assert_close(fast, ref, fg, rg)


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"rev{int(c['reversed'])}-sq{int(c['squared'])}-{c['blend']}")
def test_drjit_matches_torch(case):
    pytest.importorskip("drjit")
    from test_drjit_parity import assert_parity_f64
    dist = gendr.distribution("test_triangular", mode=-0.4, reversed=case["reversed"], squared=case["squared"])
    assert_parity_f64(dist, gendr.tconorm("test_sugeno_weber", p=0.5), blend=case["blend"], eps=case["eps"])


# the generic checks of tests/test_distributions.py and tests/test_tconorms.py (each takes one setting;
# not their comparisons with the paper's table or with scipy, which a new family has no entry in)
DISTRIBUTION_CHECKS = ("test_cdf_in_unit_interval_and_monotone", "test_limits", "test_no_nan_at_extremes",
                       "test_derivative_is_density", "test_log_sf_and_log_cdf_consistent", "test_support_and_tails",
                       "test_quantile_inverts_cdf", "test_squared_coverage")
TCONORM_CHECKS = ("test_range_and_finite", "test_commutative", "test_associative", "test_monotone_in_each_argument",
                  "test_neutral_element_zero", "test_boundary_one", "test_between_max_and_one",
                  "test_generator_basics", "test_generator_form_equals_binary_formula",
                  "test_aggregate_equals_folded_binary")


@pytest.mark.parametrize("check", DISTRIBUTION_CHECKS)
@pytest.mark.parametrize("variant", [{}, {"reversed": True}, {"shift": 0.3}], ids=["plain", "rev", "shift"])
def test_the_generic_distribution_checks_pass(check, variant):
    import test_distributions
    getattr(test_distributions, check)(gendr.distribution("test_triangular", mode=0.3, **variant))


@pytest.mark.parametrize("squared", [False, True])
def test_the_generic_culling_and_identity_checks_pass(squared):
    import test_distributions
    test_distributions.test_reversed_and_shift_identities(gendr.distribution("test_triangular", mode=-0.4))
    test_distributions.test_culling_distance(gendr.distribution("test_triangular", mode=-0.4), squared)


@pytest.mark.parametrize("check", TCONORM_CHECKS)
@pytest.mark.parametrize("p", [-0.5, 2.0])
def test_the_generic_tconorm_checks_pass(check, p):
    import test_tconorms
    getattr(test_tconorms, check)(gendr.tconorm("test_sugeno_weber", p=p))


@pytest.mark.parametrize("p", [-0.5, 2.0])
def test_the_generic_tconorm_gradient_check_passes(p):
    import test_tconorms
    import torch
    from gendr_torch.ops import torch_ops
    test_tconorms.test_aggregate_gradient_is_generator_ratio(gendr.tconorm("test_sugeno_weber", p=p),
                                                             (torch, torch_ops))
