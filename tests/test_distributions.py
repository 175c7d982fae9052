"""Tests of the distribution spec layer (gendr/distributions.py), evaluated with float64 NumpyOps.

References are scipy.stats / scipy.special (or a closed form where scipy has no such family).
Numpy evaluates both branches of every ``where``, so divide/overflow RuntimeWarnings are expected and
silenced; NaNs are checked for explicitly instead.
"""
import math
import re

import mpmath
import numpy as np
import pytest
from scipy import special, stats

import gendr
from gendr.distributions import (DISTRIBUTIONS, BOUNDED, EXPONENTIAL, HEAVY, Distribution,
                                 distribution, _GAMMA_SWITCH)
from gendr.errors import ParameterError, UnknownNameError
from gendr.grid import DISTRIBUTION_SETTINGS
from gendr.ops import numpy_ops as O

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")

# ------------------------------------------------------------------------------------------------
# the one list: every family (gamma at three shapes) x variants
# ------------------------------------------------------------------------------------------------

FAMILIES = [
    ("heaviside", {}), ("uniform", {}), ("cubic_hermite", {}), ("wigner_semicircle", {}),
    ("gaussian", {}), ("laplace", {}), ("logistic", {}), ("hyperbolic_secant", {}), ("cauchy", {}),
    ("reciprocal", {}), ("gumbel_max", {}), ("gumbel_min", {}), ("exponential", {}),
    ("gamma", {"shape": 0.5}), ("gamma", {"shape": 1.0}), ("gamma", {"shape": 4.0}), ("levy", {}),
]
VARIANTS = [{}, {"reversed": True}, {"shift": 0.3}, {"reversed": True, "shift": -0.7}]
CASES = [distribution(name, **params, **v) for name, params in FAMILIES for v in VARIANTS]
PLAIN = [distribution(name, **params) for name, params in FAMILIES]


def ids(d):
    return d.label()


def family_arg(d, x):
    """The argument the family's own formulas see for effective argument x."""
    y = x + d.shift
    return -y if d.reversed else y


def eff_log_cdf(d, x):
    """log F_eff(x) from the family's log_cdf / log_sf (both optional: else from its CDF)."""
    f, kw, y = d.family, d.kwargs, family_arg(d, x)
    log = f.log_sf if d.reversed else f.log_cdf
    if log is not None:
        return log(O, y, **kw)
    with np.errstate(divide="ignore"):
        return np.log1p(-f.cdf(O, y, **kw)) if d.reversed else np.log(f.cdf(O, y, **kw))


def test_every_registered_family_is_tested():
    assert {name for name, _ in FAMILIES} == set(DISTRIBUTIONS)


# dense grid avoiding exact kinks (offset), plus wide points
GRID = np.concatenate([np.linspace(-12.0, 12.0, 4801) + 1.2345e-4,
                       np.geomspace(1e-6, 1e4, 200), -np.geomspace(1e-6, 1e4, 200)])
GRID.sort()


# ------------------------------------------------------------------------------------------------
# generic properties over all cases
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("d", CASES, ids=ids)
def test_cdf_in_unit_interval_and_monotone(d):
    F = d.cdf(O, GRID)
    assert np.all(np.isfinite(F))
    assert np.all((F >= 0.0) & (F <= 1.0))
    # gamma switches from its series to its continued fraction at k + 1.5: the two approximations
    # (each accurate to < 2e-8) may meet with a tiny step there; everything else is exact monotone
    tol = 1e-7 if d.name == "gamma" else 1e-15
    assert np.min(np.diff(F)) >= -tol


@pytest.mark.parametrize("d", CASES, ids=ids)
def test_limits(d):
    big = np.array([1e15, 1e30, 1e300])
    # 1e-6: the heaviest tail (Levy, 1 - F ~ sqrt(2/(pi x))) is 2.5e-8 at 1e15
    np.testing.assert_allclose(d.cdf(O, -big), 0.0, atol=1e-6)
    np.testing.assert_allclose(d.cdf(O, big), 1.0, atol=1e-6)
    lo, hi = d.support()
    if math.isfinite(lo):
        assert np.all(d.cdf(O, np.array([lo - 1e-9, lo - 0.1, lo - 10.0, -1e300])) == 0.0)
    if math.isfinite(hi):
        assert np.all(d.cdf(O, np.array([hi + 1e-9, hi + 0.1, hi + 10.0, 1e300])) == 1.0)


@pytest.mark.parametrize("d", CASES, ids=ids)
def test_no_nan_at_extremes(d):
    x = np.array([-1e300, -1e30, -1e15, -1e3, -80.5, -40.5, -1.0, -1e-300, 0.0, 1e-300, 1.0,
                  40.5, 80.5, 1e3, 1e15, 1e30, 1e300])
    F, f, lsf = d.cdf(O, x), d.pdf(O, x), d.log_sf(O, x)
    lcdf = eff_log_cdf(d, x)
    for v in (F, f, lsf, lcdf):
        assert not np.any(np.isnan(v))
    assert np.all((F >= 0) & (F <= 1)) and np.all(f >= 0)
    assert np.all(lsf <= 0) and np.all(lcdf <= 0)


