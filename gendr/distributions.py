"""Distributions whose CDF turns a signed pixel-to-edge distance into soft coverage.

Each family is ONE entry in :data:`DISTRIBUTIONS` (formulas written once against an ops namespace,
see :mod:`gendr.ops`). :func:`distribution` builds a :class:`Distribution` spec: a family with
validated parameters and the ``reversed`` / ``shift`` / ``squared`` variants (DESIGN.md §3):

* plain:    p = F(d / τ)
* squared:  p = F(d·|d| / τ)
* reversed: F_rev(x) = 1 − F(−x)
* shifted:  F(x + shift)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

from .ops import numpy_ops
from .params import Param, Registry, validate_params, POSITIVE
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
    differentiable: bool = True
    doc: str = ""


DISTRIBUTIONS = Registry("distribution")


@dataclass(frozen=True)
class Distribution:
    """A validated distribution setting. Frozen and hashable; build it with :func:`distribution`."""

    family: DistributionFamily
    params: tuple[tuple[str, float], ...] = ()
    reversed: bool = False
    shift: float = 0.0
    squared: bool = False

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
            s += "(" + ",".join(f"{k}={v:g}" for k, v in self.params) + ")"
        if self.shift:
            s += f"+shift={self.shift:g}"
        if self.reversed:
            s += "+rev"
        if self.squared:
            s += "+sq"
        return s

    # --- the effective one-dimensional CDF (reversed and shift applied, not squared) ---
    def cdf(self, ops, x):
        f, kw = self.family, self.kwargs
        x = x + self.shift if self.shift else x
        if self.reversed:
            return 1.0 - f.cdf(ops, -x, **kw)
        return f.cdf(ops, x, **kw)

    def pdf(self, ops, x):
        f, kw = self.family, self.kwargs
        x = x + self.shift if self.shift else x
        return f.pdf(ops, -x if self.reversed else x, **kw)

    def log_sf(self, ops, x):
        """log(1 − F(x)) of the effective CDF, accurate where the family supplies it."""
        f, kw = self.family, self.kwargs
        x = x + self.shift if self.shift else x
        if self.reversed:  # 1 − F_rev(x) = F(−x)
            if f.log_cdf is not None:
                return f.log_cdf(ops, -x, **kw)
            return ops.log(f.cdf(ops, -x, **kw))
        if f.log_sf is not None:
            return f.log_sf(ops, x, **kw)
        return ops.log1p(-f.cdf(ops, x, **kw))

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

    def coverage(self, ops, d, tau):
        """Soft coverage ``(p, log(1 − p))`` of signed distances ``d`` at scale ``tau``."""
        x = self.argument(ops, d, tau)
        return self.cdf(ops, x), self.log_sf(ops, x)

    def quantile(self, q: float) -> float:
        """Smallest x with F(x) >= q (float64 bisection on the CDF; ``-inf`` if F(x) >= q for all x)."""
        if not 0.0 <= q <= 1.0:
            raise ParameterError(f"quantile level q={q!r} must lie in [0, 1]")
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


def distribution(name, *, reversed: bool = False, shift: float = 0.0, squared: bool = False, **params) -> Distribution:
    """Build a distribution spec: ``gendr.distribution("gamma", shape=0.5, reversed=True)``.

    ``name`` may also be a :class:`Distribution` (returned unchanged when no options are given).
    Raises :class:`~gendr.errors.UnknownNameError` listing valid names, and
    :class:`~gendr.errors.ParameterError` for out-of-domain parameters.
    """
    if isinstance(name, Distribution):
        if params or reversed or shift or squared:
            raise ParameterError("options cannot be combined with an existing Distribution object")
        return name
    fam = DISTRIBUTIONS.lookup(name)
    values = validate_params(f"distribution {name!r}", fam.params, params)
    try:
        shift = float(shift)
    except (TypeError, ValueError):
        raise ParameterError(f"distribution {name!r} parameter shift={shift!r} must be a finite real number") from None
    if not math.isfinite(shift):
        raise ParameterError(f"distribution {name!r} parameter shift={shift!r} must be a finite real number")
    for flag, v in (("reversed", reversed), ("squared", squared)):
        if not isinstance(v, bool):
            raise ParameterError(f"distribution {name!r} option {flag}={v!r} must be True or False")
    return Distribution(fam, tuple((p.name, values[p.name]) for p in fam.params), reversed, shift, squared)


# ------------------------------------------------------------------------------------------------
# The families. One entry each; every backend, test and report picks a new entry up.
# ------------------------------------------------------------------------------------------------

def _logistic_cdf(ops, x):
    return ops.sigmoid(x)


def _logistic_pdf(ops, x):
    s = ops.sigmoid(x)
    return s * (1.0 - s)


DISTRIBUTIONS.add(DistributionFamily(
    "logistic", _logistic_cdf, _logistic_pdf,
    support=lambda: (-math.inf, math.inf), tails=(EXPONENTIAL, EXPONENTIAL),
    log_sf=lambda ops, x: -ops.softplus(x),
    log_cdf=lambda ops, x: -ops.softplus(-x),
    doc="F(x) = 1/(1+exp(−x)). SoftRas is its squared variant with the probabilistic T-conorm.",
))
