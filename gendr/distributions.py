"""Distributions whose CDF turns a signed pixel-to-edge distance into soft coverage.

Each family is ONE entry in :data:`DISTRIBUTIONS` (formulas written once against an ops namespace,
see :mod:`gendr.ops`). :func:`distribution` builds a :class:`Distribution` spec: a family with
validated parameters and the ``reversed`` / ``shift`` / ``squared`` variants (DESIGN.md §3):

* plain:    p = F(d / τ)
* squared:  p = F(d·|d| / τ)
* reversed: F_rev(x) = 1 − F(−x), evaluated as exp(log(1 − F(−x))) so that its tail keeps its
  relative accuracy (1 − F(−x) rounds every value below ~1e-16 to a multiple of 2⁻⁵³)
* shifted:  F(x + shift)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Callable

from .ops import NumpyOps, numpy_ops, quiet_numpy
from .params import (Learnable, LearnableParams, Param, Registry, array_value, is_backend_array, plain_number,
                     short_number, validate_params, Constraint)
from .errors import ParameterError

#: how fast F → 0 (left) or → 1 (right) at an end of the support
BOUNDED, EXPONENTIAL, HEAVY = "bounded", "exponential", "heavy"


@dataclass(frozen=True)
class DistributionFamily:
    """One distribution, as in the paper's supplement.

    ``cdf(ops, x, **params)`` and ``pdf(ops, x, **params)`` are elementwise. ``support(**params)``
    returns ``(lo, hi)`` (±inf where unbounded), ``tails`` says how the left and right tails decay.
    ``log_sf(ops, x, **params)`` = log(1 − F(x)) and ``log_cdf`` = log F(x) are optional, for
    accuracy where 1 − F underflows (T-conorm generators use log(1 − p)).
    """

    name: str
    cdf: Callable
    pdf: Callable
    support: Callable[..., tuple[float, float]]
    tails: tuple[str, str]
    params: tuple[Param, ...] = ()
    log_sf: Callable | None = None
    log_cdf: Callable | None = None
    #: optional ``sf(ops, x, **params)`` = 1 − F(x), relatively accurate where it is small: the
    #: reversed variant's CDF F(−x) without exp(log_sf) (Lévy: erf where F is erfc)
    sf: Callable | None = None
    #: optional ``cdf_and_logs(ops, x, **params)`` = ``(F, log(1 − F), log F)`` from shared work (one
    #: evaluation where the three functions would each repeat it); requires ``accurate_logs``
    cdf_and_logs: Callable | None = None
    #: log_sf and log_cdf keep their relative accuracy on the whole line, also where F (or 1 − F) is
    #: tiny, so the renderer's log(1 − F) needs no log1p(−F) branch (tested against scipy/mpmath)
    accurate_logs: bool = False
    #: optional ``odds(ops, x, **params)`` = F/(1 − F), given where it is cheaper than log(1 − F)
    #: (logistic: e^x; Cauchy, reciprocal: one division): a sum of generators log(1 + c·odds)
    #: (probabilistic, Einstein, Hamacher; TConormFamily.odds_factor) is then log Π(1 + c·odds), one
    #: log per pixel, not one per face (+inf where 1 − F underflows)
    odds: Callable | None = None
    #: optional ``log_odds(ops, x, **params)`` = log(F/(1 − F)) where cheaper than log(odds) (the
    #: logistic's: x); families with ``odds`` and without it take log(odds)
    log_odds: Callable | None = None
    differentiable: bool = True
    doc: str = ""

    def __post_init__(self):
        if self.cdf_and_logs is not None and not self.accurate_logs:
            raise ValueError(f"distribution family {self.name!r}: cdf_and_logs requires accurate_logs")


DISTRIBUTIONS = Registry("distribution")


@dataclass(frozen=True)
class Distribution(LearnableParams):
    """A validated distribution setting. Frozen and hashable; build it with :func:`distribution`.

    Its methods (``cdf``, ``pdf``, ``coverage``, ...) take an ``ops`` namespace (``gendr.ops.numpy_ops``
    or a backend's) and arrays of that namespace (NumPy, torch on any device, Dr.Jit), of any shape,
    and return arrays of the same shape, dtype and device: elementwise and differentiable where the
    family is (``.differentiable``). The
    argument ``x`` is d/τ (or d·|d|/τ when ``squared``): signed screen-unit distance over τ.

    >>> import numpy as np, gendr
    >>> from gendr.ops import numpy_ops
    >>> d = gendr.distribution("logistic")
    >>> d, d.support(), d.differentiable
    (Distribution('logistic'), (-inf, inf), True)
    >>> d.cdf(numpy_ops, np.array([0.0, 2.0])).round(4)
    array([0.5   , 0.8808])
    >>> round(d.culling_distance(eps=1e-4, tau=0.01), 4)  # screen units beyond which p < eps
    0.0921
    """

    family: DistributionFamily
    params: tuple[tuple[str, float], ...] = ()
    reversed: bool = False
    shift: float = 0.0
    squared: bool = False
    _owner_kind = "distribution"

    @property
    def name(self) -> str:
        return self.family.name

    @property
    def differentiable(self) -> bool:
        return self.family.differentiable

    @property
    def kwargs(self) -> dict[str, float]:
        return dict(self.params)

    def label(self) -> str:
        """Short unique text, e.g. ``gamma(shape=0.5)+rev+sq``."""
        s = self.name
        if self.params:
            s += "(" + ",".join(f"{k}={short_number(v)}" for k, v in self.params) + ")"
        if self.shift:
            s += f"+shift={short_number(self.shift)}"
        if self.reversed:
            s += "+rev"
        if self.squared:
            s += "+sq"
        return s

    def __repr__(self) -> str:
        return f"Distribution({self.label()!r})"

    # --- the effective one-dimensional CDF (reversed and shift applied, not squared) ---
    @quiet_numpy
    def cdf(self, ops, x):
        f, kw = self.family, self.kwargs
        x = x + self.shift if self.shift else x
        if self.reversed:
            if f.sf is not None:
                return f.sf(ops, -x, **kw)
            if f.log_sf is not None:
                if ops.needs_grad(x):  # x = −inf (an overflowed d/τ): F = 0 with slope 0, not exp(−inf)·(−inf)
                    up = x > -math.inf
                    return ops.where(up, ops.exp(f.log_sf(ops, -ops.where(up, x, 0.0), **kw)), 0.0)
                return ops.exp(f.log_sf(ops, -x, **kw))
            return 1.0 - f.cdf(ops, -x, **kw)
        return f.cdf(ops, x, **kw)

    @quiet_numpy
    def pdf(self, ops, x):
        f, kw = self.family, self.kwargs
        x = x + self.shift if self.shift else x
        return f.pdf(ops, -x if self.reversed else x, **kw)

    @quiet_numpy
    def log_sf(self, ops, x):
        """log(1 − F(x)) of the effective CDF, relatively accurate everywhere (see cdf_and_log_sf)."""
        return self._log_sf(ops, x, self.cdf(ops, x))

    @quiet_numpy
    def cdf_and_log_sf(self, ops, x):
        """``(F(x), log(1 − F(x)))``, F evaluated once.

        Where F < 1/2 the log is log1p(−F) (unless the family's logs are ``accurate_logs``): the
        families' log-survival formulas are written for the upper half and may round log(1 − F) to 0
        for tiny F (Gaussian, Cauchy), which T-conorm generators with small exponents, e.g.
        (−log(1 − p))^0.25, turn into large absolute errors. A backend that uses only the log (e.g.
        for the probabilistic generator −log(1 − p)) then never evaluates F of an accurate family.
        """
        f = self.family
        if f.cdf_and_logs is not None:
            xs = x + self.shift if self.shift else x
            if self.reversed:  # F_rev(x) = 1 − F(−x): (exp log(1 − F(−x)), log F(−x))
                _, log_sf, log_cdf = f.cdf_and_logs(ops, -xs, **self.kwargs)
                return ops.exp(log_sf), log_cdf
            F, log_sf, _ = f.cdf_and_logs(ops, xs, **self.kwargs)
            return F, log_sf
        F = self.cdf(ops, x)
        return F, self._log_sf(ops, x, F)

    def _log_sf(self, ops, x, F):
        f, kw = self.family, self.kwargs
        x = x + self.shift if self.shift else x

        def upper(_, x):
            if self.reversed:  # 1 − F_rev(x) = F(−x)
                return f.log_cdf(ops, -x, **kw) if f.log_cdf is not None else ops.log(f.cdf(ops, -x, **kw))
            if f.log_sf is not None:
                return f.log_sf(ops, x, **kw)
            return ops.log1p(-f.cdf(ops, x, **kw))
        # where F < 1/2, log1p(−F) from the F already computed; a branch, so that packets of such
        # lanes skip the family's formula. Families with accurate logs use theirs everywhere, except
        # reversed ones whose F is their own accurate 1 − F (``sf``: reversed Lévy's far field then
        # needs one erf per pair, not two)
        if f.accurate_logs and not (self.reversed and f.sf is not None):
            return upper(F, x)
        lower = F < 0.5
        return ops.branch(lower, lambda F_, x_: ops.log1p(-F_), upper, ops.where(lower, F, 0.0), x)

    @property
    def has_odds(self) -> bool:
        """Whether the family gives :meth:`odds` in closed form."""
        return self.family.odds is not None

    @quiet_numpy
    def odds(self, ops, x):
        """F(x)/(1 − F(x)) of the effective CDF (families with ``has_odds`` only)."""
        f, kw = self.family, self.kwargs
        if f.odds is None:
            raise NotImplementedError(f"distribution {self.label()!r} has no closed-form odds")
        x = x + self.shift if self.shift else x
        return 1.0 / f.odds(ops, -x, **kw) if self.reversed else f.odds(ops, x, **kw)

    @quiet_numpy
    def log_odds(self, ops, x):
        """log(F(x)/(1 − F(x))) of the effective CDF (families with ``has_odds`` only)."""
        f, kw = self.family, self.kwargs
        if f.odds is None:
            raise NotImplementedError(f"distribution {self.label()!r} has no closed-form odds")
        x = x + self.shift if self.shift else x
        fn = f.log_odds if f.log_odds is not None else (lambda ops, x, **kw: ops.log(f.odds(ops, x, **kw)))
        return -fn(ops, -x, **kw) if self.reversed else fn(ops, x, **kw)

    def support(self) -> tuple[float, float]:
        lo, hi = self.family.support(**self.kwargs)
        if self.reversed:
            lo, hi = -hi, -lo
        return lo - self.shift, hi - self.shift

    @property
    def left_tail(self) -> str:
        """Decay of F towards 0 (outside the face): what decides the culling radius."""
        return self.family.tails[1] if self.reversed else self.family.tails[0]

    # --- what the renderer uses ---
    def argument(self, ops, d, tau):
        """x = d/τ, or d·|d|/τ for the squared variant (d: signed distance, + inside)."""
        return d * ops.abs(d) / tau if self.squared else d / tau

    def argument_derivative(self, ops, d, tau):
        """∂x/∂d of :meth:`argument`: 1/τ, or 2|d|/τ for the squared variant (∂x/∂τ is −x/τ)."""
        return 2.0 * ops.abs(d) / tau if self.squared else ops.full_like(d, 1.0) / tau

    @quiet_numpy
    def coverage(self, ops, d, tau):
        """Soft coverage ``(p, log(1 − p))`` of signed distances ``d`` at scale ``tau``."""
        return self.cdf_and_log_sf(ops, self.argument(ops, d, tau))

    def quantile(self, q: float) -> float:
        """Smallest x with F(x) >= q (float64 bisection on the CDF; ``-inf`` if F(x) >= q for all x).

        Cached: renderers ask for the same levels (eps) at every render."""
        if not 0.0 <= q <= 1.0:
            raise ParameterError(f"quantile level q={q!r} must lie in [0, 1]")
        plain = self if not self.learnable else replace(self, params=tuple((k, float(v)) for k, v in self.params))
        return _cached_quantile(plain, float(q))  # (keyed on floats: the cache holds no tensor)

    def _quantile(self, q: float) -> float:
        lo, hi = self.support()
        if q <= 0.0:
            return lo
        F = lambda v: float(self.cdf(numpy_ops, numpy_ops.asarray(v)))
        # bracket [a, b] with F(a) < q <= F(b)
        b = 1.0 if not math.isfinite(hi) else hi
        while F(b) < q:
            b = b * 2.0 if b > 0 else 1.0
            if b > 1e300:
                return math.inf
        a = b - 1.0 if not math.isfinite(lo) else lo
        step = 1.0
        while F(a) >= q:
            if math.isfinite(lo) and a <= lo:
                return lo
            step *= 2.0
            a = b - step
            if step > 1e300:
                return -math.inf
        for _ in range(200):
            m = 0.5 * (a + b)
            if m in (a, b):
                break
            if F(m) >= q:
                b = m
            else:
                a = m
        return b

    def argument_threshold(self, eps: float) -> float:
        """F⁻¹(eps): the argument x below which the coverage F(x) is < ``eps`` (−inf for eps = 0).

        Renderers drop the pairs with x < F⁻¹(eps) (coverage < eps) by this test on x, so that the
        coverage itself need not be evaluated where only its log enters the generator."""
        return self.quantile(eps) if eps > 0 else -math.inf

    def culling_distance(self, eps: float, tau: float) -> float:
        """Distance outside a face beyond which its coverage is < ``eps`` (``inf``: none).

        Coverage p >= eps  <=>  x >= F⁻¹(eps). With x = d/τ that is d >= τ·F⁻¹(eps); for the squared
        variant d >= −sqrt(τ·|F⁻¹(eps)|). The result is >= 0 (a face's own pixels are never culled
        by this bound; pixels inside it with p < eps are dropped by the renderer's eps mask).
        """
        x = self.quantile(eps) if eps > 0 else self.support()[0]
        if x >= 0:
            return 0.0
        if not math.isfinite(x):
            return math.inf
        return math.sqrt(tau * -x) if self.squared else tau * -x


@lru_cache(maxsize=4096)
def _cached_quantile(dist: Distribution, q: float) -> float:
    return dist._quantile(q)


def distribution(name, *, reversed: bool = False, shift: float = 0.0, squared: bool = False, **params) -> Distribution:
    """Build a distribution spec: ``gendr.distribution("gamma", shape=0.5, reversed=True)``.

    ``name`` may also be a :class:`Distribution` (returned unchanged when no options are given).
    Raises :class:`~gendr.errors.UnknownNameError` listing valid names, and
    :class:`~gendr.errors.ParameterError` for out-of-domain parameters.

    Args:
        name: a family of :data:`DISTRIBUTIONS` (``sorted(gendr.DISTRIBUTIONS)``).
        reversed: mirror the CDF, F_rev(x) = 1 − F(−x) (one-sided families covering outside).
        shift: finite float added to the argument, F(x + shift).
        squared: use the argument d·|d|/τ instead of d/τ (τ then in squared screen units).
        **params: the family's parameters as Python floats (e.g. ``shape`` of ``gamma``), or as
            0-d torch tensors / Dr.Jit arrays that require grad: *learnable* (``.learnable``),
            both backends return ∂/∂shape, and the value is re-checked at every render.

    Returns a frozen, hashable :class:`Distribution`.

    >>> import gendr
    >>> gendr.distribution("gamma", shape=0.5, reversed=True, squared=True)
    Distribution('gamma(shape=0.5)+rev+sq')
    >>> gendr.distribution("gamma", shape=-1.0)
    Traceback (most recent call last):
    ...
    gendr.errors.ParameterError: distribution 'gamma' parameter shape=-1.0 ...
    """
    if isinstance(name, Distribution):
        if params or reversed or shift or squared:
            raise ParameterError("options cannot be combined with an existing Distribution object")
        return name
    fam = DISTRIBUTIONS.lookup(name)
    values = validate_params(f"distribution {name!r}", fam.params, params, learnable=True)
    if getattr(shift, "requires_grad", False):  # (float() would cut the gradient silently)
        raise ParameterError(f"distribution {name!r} parameter shift={shift!r} is not learnable: give a number")
    value = plain_number(shift) if not is_backend_array(shift) else array_value(f"distribution {name!r}", "shift", shift)
    if value is None or not math.isfinite(value):
        raise ParameterError(f"distribution {name!r} parameter shift={shift!r} must be a finite real number")
    shift = value
    for flag, v in (("reversed", reversed), ("squared", squared)):
        if not isinstance(v, bool):
            raise ParameterError(f"distribution {name!r} option {flag}={v!r} must be True or False")
    return Distribution(fam, tuple((p.name, values[p.name]) for p in fam.params), reversed, shift, squared)


# ------------------------------------------------------------------------------------------------
# The families. One entry each; every backend, test and report picks a new entry up.
# ------------------------------------------------------------------------------------------------

# Helpers. Conventions for autograd safety: every branch of a ``where`` is fed an argument for which
# it is finite (the double-where trick), so that a branch not taken contributes a zero, not NaN,
# gradient. Symmetric families (F(−x) = 1 − F(x)) get ``log_cdf(x) = log_sf(−x)``.

_LN2 = math.log(2.0)
_LOG_2_OVER_PI = math.log(2.0 / math.pi)
_INV_SQRT_2 = 1.0 / math.sqrt(2.0)
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


def _unbounded():
    return (-math.inf, math.inf)


def _mirror(fn):
    """``x -> fn(−x)``: log_cdf of a symmetric family from its log_sf (and vice versa)."""
    return lambda ops, x, **kw: fn(ops, -x, **kw)


def _log1mexp(ops, a):
    """log(1 − exp(−a)) for a > 0, accurate for small and large ``a`` (Mächler's switch at log 2)."""
    small = a < _LN2
    a_small = ops.where(small, a, _LN2)
    a_large = ops.where(small, _LN2, a)
    return ops.branch(small, lambda s, l: ops.log(-ops.expm1(-s)), lambda s, l: ops.log1p(-ops.exp(-l)),
                      a_small, a_large)


# --- heaviside ----------------------------------------------------------------------------------

def _heaviside_cdf(ops, x):
    return ops.where(x >= 0.0, ops.full_like(x, 1.0), 0.0)


def _heaviside_pdf(ops, x):
    return ops.full_like(x, 0.0)


DISTRIBUTIONS.add(DistributionFamily(
    "heaviside", _heaviside_cdf, _heaviside_pdf,
    support=lambda: (0.0, 0.0), tails=(BOUNDED, BOUNDED),
    log_sf=lambda ops, x: ops.where(x >= 0.0, ops.full_like(x, -math.inf), 0.0),
    log_cdf=lambda ops, x: ops.where(x >= 0.0, ops.full_like(x, 0.0), -math.inf),
    differentiable=False,
    doc="F(x) = 1 if x >= 0 else 0 (the hard occlusion test); density 0. Support: the point {0}.",
))


# --- uniform on [-1, 1] -------------------------------------------------------------------------

def _uniform_cdf(ops, x):
    return ops.clamp((x + 1.0) * 0.5, 0.0, 1.0)


def _uniform_pdf(ops, x):  # closed interval, as scipy and the derivative of a clamp at its ends
    return ops.where(ops.abs(x) <= 1.0, ops.full_like(x, 0.5), 0.0)


def _uniform_log_sf(ops, x):
    below = x < 1.0
    xs = ops.where(below, x, 0.0)
    return ops.where(below, ops.log(ops.clamp((1.0 - xs) * 0.5, None, 1.0)), -math.inf)


DISTRIBUTIONS.add(DistributionFamily(
    "uniform", _uniform_cdf, _uniform_pdf,
    support=lambda: (-1.0, 1.0), tails=(BOUNDED, BOUNDED),
    log_sf=_uniform_log_sf, log_cdf=_mirror(_uniform_log_sf),
    doc="Uniform on [−1, 1]: F(x) = clamp((x+1)/2, 0, 1), f(x) = 1/2 on [−1, 1].",
))


# --- cubic Hermite (smoothstep) on [-1, 1] ------------------------------------------------------

def _hermite_cdf(ops, x):
    t = ops.clamp((x + 1.0) * 0.5, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _hermite_pdf(ops, x):
    t = ops.clamp((x + 1.0) * 0.5, 0.0, 1.0)
    return 3.0 * t * (1.0 - t)


def _hermite_log_sf(ops, x):
    # 1 − F = u²(3 − 2u) with u = 1 − t = (1 − x)/2
    below = x < 1.0
    u = ops.clamp((1.0 - ops.where(below, x, 0.0)) * 0.5, None, 1.0)
    return ops.where(below, 2.0 * ops.log(u) + ops.log(3.0 - 2.0 * u), -math.inf)


DISTRIBUTIONS.add(DistributionFamily(
    "cubic_hermite", _hermite_cdf, _hermite_pdf,
    support=lambda: (-1.0, 1.0), tails=(BOUNDED, BOUNDED),
    log_sf=_hermite_log_sf, log_cdf=_mirror(_hermite_log_sf),
    doc="Smoothstep on [−1, 1]: t = clamp((x+1)/2, 0, 1), F(x) = t²(3 − 2t), f(x) = 3t(1 − t).",
))


# --- Wigner semicircle, radius 1 ----------------------------------------------------------------

def _semicircle_sf(ops, x):
    """1 − F(x) = (u − sin u)/(2π) with u = 2·acos(x), accurate as it → 0 (x → 1)."""
    inside = ops.abs(x) < 1.0
    xs = ops.where(inside, x, 0.0)
    u = 4.0 * ops.atan(ops.sqrt((1.0 - xs) / (1.0 + xs)))  # 2·acos(x), stable on (−1, 1)
    small = u < 1.0
    us = ops.where(small, u, 0.0)
    ud = ops.where(small, 1.0, u)
    v = us * us  # u − sin u = u³/3! − u⁵/5! + ... (7 terms: relative error < 2e-14 for u < 1)
    series = us * v / 6.0 * (1.0 - v / 20.0 * (1.0 - v / 42.0 * (1.0 - v / 72.0 * (
        1.0 - v / 110.0 * (1.0 - v / 156.0 * (1.0 - v / 210.0))))))
    g = ops.where(small, series, ud - ops.sin(ud)) * (0.5 / math.pi)
    return ops.where(inside, g, ops.where(x >= 1.0, ops.full_like(x, 0.0), 1.0))


def _semicircle_cdf(ops, x):
    return _semicircle_sf(ops, -x)


def _semicircle_pdf(ops, x):
    inside = ops.abs(x) < 1.0
    xs = ops.where(inside, x, 0.0)
    return ops.where(inside, (2.0 / math.pi) * ops.sqrt((1.0 - xs) * (1.0 + xs)), 0.0)


def _semicircle_log_sf(ops, x):
    below = x < 1.0
    return ops.where(below, ops.log(ops.where(below, _semicircle_sf(ops, x), 1.0)), -math.inf)


DISTRIBUTIONS.add(DistributionFamily(
    "wigner_semicircle", _semicircle_cdf, _semicircle_pdf,
    support=lambda: (-1.0, 1.0), tails=(BOUNDED, BOUNDED),
    log_sf=_semicircle_log_sf, log_cdf=_mirror(_semicircle_log_sf),
    doc="Semicircle of radius 1: F(x) = 1/2 + (x·sqrt(1−x²) + asin x)/π on [−1, 1], "
        "f(x) = (2/π)·sqrt(1 − x²). Evaluated as 1 − F(x) = (u − sin u)/(2π), u = 2·acos x.",
))


# --- Gaussian -----------------------------------------------------------------------------------

_GAUSS_TAIL_X = 6.0  # above: log Q(x) by Laplace's continued fraction (erfc underflows in float32)
_GAUSS_CF_DEPTH = 15  # relative error of Q < 1e-15 for x >= 6


def _gaussian_cdf(ops, x):
    return 0.5 * ops.erfc(-x * _INV_SQRT_2)


def _gaussian_pdf(ops, x):
    return _INV_SQRT_2PI * ops.exp(-0.5 * x * x)


def _gaussian_log_sf(ops, x):
    tail = x > _GAUSS_TAIL_X

    def log_tail(x):  # Q(x) = φ(x) / (x + 1/(x + 2/(x + 3/(x + ...))))
        xt = ops.where(tail, x, _GAUSS_TAIL_X)
        t = xt
        for k in range(_GAUSS_CF_DEPTH, 0, -1):
            t = xt + float(k) / t
        return -0.5 * xt * xt - _HALF_LOG_2PI - ops.log(t)
    return ops.branch(tail, log_tail, lambda x: ops.log(0.5 * ops.erfc(ops.where(tail, 0.0, x) * _INV_SQRT_2)), x)


DISTRIBUTIONS.add(DistributionFamily(
    "gaussian", _gaussian_cdf, _gaussian_pdf,
    support=_unbounded, tails=(EXPONENTIAL, EXPONENTIAL),
    log_sf=_gaussian_log_sf, log_cdf=_mirror(_gaussian_log_sf),
    doc="Standard normal: F(x) = erfc(−x/√2)/2, f(x) = exp(−x²/2)/√(2π). log(1 − F) uses erfc up "
        "to x = 6 and Laplace's continued fraction (depth 15) beyond.",
))


# --- Laplace ------------------------------------------------------------------------------------

def _laplace_cdf(ops, x):
    # one exp of −|x| (written as a where: its slope at 0 is the right side's, where abs's is 0)
    neg = x < 0.0
    h = 0.5 * ops.exp(ops.where(neg, x, -x))
    return ops.where(neg, h, 1.0 - h)


def _laplace_pdf(ops, x):
    return 0.5 * ops.exp(-ops.abs(x))


def _laplace_log_sf(ops, x):
    neg = x < 0.0
    xn = ops.where(neg, x, 0.0)
    xp = ops.where(neg, 0.0, x)
    return ops.where(neg, ops.log1p(-0.5 * ops.exp(xn)), -_LN2 - xp)


DISTRIBUTIONS.add(DistributionFamily(
    "laplace", _laplace_cdf, _laplace_pdf,
    support=_unbounded, tails=(EXPONENTIAL, EXPONENTIAL),
    log_sf=_laplace_log_sf, log_cdf=_mirror(_laplace_log_sf),
    accurate_logs=True,
    doc="Standard Laplace (scale 1): F(x) = e^x/2 for x < 0, 1 − e^(−x)/2 for x >= 0; "
        "f(x) = e^(−|x|)/2.",
))


# --- logistic -----------------------------------------------------------------------------------

def _logistic_cdf(ops, x):
    return ops.sigmoid(x)


def _logistic_pdf(ops, x):
    return ops.sigmoid(x) * ops.sigmoid(-x)  # not s·(1 − s): that cancels to 0 from x = 37


DISTRIBUTIONS.add(DistributionFamily(
    "logistic", _logistic_cdf, _logistic_pdf,
    support=lambda: (-math.inf, math.inf), tails=(EXPONENTIAL, EXPONENTIAL),
    log_sf=lambda ops, x: -ops.softplus(x),
    log_cdf=lambda ops, x: -ops.softplus(-x),
    accurate_logs=True,
    odds=lambda ops, x: ops.exp(x),
    log_odds=lambda ops, x: x,
    doc="F(x) = 1/(1+exp(−x)). SoftRas is its squared variant with the probabilistic T-conorm.",
))


# --- hyperbolic secant --------------------------------------------------------------------------

def _hypsec_cdf(ops, x):
    neg = x <= 0.0
    xn = ops.where(neg, x, 0.0)
    xp = ops.where(neg, 0.0, x)
    # atan(e^a) = π/2 − atan(e^(−a)): only exp of non-positive arguments
    return ops.where(neg, (2.0 / math.pi) * ops.atan(ops.exp((0.5 * math.pi) * xn)),
                     1.0 - (2.0 / math.pi) * ops.atan(ops.exp((-0.5 * math.pi) * xp)))


def _hypsec_pdf(ops, x):
    e = ops.exp((-0.5 * math.pi) * ops.abs(x))
    return e / (1.0 + e * e)


def _hypsec_log_sf(ops, x):
    pos = x > 0.0

    def right(x):
        a = (0.5 * math.pi) * ops.where(pos, x, 0.0)
        far = a > 40.0  # atan(u) = u to 1e-35 relative for u = e^(−a) < e^(−40)
        a_near = ops.where(far, 40.0, a)
        return ops.where(far, _LOG_2_OVER_PI - a, ops.log((2.0 / math.pi) * ops.atan(ops.exp(-a_near))))

    def left(x):
        xn = ops.where(pos, 0.0, x)
        return ops.log1p(-(2.0 / math.pi) * ops.atan(ops.exp((0.5 * math.pi) * xn)))
    return ops.branch(pos, right, left, x)


DISTRIBUTIONS.add(DistributionFamily(
    "hyperbolic_secant", _hypsec_cdf, _hypsec_pdf,
    support=_unbounded, tails=(EXPONENTIAL, EXPONENTIAL),
    log_sf=_hypsec_log_sf, log_cdf=_mirror(_hypsec_log_sf),
    accurate_logs=True,
    doc="Hyperbolic secant, unit variance: F(x) = (2/π)·atan(exp(πx/2)), f(x) = sech(πx/2)/2 (the "
        "reference implementation's Gudermannian (2/π)·atan(exp(x)) is this law scaled by 2/π).",
))


# --- Cauchy -------------------------------------------------------------------------------------

def _cauchy_tail(ops, x):
    """(pos, t, r): pos = x >= 0; t = F(−|x|) = min(F, 1 − F) from one atan of an argument in
    [0, 1], r = that argument (1/|x| above 1, where t = atan(1/|x|)/π keeps its relative accuracy).
    |x| is split with where, not abs (autograd's d|x|/dx is 0 at 0); the CDF and the log share this
    split, so a backend that merges common work (Dr.Jit) evaluates one atan for both."""
    pos = x >= 0.0
    a = ops.where(pos, x, -x)
    big = a > 1.0
    r = ops.where(big, 1.0 / ops.where(big, a, 1.0), a)
    phi = ops.atan(r) / math.pi
    return pos, ops.where(big, phi, 0.5 - phi), r


def _cauchy_cdf(ops, x):
    pos, t, _ = _cauchy_tail(ops, x)
    return ops.where(pos, 1.0 - t, t)


def _cauchy_log_sf(ops, x):
    # log t on the right (relatively accurate), log1p(−t) on the left (t <= 1/2). Beyond x = 1e4:
    # log(atan(r)/π) = log r − log π − r²/3 + O(r⁴), with log r = −log x where r = 1/x is below
    # 1e-37 (subnormal in float32, which Dr.Jit flushes to 0: log 0 = −inf at x = 1e38; and x = +inf,
    # an overflowed d/τ, then has the slope −1/x = 0, not log(0)'s inf·0)
    pos, t, r = _cauchy_tail(ops, x)
    far = x > 1e4

    def right(t, r, x):
        flip = far & (r < 1e-37)  # one logarithm per pair still: of t, r or x
        lg = ops.log(ops.where(pos, ops.where(far, ops.where(flip, x, r), t), 1.0))
        return ops.where(flip, -lg, lg) - ops.where(far, math.log(math.pi) + r * r / 3.0, 0.0)
    # a branch: the pairs of a SIMD packet mostly lie on one side of the face's edges, so most
    # packets evaluate one logarithm, not both
    return ops.branch(pos, right, lambda t, r, x: ops.log1p(-ops.where(pos, 0.0, t)), t, r, x)


def _cauchy_odds(ops, x):
    # t/(1 − t) outside the face, (1 − t)/t inside: one division, no logarithm (1 − t >= 1/2 is exact
    # enough); +inf only where t underflows, beyond float32's x ~ 1e38
    pos, t, _ = _cauchy_tail(ops, x)
    u = 1.0 - t
    return ops.where(pos, u, t) / ops.where(pos, t, u)


DISTRIBUTIONS.add(DistributionFamily(
    "cauchy", _cauchy_cdf,
    lambda ops, x: 1.0 / (math.pi * (1.0 + x * x)),
    support=_unbounded, tails=(HEAVY, HEAVY),
    log_sf=_cauchy_log_sf, log_cdf=_mirror(_cauchy_log_sf),
    accurate_logs=True,
    odds=_cauchy_odds,
    doc="Standard Cauchy: F(x) = 1/2 + atan(x)/π, f(x) = 1/(π(1 + x²)). Heavy tails "
        "(1 − F ~ 1/(πx)): the culling radius τ/(π·ε) is finite but of no practical use.",
))


# --- reciprocal ---------------------------------------------------------------------------------

def _reciprocal_sides(ops, x):
    """(x > 0, x there else 0, x elsewhere else 0): each side's formula sees only its own x."""
    pos = x > 0.0
    return pos, ops.where(pos, x, 0.0), ops.where(pos, 0.0, x)


def _reciprocal_sf(ops, x):
    pos, xp, xn = _reciprocal_sides(ops, x)
    return ops.where(pos, 0.5 / (1.0 + xp), 1.0 - 0.5 / (1.0 - xn))


def _reciprocal_log_sf(ops, x):
    pos, xp, xn = _reciprocal_sides(ops, x)
    return ops.branch(pos, lambda xp, xn: -_LN2 - ops.log1p(xp), lambda xp, xn: ops.log1p(-0.5 / (1.0 - xn)), xp, xn)


def _reciprocal_odds(ops, x):
    # F/(1 − F) = 1 + 2x for x > 0 and 1/(1 − 2x) below: exact up to rounding, no logarithm
    pos, xp, xn = _reciprocal_sides(ops, x)
    return ops.where(pos, 1.0 + 2.0 * xp, 1.0 / (1.0 - 2.0 * xn))


def _reciprocal_pdf(ops, x):
    r = 1.0 + ops.abs(x)
    return 0.5 / (r * r)


DISTRIBUTIONS.add(DistributionFamily(
    "reciprocal", lambda ops, x: _reciprocal_sf(ops, -x), _reciprocal_pdf,
    support=_unbounded, tails=(HEAVY, HEAVY),
    log_sf=_reciprocal_log_sf, log_cdf=_mirror(_reciprocal_log_sf),
    accurate_logs=True,
    odds=_reciprocal_odds,
    doc="F(x) = 1/2 + x/(2(1 + |x|)), f(x) = 1/(2(1 + |x|)²). Heavy tails (1 − F ~ 1/(2x)): "
        "the culling radius ≈ τ/(2ε) is finite but of no practical use.",
))


# --- Gumbel-max and Gumbel-min ------------------------------------------------------------------

_GUMBEL_LO = -50.0  # F_max(x) = exp(−e^(−x)) underflows to exactly 0 below this (in float64 too)
_GUMBEL_LOG_LO = -80.0  # log F_max = −e^(−x) is held at −e^80 ≈ −5.5e34 below this (finite in float32)
_GUMBEL_HI = 40.0  # log(1 − F_max) = −x − e^(−x)/2 + ... = −x to float64 precision above this


def _gmax_cdf(ops, x):
    return ops.exp(-ops.exp(-ops.where(x > _GUMBEL_LO, x, _GUMBEL_LO)))


def _gmax_pdf(ops, x):
    xs = ops.where(x > _GUMBEL_LO, x, _GUMBEL_LO)
    return ops.exp(-xs - ops.exp(-xs))


def _gmax_log_cdf(ops, x):
    return -ops.exp(-ops.where(x > _GUMBEL_LOG_LO, x, _GUMBEL_LOG_LO))


def _gmax_log_sf(ops, x):
    far = x > _GUMBEL_HI
    xm = ops.where(far, _GUMBEL_HI, ops.where(x > _GUMBEL_LO, x, _GUMBEL_LO))
    return ops.where(far, -x, _log1mexp(ops, ops.exp(-xm)))


DISTRIBUTIONS.add(DistributionFamily(
    "gumbel_max", _gmax_cdf, _gmax_pdf,
    support=_unbounded, tails=(EXPONENTIAL, EXPONENTIAL),
    log_sf=_gmax_log_sf, log_cdf=_gmax_log_cdf,
    accurate_logs=True,
    doc="Standard Gumbel (maximum): F(x) = exp(−exp(−x)), f(x) = exp(−x − exp(−x)); "
        "log F = −exp(−x) (held at −exp(80) for x < −80 to stay finite). The left tail is "
        "double-exponential, i.e. lighter than EXPONENTIAL.",
))

def _gmin_cdf(ops, x):
    # 1 − exp(−e^x): by expm1 where it is small (x < 0); by exp above, whose autograd derivative
    # (from its result) stays accurate where expm1's (from result + 1) would round to 0
    neg = x < 0.0
    u = ops.exp(ops.where(neg, x, ops.where(x < -_GUMBEL_LO, x, -_GUMBEL_LO)))
    return ops.where(neg, -ops.expm1(-u), 1.0 - ops.exp(-u))


DISTRIBUTIONS.add(DistributionFamily(
    "gumbel_min", _gmin_cdf, _mirror(_gmax_pdf),
    support=_unbounded, tails=(EXPONENTIAL, EXPONENTIAL),
    log_sf=_mirror(_gmax_log_cdf), log_cdf=_mirror(_gmax_log_sf),
    accurate_logs=True,
    doc="Gumbel (minimum): F(x) = 1 − exp(−exp(x)), f(x) = exp(x − exp(x)), i.e. the reversed "
        "gumbel_max. (The paper's printed Gumbel-Min formula is not increasing; this is the CDF "
        "of the Gumbel-min distribution.) log(1 − F) = −exp(x), held at −exp(80) for x > 80.",
))


# --- exponential --------------------------------------------------------------------------------

def _expon_cdf(ops, x):
    # expm1 near 0, 1 − exp above 1 (accurate autograd derivative there, see _gmin_cdf)
    xp = ops.where(x >= 0.0, x, 0.0)
    return ops.where(xp < 1.0, -ops.expm1(-xp), 1.0 - ops.exp(-xp))


def _expon_pdf(ops, x):
    pos = x >= 0.0
    return ops.where(pos, ops.exp(-ops.where(pos, x, 0.0)), 0.0)


def _expon_log_cdf(ops, x):
    pos = x > 0.0
    return ops.where(pos, _log1mexp(ops, ops.where(pos, x, 1.0)), -math.inf)


DISTRIBUTIONS.add(DistributionFamily(
    "exponential", _expon_cdf, _expon_pdf,
    support=lambda: (0.0, math.inf), tails=(BOUNDED, EXPONENTIAL),
    log_sf=lambda ops, x: -ops.where(x >= 0.0, x, 0.0), log_cdf=_expon_log_cdf,
    accurate_logs=True,
    doc="Standard exponential (rate 1): F(x) = 1 − e^(−x) for x >= 0, 0 below; f(x) = e^(−x) "
        "on [0, ∞); log(1 − F) = −x.",
))


# --- gamma --------------------------------------------------------------------------------------

#: P(k, x) by its power series for x < k + _GAMMA_SWITCH, else Q(k, x) by Legendre's continued
#: fraction; both evaluated with a fixed number of terms (absolute error of P < 2e-8 in float64 for
#: shapes 0.1..20 and x in [0, 100]; see tests/test_distributions.py).
_GAMMA_SWITCH = 1.5
#: beyond k = 20 the series has not converged near x = k (|error| 2e-7 at k = 25, 4e-3 at k = 100)
_GAMMA_SHAPES = Constraint("in (0, 20]", lambda v: 0.0 < v <= 20.0)
_GAMMA_SERIES_TERMS = 32
_GAMMA_CF_DEPTH = 11
#: integer shapes whose upper branch is the finite sum Q = e^(−x) Σ_{n<k} x^n/n! (x^k stays finite in
#: float32 over the x the renderer keeps)
_GAMMA_INTEGER_SHAPES = frozenset(float(k) for k in range(1, 9))
_GAMMA_SUM_MAX = 1e4  # (1e4)^8 < float32's max
#: x = +inf (an overflowed d/τ) is read as this (finite in float32 too: Q = 0, F = 1 exactly), where
#: log Q = k·log x − x and log f would be inf − inf
_GAMMA_X_MAX = 3e38


def _log_ratio(ops, x, k):
    """log(x/k) for x > 0, accurate (log1p) near x = k, where float32 would cancel k·log x − x."""
    near = ops.abs(x - k) < 0.5 * k
    x_near = ops.where(near, x, k)
    x_far = ops.where(near, k, x)
    return ops.where(near, ops.log1p((x_near - k) / k), ops.log(x_far) - math.log(k))


def _finite_gamma_x(ops, x):
    return ops.where(x == math.inf, _GAMMA_X_MAX, x)


def _gamma_parts(ops, x, k, shape_derivatives=False):
    """The incomplete gamma function at x > 0 (finite elsewhere, unused) by the approximation of
    x's range: the series where ``use_series`` (x < k + _GAMMA_SWITCH), else the fraction (a
    branch: Dr.Jit's packets skip the one none of their lanes takes).

    Returns ``(use_series, log_p, log_q, a, b)``: the selection, log P(k, x), log Q(k, x) and what
    the derivatives reuse: (xs, Σ) of the series in its lanes, (xc, t) of the fraction in the
    others. With ``shape_derivatives``, also ``db``: ∂Σ/∂k or ∂t/∂k of the same truncated series
    and fraction, differentiated term by term in the same loops (see _gamma_shape_derivatives).
    An integer k in _GAMMA_INTEGER_SHAPES takes the finite sum for Q in place of the fraction (exact,
    and less work in the renderer's loops; a learnable k that sits on an integer too, so that its
    image equals the float's; its ∂/∂k keeps the fraction's term-by-term derivative).
    """
    x = _finite_gamma_x(ops, x)  # (once, before the regimes: the upper ones would read inf − inf)
    sw = k + _GAMMA_SWITCH
    use_series = x < sw
    # log of x^k e^(−x) / Γ(k+1), as k·log(x/k) − (x − k) − c with c a float64 constant
    c = math.lgamma(k + 1.0) - k * math.log(k) + k

    def series(x):  # P = x^k e^(−x) / Γ(k+1) · Σ_n x^n / ((k+1)...(k+n)),  n < _GAMMA_SERIES_TERMS
        xs = ops.where(x > 0.0, ops.where(use_series, x, sw), 1.0)
        term = ops.full_like(xs, 1.0)
        total = term
        # ∂term_n/∂k = −term_n Σ_{j≤n} 1/(k+j) (only when asked: this is the renderer's hot loop)
        dtotal, harmonic = (ops.full_like(xs, 0.0), 0.0) if shape_derivatives else (None, None)
        for n in range(1, _GAMMA_SERIES_TERMS):
            term = term * xs / (k + n)
            total = total + term
            if shape_derivatives:
                harmonic += 1.0 / (k + n)
                dtotal = dtotal - term * harmonic
        log_p = k * _log_ratio(ops, xs, k) - (xs - k) - c + ops.log(total)
        parts = (log_p, ops.log1p(-ops.exp(log_p)), xs, total)
        return parts + (dtotal,) if shape_derivatives else parts

    def fraction(x):  # Legendre's, bottom-up from depth _GAMMA_CF_DEPTH:
        # Q = x^k e^(−x) / Γ(k) / t,  t = x+1−k − 1(1−k)/(x+3−k − 2(2−k)/(x+5−k − ...))
        xc = ops.where(use_series, sw, x)
        t = xc + (2.0 * _GAMMA_CF_DEPTH + 1.0 - k)
        dt = ops.full_like(xc, -1.0) if shape_derivatives else None
        for n in range(_GAMMA_CF_DEPTH, 0, -1):
            if shape_derivatives:  # of t_n = x + 2n − 1 − k − n(n − k)/t_{n+1}
                dt = -1.0 + n / t + (n * (n - k)) * dt / (t * t)
            t = xc + (2.0 * n - 1.0 - k) - (n * (n - k)) / t
        log_q = k * _log_ratio(ops, xc, k) - (xc - k) - (c - math.log(k)) - ops.log(t)
        parts = (ops.log1p(-ops.exp(log_q)), log_q, xc, t)
        return parts + (dt,) if shape_derivatives else parts

    def finite_sum(x):  # integer k: Q = e^(−x) Σ_{n<k} x^n/n! exactly, positive terms (no fraction);
        # t = x^k / ((k−1)!·Σ) is the fraction's t, so the derivatives read it alike (−t/x)
        xc = ops.where(use_series, sw, x)
        big = xc > _GAMMA_SUM_MAX
        xs = ops.where(big, _GAMMA_SUM_MAX, xc)
        total = ops.full_like(xs, 1.0)
        power = xs
        for n in range(int(k) - 1, 0, -1):  # Horner: 1 + x(1 + x/2(1 + ... (1 + x/(k−1))))
            total = 1.0 + total * xs * (1.0 / n)
            power = power * xs
        # beyond _GAMMA_SUM_MAX, where x^k would overflow float32: the same sum in powers of y = 1/x,
        # Σ = x^(k−1)/(k−1)! · s(y), s(y) = Σ_j (k−1)!/(k−1−j)! y^j, so log Q = (k−1) log x −
        # log (k−1)! + log s − x and t/x = 1/s (before: log Q = −x and t from x clamped to 1e4,
        # a slope −0.9999 for k = 2 at any x > 1e4)
        xb = ops.where(big, xc, 2.0 * _GAMMA_SUM_MAX)
        y = 1.0 / xb
        s = ops.full_like(xb, 1.0)
        for f in range(1, int(k)):  # Horner: 1 + (k−1)y(1 + (k−2)y(... (1 + y)))
            s = 1.0 + s * y * float(f)
        log_q = ops.where(big, (k - 1.0) * ops.log(xb) - math.lgamma(k) + ops.log(s) - xb, ops.log(total) - xs)
        # (a big lane's t is given over the clamped xs, which the slope −t/xs reads as −1/s)
        t = ops.where(big, xs / s, power / (math.factorial(int(k) - 1) * total))
        return ops.log1p(-ops.exp(log_q)), log_q, xs, t

    upper = finite_sum if k in _GAMMA_INTEGER_SHAPES and not shape_derivatives else fraction
    return (use_series, *ops.branch(use_series, series, upper, x))


def _gamma_log_pdf(ops, x, k):
    """log f on x > 0 (finite elsewhere, where it is unused; −huge at x = +inf, not inf − inf)."""
    xs = ops.where(x > 0.0, _finite_gamma_x(ops, x), 1.0)
    return (k - 1.0) * ops.log(xs) - xs - math.lgamma(k)


def _gamma_pdf(ops, x, shape):
    return ops.where(x > 0.0, ops.exp(_gamma_log_pdf(ops, x, float(shape))), 0.0)


def _digamma(k: float) -> float:
    """ψ(k) = d log Γ(k)/dk for a float k > 0: recurrence up to k >= 16, then the asymptotic
    series to the k⁻¹⁰ term (truncation error < 1e-16 there)."""
    acc = 0.0
    while k < 16.0:
        acc -= 1.0 / k
        k += 1.0
    r = 1.0 / (k * k)
    return acc + math.log(k) - 0.5 / k - r * (1 / 12 - r * (1 / 120 - r * (1 / 252 - r * (1 / 240 - r / 132))))


def _gamma_shape_derivatives(ops, x, k):
    """(use_series, ∂ log P/∂k, ∂ log Q/∂k, log P, log Q) of the regularized incomplete gamma
    functions at x > 0 (0 elsewhere), from the same truncated series and continued fraction,
    differentiated term by term (:func:`_gamma_parts` with ``shape_derivatives``):

    series: log P = k log x − x − log Γ(k+1) + log Σ_n a_n, a_n = Π_{j≤n} x/(k+j), with
            ∂a_n/∂k = −a_n Σ_{j≤n} 1/(k+j);
    fraction: log Q = k log x − x − log Γ(k) − log t, with ∂t/∂k from the recurrence of t.
    The other function follows from P + Q = 1 (∂ log P/∂k = −(Q/P) ∂ log Q/∂k)."""
    x = ops.detach(x)
    use_series, log_p, log_q, a, b, db = _gamma_parts(ops, x, k, shape_derivatives=True)
    dlog_p_series = ops.log(a) - _digamma(k + 1.0) + db / b  # (series lanes: a = xs, b = Σ)
    dlog_q_cf = ops.log(a) - _digamma(k) - db / b  # (fraction lanes: a = xc, b = t)
    dlog_p = ops.where(use_series, dlog_p_series, -ops.exp(log_q - log_p) * dlog_q_cf)
    dlog_q = ops.where(use_series, -ops.exp(log_p - log_q) * dlog_p_series, dlog_q_cf)
    pos = x > 0.0
    return use_series, ops.where(pos, dlog_p, 0.0), ops.where(pos, dlog_q, 0.0), log_p, log_q


def _with_shape_gradient(ops, value, k, derivative):
    """``value`` (computed with k as a float) plus ``(k − detach k)·derivative``: the value is
    unchanged and ∂/∂k = ``derivative`` when k is a :class:`Learnable` (nothing added otherwise)."""
    if not isinstance(k, Learnable) or isinstance(ops, NumpyOps):
        return value
    ka = k.array
    d = derivative()
    # a non-finite derivative (none is expected) must not turn the value into NaN (0·inf)
    return value + (ka - ops.detach(ka)) * ops.where(d - d == 0.0, d, 0.0)


def _gamma_cdf_and_logs(ops, x, shape):
    """``(F, log(1 − F), log F)`` of gamma(k) from one evaluation of the incomplete gamma function,
    each with its exact derivative attached (f, −f/Q, f/P; never through the iterations) and, for a
    learnable k, its ∂/∂k. The renderer's loops ask for two of them at once (cdf_and_log_sf)."""
    k = float(shape)  # (a Learnable is a float subclass; Dr.Jit takes only plain floats)
    xd = ops.detach(x)
    pos = xd > 0.0
    use_series, log_p, log_q, a, b = _gamma_parts(ops, xd, k)
    F = ops.where(pos, ops.where(use_series, ops.exp(log_p), -ops.expm1(log_q)), 0.0)
    log_sf = ops.where(pos, log_q, 0.0)
    log_cdf = ops.where(pos, log_p, -math.inf)

    def d_log_sf(_):  # d log Q/dx = −f/Q; in the fraction's lanes exactly −t/x (a = x, b = t)
        return ops.where(pos, ops.where(use_series, -ops.exp(_gamma_log_pdf(ops, xd, k) - log_q), -b / a), 0.0)

    def d_log_cdf(_):  # d log P/dx = f/P; in the series' lanes exactly k/(x·Σ) (a = x, b = Σ)
        return ops.where(pos, ops.where(use_series, k / (a * b), ops.exp(_gamma_log_pdf(ops, xd, k) - log_p)), 0.0)

    shape_d = []  # ∂/∂k of the three, evaluated once (and only for a learnable k)

    def dk(i):
        if not shape_d:
            shape_d.append(_gamma_shape_derivatives(ops, x, k))
        return shape_d[0][i]

    def dk_cdf():  # ∂P/∂k = P ∂log P/∂k = −Q ∂log Q/∂k (the one that does not cancel)
        use, dlog_p, dlog_q, lp, lq = (dk(i) for i in range(5))
        return ops.where(use, ops.exp(lp) * dlog_p, -ops.exp(lq) * dlog_q)
    return (_with_shape_gradient(ops, ops.with_derivative(lambda _: F, lambda _: _gamma_pdf(ops, xd, k), x),
                                 shape, dk_cdf),
            _with_shape_gradient(ops, ops.with_derivative(lambda _: log_sf, d_log_sf, x), shape, lambda: dk(2)),
            _with_shape_gradient(ops, ops.with_derivative(lambda _: log_cdf, d_log_cdf, x), shape, lambda: dk(1)))


DISTRIBUTIONS.add(DistributionFamily(
    "gamma", lambda ops, x, shape: _gamma_cdf_and_logs(ops, x, shape)[0], _gamma_pdf,
    support=lambda shape: (0.0, math.inf), tails=(BOUNDED, EXPONENTIAL),
    params=(Param("shape", _GAMMA_SHAPES, doc="shape 0 < k <= 20 (scale 1)"),),
    log_sf=lambda ops, x, shape: _gamma_cdf_and_logs(ops, x, shape)[1],
    log_cdf=lambda ops, x, shape: _gamma_cdf_and_logs(ops, x, shape)[2],
    cdf_and_logs=_gamma_cdf_and_logs, accurate_logs=True,
    doc="Gamma with shape k, scale 1: F(x) = P(k, x) (regularized lower incomplete gamma) for "
        "x > 0, 0 below; f(x) = x^(k−1) e^(−x) / Γ(k). P by its power series (32 terms) for "
        "x < k + 1.5, else 1 − Q with Q by Legendre's continued fraction (depth 11) or, for an "
        "integer k ≤ 8, the exact finite sum e^(−x) Σ_{n<k} x^n/n!, as a branch (``ops.branch``); "
        "derivatives via with_derivative (f, −f/Q, f/P), never through the iterations.",
))


# --- Lévy ---------------------------------------------------------------------------------------

_LEVY_LO = 5e-4  # F(x) = erfc(sqrt(1/(2x))) < erfc(31.6) ≈ 1e-436: exactly 0 in float64 below this


def _levy_z(ops, x):
    """(x > _LEVY_LO, z = √(1/(2x)) there, else 1/√2). z = 0 at x = +inf is a constant: through
    the square root its gradient would be inf·0 = NaN."""
    pos = x > _LEVY_LO
    finite = x < math.inf
    return pos, ops.where(finite, ops.sqrt(0.5 / ops.where(pos, ops.where(finite, x, 1.0), 1.0)), 0.0)


def _levy_cdf(ops, x):
    pos, z = _levy_z(ops, x)
    return ops.where(pos, ops.erfc(z), 0.0)


def _levy_sf(ops, x):
    # 1 − F = erf(√(1/(2x))): one erf, relatively accurate where small (x large)
    pos, z = _levy_z(ops, x)
    return ops.where(pos, ops.erf(z), 1.0)


def _levy_pdf(ops, x):
    pos = x > _LEVY_LO
    xs = ops.where(pos, x, 1.0)
    return ops.where(pos, _INV_SQRT_2PI * ops.exp(-0.5 / xs) / (xs * ops.sqrt(xs)), 0.0)


def _levy_log_sf(ops, x):
    pos, z = _levy_z(ops, x)
    small = z < 1.0  # 1 − F = erf(z): log erf(z) for small z, log1p(−erfc z) for large z
    z_small = ops.where(small, z, 0.5)
    z_large = ops.where(small, 1.0, z)
    val = ops.branch(small, lambda zs, zl: ops.log(ops.erf(zs)), lambda zs, zl: ops.log1p(-ops.erfc(zl)),
                     z_small, z_large)
    return ops.where(pos, val, 0.0)


def _levy_log_cdf(ops, x):
    # log erfc(z), z = sqrt(1/(2x)): log1p(−erf z) for z < 1/2 (F near 1: keeps log F's relative
    # accuracy, which log 2 + log Q(z·√2) loses to cancellation), else log 2 + log Q(z·√2);
    # x held >= 1e-30 (value −5e29 there)
    pos = x > 0.0
    finite = x < math.inf  # w = 0 there as a constant (as in _levy_z)
    xs = ops.where(pos, ops.where(x > 1e-30, ops.where(finite, x, 1.0), 1e-30), 1.0)
    w = ops.where(finite, ops.sqrt(1.0 / xs), 0.0)  # z·√2
    near_one = w < 0.5 * math.sqrt(2.0)
    val = ops.branch(near_one, lambda w: ops.log1p(-ops.erf(ops.where(near_one, w, 0.0) * math.sqrt(0.5))),
                     lambda w: _LN2 + _gaussian_log_sf(ops, ops.where(near_one, 1.0, w)), w)
    return ops.where(pos, val, -math.inf)


DISTRIBUTIONS.add(DistributionFamily(
    "levy", _levy_cdf, _levy_pdf,
    support=lambda: (0.0, math.inf), tails=(BOUNDED, HEAVY),
    log_sf=_levy_log_sf, log_cdf=_levy_log_cdf, sf=_levy_sf,
    accurate_logs=True,
    doc="Standard Lévy: F(x) = erfc(sqrt(1/(2x))) for x > 0, 0 below; "
        "f(x) = exp(−1/(2x)) / sqrt(2π x³). Heavy right tail (1 − F ~ sqrt(2/(πx))): reversed, "
        "its culling radius ≈ 2τ/(π ε²) is finite but of no practical use.",
))