@pytest.mark.parametrize("d", CASES, ids=ids)
def test_derivative_is_density(d):
    x = GRID[np.abs(GRID) < 30]
    if not d.differentiable:
        assert np.all(d.pdf(O, x) == 0.0)
        return
    h = 1e-6
    y = family_arg(d, x)
    lo, hi = d.family.support(**d.kwargs)
    # F is not smooth at the ends of a bounded support (kinks; the semicircle's f ~ sqrt there makes
    # the difference quotient converge slowly, so keep 1e-3 away) nor at gamma's series/fraction switch
    keep = (np.abs(y - lo) > 1e-3) & (np.abs(y - hi) > 1e-3)
    if d.name == "gamma":
        k = d.kwargs["shape"]
        keep &= np.abs(y - (k + _GAMMA_SWITCH)) > 10 * h
        keep &= (y < -10 * h) | (y > 0.05)  # k < 1: f ~ y^(k-1) is singular at 0+
    x = x[keep]
    fd = (d.cdf(O, x + h) - d.cdf(O, x - h)) / (2 * h)
    # central difference in float64: truncation h^2 F'''/6 <~ 1e-10, rounding eps/h ~ 1e-10;
    # gamma's approximation error (< 2e-8, smooth within a branch) adds well under 1e-8
    np.testing.assert_allclose(fd, d.pdf(O, x), rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("d", CASES, ids=ids)
def test_log_sf_and_log_cdf_consistent(d):
    F = d.cdf(O, GRID)
    lsf, lcdf = d.log_sf(O, GRID), eff_log_cdf(d, GRID)
    # where 1 - F (resp. F) >= 1e-4, log1p(-F) (resp. log F) is accurate to ~1e-12
    m = (1.0 - F) >= 1e-4
    np.testing.assert_allclose(lsf[m], np.log1p(-F[m]), rtol=0, atol=1e-10)
    m = F >= 1e-4
    np.testing.assert_allclose(lcdf[m], np.log(F[m]), rtol=0, atol=1e-10)
    # where F rounds to exactly 0 / 1 (a value below eps/2 = 1.1e-16 at least), log F / log(1 - F)
    # must still be very negative (or -inf), never NaN
    assert np.all(lcdf[F == 0.0] < -36) and np.all(lsf[F == 1.0] < -36)
    # and the log values are monotone themselves (no wiggles where F saturates)
    finite = lambda v: np.maximum(v, -1e300)
    assert np.max(np.diff(finite(lsf))) <= 1e-7 and np.min(np.diff(finite(lcdf))) >= -1e-7


@pytest.mark.parametrize("d", CASES, ids=ids)
def test_odds_are_cdf_over_survival(d):
    """Where a family gives closed-form odds (the probabilistic T-conorm's product form uses them),
    odds = F/(1 − F) = exp(log F − log(1 − F)), relatively to 1e-12 (float64) wherever both logs are
    finite; a family without them says so."""
    if not d.has_odds:
        for fn in (d.odds, d.log_odds):
            with pytest.raises(NotImplementedError, match=re.escape(d.label())):
                fn(O, GRID)
        return
    lsf, lcdf = d.log_sf(O, GRID), eff_log_cdf(d, GRID)
    m = np.isfinite(lsf) & np.isfinite(lcdf) & (np.abs(lcdf - lsf) < 700)
    assert m.sum() > len(GRID) // 2
    np.testing.assert_allclose(d.odds(O, GRID)[m], np.exp(lcdf[m] - lsf[m]), rtol=1e-12, atol=0)
    # and the log-odds (Dombi's generator reads them), absolutely to 1e-12 of their size
    np.testing.assert_allclose(d.log_odds(O, GRID)[m], (lcdf - lsf)[m], rtol=1e-12, atol=1e-12)


def test_sf_is_the_survival_function():
    """A family's ``sf`` (Lévy's erf, what the reversed variant's CDF reads) is 1 − F relatively to
    1e-12 (float64) against exp(log(1 − F)) wherever that is a normal number, and the reversed
    CDF is sf(−x)."""
    families = [f for f in (DISTRIBUTIONS[n] for n in DISTRIBUTIONS) if f.sf is not None]
    assert [f.name for f in families] == ["levy"]
    for f in families:
        d = distribution(f.name)
        lsf = d.log_sf(O, GRID)
        m = lsf > -700
        assert m.sum() > len(GRID) // 2
        np.testing.assert_allclose(f.sf(O, GRID)[m], np.exp(lsf[m]), rtol=1e-12, atol=0)
        np.testing.assert_array_equal(distribution(f.name, reversed=True).cdf(O, GRID), f.sf(O, -GRID))


@pytest.mark.parametrize("d", CASES, ids=ids)
def test_support_and_tails(d):
    lo, hi = d.support()
    left = d.left_tail
    right = d.family.tails[0] if d.reversed else d.family.tails[1]
    assert (left == BOUNDED) == math.isfinite(lo)
    assert (right == BOUNDED) == math.isfinite(hi)
    # decay of the tails: log F(-2X) - log F(-X) (resp. log(1 - F)) at a large X
    for tail, logfn, sign in ((left, lambda x: eff_log_cdf(d, x), -1.0),
                              (right, lambda x: d.log_sf(O, x), 1.0)):
        if tail == HEAVY:  # polynomial: the ratio F(2X)/F(X) stays bounded away from 0
            X = 1e4
            assert logfn(np.array(2 * sign * X)) - logfn(np.array(sign * X)) > math.log(0.01)
        elif tail == EXPONENTIAL:
            X = 40.0
            assert logfn(np.array(2 * sign * X)) - logfn(np.array(sign * X)) < -10.0
    if math.isfinite(lo) and math.isfinite(hi):
        assert d.cdf(O, np.array(lo + 1e-3)) < 1.0 or not d.differentiable


@pytest.mark.parametrize("d", CASES, ids=ids)
def test_quantile_inverts_cdf(d):
    for q in (1e-6, 1e-3, 0.1, 0.5, 0.9, 0.999):
        x = d.quantile(q)
        assert math.isfinite(x)
        F = float(d.cdf(O, np.array(x)))
        # smallest x with F(x) >= q, up to the resolution of the argument x + shift and of F (where
        # f·ulp(x) < ulp(q) the computed F is flat over a few ulps of x)
        delta = 4 * np.spacing(max(abs(x), abs(d.shift), 1e-300)) + 1e-9 * abs(x)
        if not d.differentiable:  # reversed heaviside: F = 1[x > 0], inf not attained; 200 halvings
            delta = max(delta, 1e-12)
        assert F >= q and float(d.cdf(O, np.array(x - delta))) < q, (q, x, F)
        if d.differentiable:
            assert F - q <= 1e-8 * q + float(d.pdf(O, np.array(x))) * delta, (q, x, F)
    assert d.quantile(0.0) == d.support()[0]


@pytest.mark.parametrize("squared", [False, True])
@pytest.mark.parametrize("d", CASES, ids=ids)
def test_culling_distance(d, squared):
    d = distribution(d.name, squared=squared, reversed=d.reversed, shift=d.shift, **d.kwargs)
    for eps in (1e-3, 1e-6):
        for tau in (0.05, 1.0):
            c = d.culling_distance(eps, tau)
            assert 0.0 <= c < math.inf
            beyond = -np.array([c * (1 + 1e-9) + 1e-12, 1.5 * c + 1e-9, 10 * c + 1.0, 1e6 * (c + 1)])
            p, _ = d.coverage(O, beyond, tau)
            assert np.all(p < eps), (eps, tau, c, p)
            if c > 0 and d.differentiable:
                p_at, _ = d.coverage(O, np.array(-c), tau)
                # 1e-4 relative: x = -c/tau (+ shift) is rounded; where the quantile sits just
                # above the start of a bounded support (gamma(0.5) shifted: F ~ sqrt(x - lo))
                # one ulp of the shift is a relative change of ~1e-5 in F
                assert abs(p_at - eps) <= 1e-4 * eps
            elif c == 0:  # coverage already below eps at distance 0+ only inside the face
                p0, _ = d.coverage(O, np.array(1e-12), tau)
                assert p0 >= eps or d.quantile(eps) >= 0


# ------------------------------------------------------------------------------------------------
# variants
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("d", PLAIN, ids=ids)
def test_reversed_and_shift_identities(d):
    x = GRID
    r = distribution(d.name, reversed=True, **d.kwargs)
    np.testing.assert_allclose(r.cdf(O, x), 1.0 - d.cdf(O, -x), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(r.pdf(O, x), d.pdf(O, -x))
    assert r.support() == (-d.support()[1], -d.support()[0])
    assert r.left_tail == d.family.tails[1]
    s = distribution(d.name, shift=0.3, **d.kwargs)
    np.testing.assert_array_equal(s.cdf(O, x), d.cdf(O, x + 0.3))
    np.testing.assert_array_equal(s.pdf(O, x), d.pdf(O, x + 0.3))
    assert s.support() == (d.support()[0] - 0.3, d.support()[1] - 0.3)
    rs = distribution(d.name, reversed=True, shift=0.3, **d.kwargs)
    np.testing.assert_allclose(rs.cdf(O, x), 1.0 - d.cdf(O, -(x + 0.3)), rtol=0, atol=1e-15)


@pytest.mark.parametrize("d", CASES, ids=ids)
def test_squared_coverage(d):
    sq = distribution(d.name, squared=True, reversed=d.reversed, shift=d.shift, **d.kwargs)
    dist = np.linspace(-3.0, 3.0, 601) + 1e-4
    for tau in (0.1, 2.0):
        p, l = sq.coverage(O, dist, tau)
        x = dist * np.abs(dist) / tau
        np.testing.assert_array_equal(p, d.cdf(O, x))
        np.testing.assert_array_equal(l, d.log_sf(O, x))
        p1, l1 = d.coverage(O, dist, tau)
        np.testing.assert_array_equal(p1, d.cdf(O, dist / tau))
        np.testing.assert_array_equal(l1, d.log_sf(O, dist / tau))


# ------------------------------------------------------------------------------------------------
# against references
# ------------------------------------------------------------------------------------------------

def _closed(cdf, pdf):
    return type("Closed", (), {"cdf": staticmethod(cdf), "pdf": staticmethod(pdf),
                               "sf": staticmethod(lambda x: cdf(-x)),  # symmetric ones only
                               "logsf": staticmethod(lambda x: np.log(cdf(-x))),
                               "logcdf": staticmethod(lambda x: np.log(cdf(x)))})


def _hermite_cdf(x):
    x = np.clip(x, -1.0, 1.0)
    return 0.5 + 0.75 * x - 0.25 * x ** 3


REFERENCES = {
    "heaviside": _closed(lambda x: (x >= 0).astype(float), lambda x: np.zeros_like(x)),
    "uniform": stats.uniform(loc=-1.0, scale=2.0),
    "cubic_hermite": _closed(_hermite_cdf, lambda x: np.where(np.abs(x) < 1, 0.75 * (1 - x * x), 0.0)),
    "wigner_semicircle": stats.semicircular(),
    "gaussian": stats.norm(),
    "laplace": stats.laplace(),
    "logistic": stats.logistic(),
    "hyperbolic_secant": stats.hypsecant(scale=2.0 / np.pi),
    "cauchy": stats.cauchy(),
    "reciprocal": _closed(lambda x: 0.5 + x / (2.0 * (1.0 + np.abs(x))),
                          lambda x: 0.5 / (1.0 + np.abs(x)) ** 2),
    "gumbel_max": stats.gumbel_r(),
    "gumbel_min": stats.gumbel_l(),
    "exponential": stats.expon(),
    "levy": stats.levy(),
}
SYMMETRIC = {"uniform", "cubic_hermite", "wigner_semicircle", "gaussian", "laplace", "logistic",
             "hyperbolic_secant", "cauchy", "reciprocal"}


def _reference(d):
    return stats.gamma(d.kwargs["shape"]) if d.name == "gamma" else REFERENCES[d.name]


@pytest.mark.parametrize("d", PLAIN, ids=ids)
def test_against_reference(d):
    ref = _reference(d)
    x = GRID[np.abs(GRID) <= 50]
    atol = 1e-7 if d.name == "gamma" else 1e-14
    np.testing.assert_allclose(d.cdf(O, x), ref.cdf(x), rtol=1e-12, atol=atol)
    lo, hi = d.support()
    smooth = (np.abs(x - lo) > 1e-9) & (np.abs(x - hi) > 1e-9)
    np.testing.assert_allclose(d.pdf(O, x[smooth]), ref.pdf(x[smooth]), rtol=1e-12, atol=1e-14)


# log-space references deep into the tails; reference tail probabilities are taken where scipy
# computes them without cancellation (sf(x) = cdf(-x) for the symmetric families)
TAIL_X = np.concatenate([-np.geomspace(1e-3, 1e3, 301), np.geomspace(1e-3, 1e3, 301)])


@pytest.mark.parametrize("d", [d for d in PLAIN if d.differentiable], ids=ids)
def test_log_tails_against_reference(d):
    ref, x = _reference(d), TAIL_X
    if d.name in SYMMETRIC:
        ref_sf, ref_cdf = ref.cdf(-x), ref.cdf(x)
    elif d.name == "gamma":
        ref_sf, ref_cdf = special.gammaincc(d.kwargs["shape"], x), special.gammainc(d.kwargs["shape"], x)
    else:
        ref_sf, ref_cdf = ref.sf(x), ref.cdf(x)
    # gamma: Q from the continued fraction is accurate to ~1e-6 relative for small shapes right
    # at the switch (absolute < 2e-8); elsewhere the log values agree to ~1e-12 relative
    tol = 3e-6 if d.name == "gamma" else 1e-10
    if d.name == "cauchy":
        tol = 1e-9  # scipy's cauchy cdf = 1/2 + atan(x)/pi cancels in the left tail
    for mine, r in ((d.log_sf(O, x), ref_sf), (d.family.log_cdf(O, x, **d.kwargs), ref_cdf)):
        m = r > 1e-300
        np.testing.assert_allclose(mine[m], np.log(r[m]), rtol=tol, atol=tol)
        assert np.all(mine[r == 0.0] < -690)


@pytest.mark.parametrize("d", [d for d in PLAIN if d.differentiable], ids=ids)
def test_reversed_cdf_tail_is_relatively_accurate(d):
    """F_rev(x) = 1 − F(−x) deep in its left tail (tiny values) keeps relative accuracy: written as
    1 − F(−x) it would round every value below ~1e-16 to a multiple of 2⁻⁵³, which made softmax
    colours of reversed squared instances jump (the weights p·exp(z/γ) compete with a tiny
    background weight far outside the mesh)."""
    ref, x = _reference(d), -np.geomspace(1e-3, 1e12, 451)  # far enough for the heavy tails
    if d.name == "reciprocal":
        ref_sf = 0.5 / (1.0 - x)  # its closed-form reference cdf above cancels for x < 0
    elif d.name in SYMMETRIC:
        ref_sf = ref.cdf(x)  # sf(−x) = cdf(x) for the symmetric families
    elif d.name == "gamma":
        ref_sf = special.gammaincc(d.kwargs["shape"], -x)
    else:
        ref_sf = ref.sf(-x)
    r = distribution(d.name, reversed=True, **d.kwargs).cdf(O, x)
    m = (ref_sf > 1e-300) & (ref_sf < 1e-3)
    assert m.sum() >= 10 or d.support()[1] < 1e3  # bounded families have few tail points
    # same tolerances as the log tails: exp(log Q) adds ≤ |log Q|·1e-16 relative
    rtol = 3e-6 if d.name == "gamma" else (1e-9 if d.name == "cauchy" else 1e-10)
    np.testing.assert_allclose(r[m], ref_sf[m], rtol=rtol, atol=0)


def _lower_tail_cdf(d, x):
    """Reference F(x) of plain or reversed ``d`` where it is tiny (x < 0 for the unbounded ones)."""
    ref = _reference(d)
    if d.name == "reciprocal":
        return 0.5 / (1.0 - x)
    if d.name in ("cubic_hermite", "wigner_semicircle"):  # near an end of [−1, 1] (symmetric)
        e = x + 1.0  # exact (Sterbenz); symmetric, so F_rev = F
        if d.name == "cubic_hermite":
            return (e / 2) ** 2 * (3.0 - e)
        # the closed form cancels here: evaluate it with 50 digits
        F = lambda v: mpmath.mpf(1) / 2 + (v * mpmath.sqrt(1 - v * v) + mpmath.asin(v)) / mpmath.pi
        with mpmath.workdps(50):
            return np.array([float(F(mpmath.mpf(-1) + mpmath.mpf(float(ei)))) for ei in e])
    if d.reversed:
        if d.name == "gamma":
            return special.gammaincc(d.kwargs["shape"], -x)
        return ref.cdf(x) if d.name in SYMMETRIC else ref.sf(-x)
    return special.gammainc(d.kwargs["shape"], x) if d.name == "gamma" else ref.cdf(x)


@pytest.mark.parametrize("d", [distribution(d.name, reversed=r, **d.kwargs) for d in PLAIN if d.differentiable
                               for r in (False, True)], ids=ids)
def test_log_sf_is_relatively_accurate_where_coverage_is_tiny(d):
    """−log(1 − F) ≈ F must keep F's relative accuracy: T-conorm generators raise it to small
    powers (aczel_alsina p = 0.25: (−log(1 − p))^0.25), so rounding it to 0 where F ~ 1e-20 (as
    log(erfc(..)/2) did for the Gaussian) dropped far faces' coverage of ~1e-5 from the aggregate."""
    lo = d.support()[0]
    x = lo + np.geomspace(1e-12, 1e-1, 121) if math.isfinite(lo) else -np.geomspace(1e-3, 1e12, 451)
    F = _lower_tail_cdf(d, x)
    m = (F > 1e-300) & (F < 1e-3)
    assert m.sum() >= 10
    p, l = d.cdf_and_log_sf(O, x[m])
    np.testing.assert_array_equal(l, d.log_sf(O, x[m]))
    np.testing.assert_array_equal(p, d.cdf(O, x[m]))
    rtol = 3e-6 if d.name == "gamma" else 1e-10  # gamma: its series/continued fraction (see above)
    np.testing.assert_allclose(-l, -np.log1p(-F[m]), rtol=rtol, atol=0)


def test_gaussian_and_gumbel_far_tails():
    g, gmax, gmin = distribution("gaussian"), distribution("gumbel_max"), distribution("gumbel_min")
    x = np.array([5.0, 6.5, 10.0, 30.0, 37.0, 100.0, 1e3])
    np.testing.assert_allclose(g.log_sf(O, x), stats.norm.logsf(x), rtol=1e-14)
    np.testing.assert_allclose(g.family.log_cdf(O, -x), stats.norm.logcdf(-x), rtol=1e-14)
    # log(1 - exp(-u)) with u = e^-x; for x = 1e3, u underflows and the value is -x - u/2 = -x
    ref = np.where(x < 700, np.log(-np.expm1(-np.exp(-np.minimum(x, 700)))), -x)
    np.testing.assert_allclose(gmax.log_sf(O, x), ref, rtol=1e-14)
    np.testing.assert_allclose(gmin.family.log_cdf(O, -x), ref, rtol=1e-14)
    np.testing.assert_allclose(gmax.family.log_cdf(O, -x[:4]), -np.exp(x[:4]), rtol=1e-14)
    np.testing.assert_allclose(gmin.log_sf(O, x[:4]), -np.exp(x[:4]), rtol=1e-14)
    np.testing.assert_allclose(distribution("exponential").log_sf(O, x), -x, rtol=1e-15)
    np.testing.assert_allclose(distribution("levy").family.log_cdf(O, 1.0 / x ** 2),
                               np.log(2.0) + stats.norm.logsf(x), rtol=1e-13)


# ------------------------------------------------------------------------------------------------
# gamma: the fixed-iteration incomplete gamma function
# ------------------------------------------------------------------------------------------------

GAMMA_SHAPES = [0.1, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0]


@pytest.mark.parametrize("k", GAMMA_SHAPES)
def test_gamma_accuracy(k):
    x = np.concatenate([np.linspace(0.0, 100.0, 20001), np.geomspace(1e-10, 100.0, 1000),
                        k + _GAMMA_SWITCH + np.linspace(-0.01, 0.01, 201)])
    d = distribution("gamma", shape=k)
    err = np.max(np.abs(d.cdf(O, x) - special.gammainc(k, x)))
    assert err <= 1e-7, err
    # log Q and log P: relative accuracy
    q, p = special.gammaincc(k, x), special.gammainc(k, x)
    m = q > 1e-300
    np.testing.assert_allclose(d.log_sf(O, x[m]), np.log(q[m]), rtol=0, atol=3e-6)
    m = p > 1e-300
    np.testing.assert_allclose(d.family.log_cdf(O, x[m], shape=k), np.log(p[m]), rtol=0, atol=3e-6)


class _DerivativeOps(type(O)):
    """NumpyOps whose with_derivative returns the derivative a backend would attach."""

    @staticmethod
    def with_derivative(value, derivative, x):
        return derivative(x)


@pytest.mark.parametrize("k", [0.1, 0.5, 1.0, 4.0, 20.0])
def test_gamma_attached_derivatives(k):
    D = _DerivativeOps()
    f = DISTRIBUTIONS["gamma"]
    x = np.concatenate([np.linspace(0.02, 60.0, 3000) + 1.234e-4, [-1.0, 0.0]])
    x = x[np.abs(x - (k + _GAMMA_SWITCH)) > 1e-3]  # the two approximations meet there
    h = 1e-6
    for fn, name in ((f.cdf, "cdf"), (f.log_sf, "log_sf"), (f.log_cdf, "log_cdf")):
        attached = fn(D, x, shape=k)
        assert np.all(attached[x <= 0] == 0.0)
        xp = x[x > 0]
        fd = (fn(O, xp + h, shape=k) - fn(O, xp - h, shape=k)) / (2 * h)
        ok = np.isfinite(fd)
        # the attached derivative is exact, the difference quotient sees the approximation, whose
        # error (< 2e-8 in P: slope up to ~5e-8; up to 1e-6 in log Q for small k just past the
        # switch: slope up to ~5e-6) changes with x; well above the finite-difference noise (1e-10)
        np.testing.assert_allclose(attached[x > 0][ok], fd[ok], rtol=1e-5, atol=2e-7, err_msg=name)
    np.testing.assert_array_equal(f.cdf(D, x, shape=k), f.pdf(O, x, shape=k))
    # far tail, where Q underflows: log Q and its slope −x^(k−1)e^(−x)/Γ(k, x) against mpmath (50
    # digits), to 1e-12 relative (the formulas are closed forms there: rounding ~1e-15). Compared with
    # the asymptote −1 + (k − 1)/x to 1e-3 before, which hid integer k's slope of −0.9999 (k = 2) and
    # its log Q = −x (0.3 % off at k = 5) beyond x = 1e4
    big = np.array([200.0, 1.1e4, 1e6, 1e300])
    with mpmath.workdps(50):
        slope = [float(-mpmath.power(v, k - 1) * mpmath.exp(-v) / mpmath.gammainc(k, v)) for v in big]
        log_q = [float(mpmath.log(mpmath.gammainc(k, v, regularized=True))) for v in big]
    np.testing.assert_allclose(f.log_sf(D, big, shape=k), slope, rtol=1e-12)
    np.testing.assert_allclose(f.log_sf(O, big, shape=k), log_q, rtol=1e-12)


def test_gamma_nonpositive_and_special_cases():
    d = distribution("gamma", shape=0.5)
    x = np.array([-1e300, -5.0, -1e-300, 0.0])
    assert np.all(d.cdf(O, x) == 0) and np.all(d.pdf(O, x) == 0) and np.all(d.log_sf(O, x) == 0)
    assert np.all(d.family.log_cdf(O, x, shape=0.5) == -np.inf)
    # shape 1 is the exponential distribution
    x = np.linspace(0.001, 30, 500)
    e = distribution("exponential")
    np.testing.assert_allclose(distribution("gamma", shape=1.0).cdf(O, x), e.cdf(O, x), atol=1e-8)


# ------------------------------------------------------------------------------------------------
# construction and errors
# ------------------------------------------------------------------------------------------------

def test_unknown_name_lists_valid_names():
    with pytest.raises(UnknownNameError) as ei:
        distribution("gausian")
    msg = str(ei.value)
    assert "gausian" in msg
    for name in DISTRIBUTIONS:
        assert name in msg
    assert isinstance(ei.value, ValueError)


@pytest.mark.parametrize("bad", [0, -1, -1.0, float("nan"), float("inf"), "x", 20.5])
def test_gamma_shape_out_of_domain(bad):
    """(20.5: beyond k = 20 the 32-term series is wrong near x = k, 3.6e-3 at k = 100)"""
    with pytest.raises(ParameterError) as ei:
        distribution("gamma", shape=bad)
    assert "shape" in str(ei.value) and repr(bad) in str(ei.value)


def test_gamma_missing_shape_and_unexpected_params():
    with pytest.raises(ParameterError, match="shape"):
        distribution("gamma")
    with pytest.raises(ParameterError, match="shape"):
        distribution("gaussian", shape=1.0)


def test_repr_and_label():
    d = distribution("gamma", shape=0.5, reversed=True)
    assert repr(d) == "Distribution('gamma(shape=0.5)+rev')"
    assert repr(distribution("logistic", squared=True)) == "Distribution('logistic+sq')"
    assert isinstance(gendr.distribution("cauchy"), Distribution)
    assert hash(d) == hash(distribution("gamma", shape=0.5, reversed=True))


def test_labels_tell_close_values_apart():
    """Labels name rows and sweep selections: {:g} made yager(p=2.0000001) 'yager(p=2)'."""
    assert gendr.tconorm("yager", p=2.0000001).label() == "yager(p=2.0000001)"
    assert gendr.tconorm("yager", p=2.0).label() == "yager(p=2)"
    assert distribution("gamma", shape=0.5000001).label() == "gamma(shape=0.5000001)"
    assert distribution("logistic", shift=0.1 + 0.2).label() == "logistic+shift=0.30000000000000004"
    assert distribution("logistic", shift=1e-5).label() == "logistic+shift=1e-05"


def test_any_shape_accepted():
    for k in (1e-3, 0.1, 3.7, 20.0):
        d = distribution("gamma", shape=k)
        x = np.linspace(0, 3 * k + 50, 50)
        assert np.all(np.isfinite(d.cdf(O, x)))


@pytest.mark.parametrize("squared", [False, True])
def test_argument_derivative_is_the_derivative_of_argument(squared):
    """∂x/∂d in closed form (used by the torch backend's compiled backward) equals autograd's."""
    torch = pytest.importorskip("torch")
    from gendr_torch.ops import torch_ops
    dist = gendr.distribution("logistic", squared=squared)
    d = torch.linspace(-0.3, 0.3, 41, dtype=torch.float64).requires_grad_(True)
    tau = torch.tensor(0.02, dtype=torch.float64)
    g, = torch.autograd.grad(dist.argument(torch_ops, d, tau).sum(), d)
    torch.testing.assert_close(dist.argument_derivative(torch_ops, d.detach(), tau), g, rtol=1e-15, atol=0.0)


@pytest.mark.parametrize("d", [distribution(n, squared=sq, **p, **v) for n, p in FAMILIES for v in VARIANTS[:2]
                               for sq in (False, True)], ids=ids)
def test_numpy_evaluation_warns_of_nothing(d):
    """The NumPy spec calls are public (a user evaluates F, f, log(1 − F) with ``numpy_ops``): at
    legitimate arguments, the extremes included, they return ±inf and 0 where meant without
    RuntimeWarnings (before: overflow in reciprocal's, Lévy's and the Gaussian's formulas at
    |x| ≥ 1e154, division by zero in log(1 − F) where F = 1)."""
    import warnings
    x = np.array([-1e300, -1e200, -1e30, -40.5, -1.0, -1e-300, 0.0, 1e-300, 1.0, 40.5, 1e30, 1e200, 1e300])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d.cdf(O, x), d.pdf(O, x), d.log_sf(O, x), d.cdf_and_log_sf(O, x), d.coverage(O, x, 0.5)
        if d.has_odds:
            d.odds(O, x), d.log_odds(O, x)


@pytest.mark.parametrize("d", CASES, ids=ids)
def test_limits_at_infinity(d):
    """F(−inf) = 0, F(+inf) = 1 and log(1 − F(−inf)) = 0 exactly (an overflowed d/τ is ±inf):
    gamma's upper regime read x = +inf as k·log x − x = inf − inf, F = NaN."""
    F, log_sf = d.cdf_and_log_sf(O, np.array([-np.inf, np.inf]))
    assert F[0] == 0.0 and F[1] == 1.0 and log_sf[0] == 0.0 and log_sf[1] < -40.0, (F, log_sf)
    np.testing.assert_array_equal(d.cdf(O, np.array([-np.inf, np.inf])), [0.0, 1.0])


GRID_DISTRIBUTIONS = [distribution(n, reversed=rev, squared=sq, **p)
                      for n, p, rev in DISTRIBUTION_SETTINGS for sq in (False, True)]


@pytest.mark.parametrize("d", GRID_DISTRIBUTIONS, ids=ids)
def test_torch_gradients_of_finite_values_at_infinity_are_finite(d):
    """Where F or log(1 − F) of a grid distribution is finite at x = ±inf, its torch gradient is
    too (0: the value is a limit there). Before, Lévy's F at +inf and the reversed Lévy's
    log(1 − F) at −inf had NaN gradients (√ of 1/x at 0: inf·0). A −inf log(1 − F) (e.g. Gaussian
    at +inf) is left out: its slope has no finite limit. So are the reversed symmetric families
    outside the grid (Gaussian, Cauchy reversed), whose F at −inf is exp(−inf) of such a log.
    (The renderer never evaluates ±inf: τ must be a normal float, culling skips far pairs.)"""
    torch = pytest.importorskip("torch")
    from gendr_torch.ops import torch_ops
    for dtype in (torch.float32, torch.float64):
        for end in (-np.inf, np.inf):  # one lane each: a masked lane's 0·NaN would blame the other
            x = torch.tensor([end], dtype=dtype, requires_grad=True)
            F, log_sf = d.cdf_and_log_sf(torch_ops, x)
            for name, value in (("F", F), ("log_sf", log_sf), ("cdf", d.cdf(torch_ops, x))):
                if torch.isfinite(value).all():
                    (g,) = torch.autograd.grad(value.sum(), x, retain_graph=True)
                    assert torch.isfinite(g).all(), (name, end, dtype, g)


@pytest.mark.parametrize("k", [0.5, 2.0, 3.0, 1.7])
@pytest.mark.parametrize("rev", [False, True])
def test_gamma_gradients_at_infinity_are_finite(k, rev):
    torch = pytest.importorskip("torch")
    from gendr_torch.ops import torch_ops
    d = distribution("gamma", shape=k, reversed=rev)
    for dtype in (torch.float32, torch.float64):
        x = torch.tensor([-np.inf, -3e38, 3e38, np.inf], dtype=dtype, requires_grad=True)
        F, log_sf = d.cdf_and_log_sf(torch_ops, x)
        assert torch.equal(F.detach(), torch.tensor([0.0, 0.0, 1.0, 1.0], dtype=dtype))
        (dF,) = torch.autograd.grad(F.sum(), x, retain_graph=True)
        assert torch.all(dF == 0.0), dF
        # d log(1 − F)/dx tends to −1 (plain: log Q ~ −x) or 0 (reversed): finite, not NaN
        (dl,) = torch.autograd.grad(torch.where(torch.isfinite(log_sf), log_sf, 0.0).sum(), x)
        assert torch.isfinite(dl).all(), dl


@pytest.mark.parametrize("backend", ["torch", "drjit"])
def test_slopes_at_an_overflowed_argument_are_zero(backend):
    """x = ±inf (d/τ overflowed) is a limit: F and log(1 − F) have slope 0 there. The reversed
    Gaussian's and Cauchy's F = exp(log_sf(−x)) gave torch exp(−inf)·(−inf) = NaN at −inf (every
    vertex gradient of a float32 render at τ = 1.2e-38 NaN); Cauchy's log(1 − F) took log(1/x) = log 0
    at +inf (NaN slope in both backends)."""
    torch = pytest.importorskip("torch")
    cases = [("gaussian", True, -math.inf), ("cauchy", True, -math.inf), ("cauchy", False, math.inf),
             ("logistic", True, -math.inf)]
    for name, rev, x in cases:
        d = gendr.distribution(name, reversed=rev)
        for which in (0, 1):  # F, log(1 − F)
            if backend == "torch":
                from gendr_torch.ops import torch_ops
                xt = torch.tensor([x], dtype=torch.float64, requires_grad=True)
                (g,) = torch.autograd.grad(d.cdf_and_log_sf(torch_ops, xt)[which].sum(), xt)
                g = float(g[0])
            else:
                dr = pytest.importorskip("drjit")
                from drjit.llvm.ad import Float64
                from gendr_drjit.ops import DrJitOps
                xd = Float64([x])
                dr.enable_grad(xd)
                dr.backward(d.cdf_and_log_sf(DrJitOps(Float64), xd)[which], flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
                g = float(dr.grad(xd)[0])
            assert g == 0.0, (d.label(), which, g)


def test_cauchy_log_sf_in_float32_up_to_its_largest_x():
    """Dr.Jit flushes the subnormal 1/x (x > 8.5e37) to 0: log(1 − F) was −inf at 1e38 (true −88.643)."""
    dr = pytest.importorskip("drjit")
    from drjit.llvm.ad import Float
    from gendr_drjit.ops import DrJitOps
    xs = [1e37, 5e37, 1e38, 3e38]
    got = np.array(gendr.distribution("cauchy").cdf_and_log_sf(DrJitOps(Float), Float(xs * 8))[1])[:4]
    want = [-math.log(math.pi * x) for x in xs]  # log(atan(1/x)/π), to float32 rounding
    np.testing.assert_allclose(got, want, rtol=1e-6)
    del dr


TAIL_X = np.concatenate([-np.geomspace(1e-3, 1e3, 61), np.geomspace(1e-3, 1e3, 61)])


def _backend_F_log_sf_and_slope(backend, d, x):
    """F, log(1 − F) and autograd dF/dx of d at float64 x in one backend (numpy arrays)."""
    if backend == "torch":
        torch = pytest.importorskip("torch")
        from gendr_torch.ops import torch_ops
        xt = torch.tensor(x, dtype=torch.float64, requires_grad=True)
        F, log_sf = d.cdf_and_log_sf(torch_ops, xt)
        (dF,) = torch.autograd.grad(F.sum(), xt)
        return F.detach().numpy(), log_sf.detach().numpy(), dF.numpy()
    dr = pytest.importorskip("drjit")
    from drjit.llvm.ad import Float64
    from gendr_drjit.ops import DrJitOps
    xd = Float64(x)
    dr.enable_grad(xd)
    F, log_sf = d.cdf_and_log_sf(DrJitOps(Float64), xd)
    dr.backward(F, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
    return F.numpy(), log_sf.numpy(), dr.grad(xd).numpy()


@pytest.mark.parametrize("backend", ["torch", "drjit"])
@pytest.mark.parametrize("d", [d for d in CASES if d.differentiable], ids=ids)
def test_backend_slopes_are_the_density_in_the_tails(backend, d):
    """Each backend's autograd dF/dx is the spec's density f to 1e-12 relative, |x| from 1e-3 to 1e3,
    wherever f is a normal float64 (support ends left out: F has kinks there); F and log(1 − F) match
    the NumPy spec to 1e-12. f is a separate formula, so this checks the autograd path, including far
    tails where a derivative taken through 1 − F cancels. 1e-12: Gaussian-type tails differ by
    ~1e-13 (e^(−x²/2) turns x's rounding into x²·ε); everything else agrees to a few ulp. Before,
    torch.sigmoid's backward s·(1 − s) was 2e-3 off at x = 31.6 and 0 from 37; torch's softplus,
    so the logistic's log(1 − F), was 2e-9 off beyond 20; the spec's logistic f had the same cancellation."""
    lo, hi = d.support()
    x = TAIL_X[(np.abs(TAIL_X - lo) > 1e-9) & (np.abs(TAIL_X - hi) > 1e-9)]
    F, log_sf, dF = _backend_F_log_sf_and_slope(backend, d, x)
    f = d.pdf(O, x)
    normal = f > np.finfo(np.float64).tiny
    np.testing.assert_allclose(dF[normal], f[normal], rtol=1e-12, atol=0)
    assert np.all(np.abs(dF[f == 0]) <= np.finfo(np.float64).tiny), d.label()
    ref_F, ref_log_sf = d.cdf(O, x), d.log_sf(O, x)
    np.testing.assert_allclose(F, ref_F, rtol=1e-12, atol=1e-300)
    fin = np.isfinite(ref_log_sf)
    np.testing.assert_allclose(log_sf[fin], ref_log_sf[fin], rtol=1e-12, atol=1e-300)
    assert np.array_equal(np.isfinite(log_sf), fin), d.label()


@pytest.mark.parametrize("d", [d for d in CASES if d.name == "logistic"], ids=ids)
def test_torch_forward_mode_slope_of_the_logistic_tail(d):
    """compile=True's gradient chain takes ∂g/∂x by torch.func.jvp, where torch.sigmoid's forward-mode
    slope is s·(1 − s) again (1e-3 off at x = 31.6, 0 from 38): the ops' sigmoid gives σ(x)·σ(−x) there too."""
    torch = pytest.importorskip("torch")
    from gendr_torch.ops import torch_ops
    x = torch.tensor(TAIL_X, dtype=torch.float64)
    _, dF = torch.func.jvp(lambda v: d.cdf(torch_ops, v), (x,), (torch.ones_like(x),))
    f = d.pdf(O, TAIL_X)
    normal = f > np.finfo(np.float64).tiny
    np.testing.assert_allclose(dF.numpy()[normal], f[normal], rtol=1e-12, atol=0)
