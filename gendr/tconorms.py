"""T-conorms that aggregate the soft coverage of all faces at a pixel.

Each family is ONE entry in :data:`TCONORMS`. One entry, ``average`` (the mean over the faces), is
not a T-conorm at all (``is_tconorm`` False; see below). Every other family except ``max`` and the
hard ``or`` is a continuous Archimedean T-conorm with an additive generator g (increasing, g(0) = 0), so the n-ary
aggregate over any number of faces is (DESIGN.md §4)

    A = g⁻¹( min( g(1), Σ_t g(p_t) ) ),      ∂A/∂p_k = g'(p_k) / g'(A),

exact, order-independent and a plain streaming sum. ``binary`` holds the paper's two-argument
formula; tests check that the generator form reproduces it.

Generators take ``(ops, x, log1m_x, **params)`` where ``log1m_x`` = log(1 − x) supplied accurately by
the distribution (−log(1 − p) loses everything in float32 as p → 1).

Numerical contract of the archimedean entries (float32 and float64, NumPy and torch autograd):

* ``generator`` is accurate to a few ulp relative over all of [0, 1], near 0 (no log(1 − x) of a tiny
  x) and near 1 (it reads ``log1m_x``, never 1 − x, where 1 − x matters; ``x`` and ``log1m_x`` must
  describe the same value, and gradients flow through whichever one a branch reads). Where its value
  is +inf (x = 1, i.e. ``log1m_x`` = −inf, or an overflow) it returns +inf with a *zero* (or finite)
  gradient rather than an inf/NaN one, so that autograd through ``g⁻¹(Σ g)`` of a saturated pixel
  gives 0, not 0·∞ = NaN. (If the caller computes ``log1m_x`` as ``log1p(−x)`` under autograd, x = 1
  itself still yields log1p's −∞ derivative: supply it from the distribution, e.g. ``−softplus``.)
* ``generator_inverse`` accepts any 0 <= s <= g(1), including huge s and s = +inf (→ 1 with zero
  gradient), without overflow or NaN.
* Where the true one-sided derivative at x = 0 (or s = 0) is +inf (x^p with p < 1: yager p < 1,
  dombi p < 1, aczel_alsina p < 1; the inverses of yager, aczel_alsina and dombi with p > 1) the
  formulas report a gradient of 0 there instead of inf/NaN. Everywhere else gradients are exact.
* Known limits: in float32 a generator can overflow to +inf (the aggregate then saturates to 1)
  while x is still representably below 1 for dombi p > 5, schweizer_sklar p < −5 and aczel_alsina
  p > 30 (in float64 only when (x/(1 − x))^p, (1 − x)^p or (−log(1 − x))^p really exceeds 1.8e308).
  frank's generator and inverse are accurate for any p in float64 and for 1e-37 < p < 1e37 in
  float32 (the constants p − 1 and 1/p − 1 must be finite). yager's x^p underflows in float32 for
  large p (p = 50: x = 0.17 gives 3e-39, subnormal; Dr.Jit's kernels may flush it to 0, and the
  torch backend zeroes a subnormal sum too, where its gradient would be NaN: in both, that
  pixel's coverage 0.17 is lost). hamacher with a fixed p > ~1e30 overflows its generator in float32
  (alpha 1 where the coverage is 0.9997). hamacher with a fixed 0 < p < ~1e-19 (float32) or 1e-154
  (float64) renders right, but Dr.Jit's derivative of the inverse w/(w + p·u) is −a/b² with b ~ p,
  which underflows: its gradients are wrong (torch's are right). Use float64 beyond those.
* ``average`` (kind ``"mean"``, ``is_tconorm`` False) is not a T-conorm: A = Σ_t p_t / F over all F
  faces of the mesh (SoftRas' mean aggregation). It streams like the archimedean kinds with the
  per-pair term p (:meth:`TConorm.pair_term`) and the finish Σ/F (:meth:`TConorm.from_sum`).
* ``binary`` is the paper's two-argument formula, a float64 forward reference (tests, docs, the
  grid); its values are right on all of [0, 1]² (frank with p < 1e-3 cancels: absolute error grows
  to ~1e-12 at p = 1e-6 and ~1e-8 at p = 1e-10), its gradients are meant for arguments in [0, 1).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from .params import (Param, Registry, validate_params, POSITIVE, NONNEGATIVE, NEGATIVE, POSITIVE_NOT_ONE,
                     Learnable, LearnableParams, array_of as _a, short_number)
from .errors import ParameterError
from .ops import quiet_numpy

ARCHIMEDEAN, MAX, HARD_OR, MEAN = "archimedean", "max", "or", "mean"
#: kinds whose n-ary aggregate is a function of a per-pixel *sum* of per-pair terms: backends stream
#: them (scatter-add / one summing loop) and finish with :meth:`TConorm.from_sum`
SUM_KINDS = (ARCHIMEDEAN, MEAN)


@dataclass(frozen=True)
class TConormFamily:
    """One aggregation family. ``kind`` is ``"archimedean"``, ``"max"``, ``"or"`` or ``"mean"``.

    ``is_tconorm`` is False for an aggregation that is not a T-conorm (``average``, kind ``"mean"``):
    it is selected like one (``gendr.tconorm(name)``, ``Renderer(dist, name)``) but is listed apart
    and is never part of the paper's grid of T-conorms."""

    name: str
    kind: str
    binary: Callable  # (ops, a, b, **params) -> S(a, b), the paper's formula
    params: tuple[Param, ...] = ()
    generator: Callable | None = None  # (ops, x, log1m_x, **params) -> g(x)
    generator_inverse: Callable | None = None  # (ops, s, **params) -> x, for 0 <= s <= g(1)
    generator_at_one: Callable | None = None  # (**params) -> g(1) as a Python float (inf: strict)
    doc: str = ""
    is_tconorm: bool = True
    #: optional ``(**params) -> c`` (or None) where the generator is log(1 + c·x/(1 − x)) (probabilistic:
    #: 1, einstein: 2, hamacher p > 0: p): a backend may sum it as log Π(1 + c·odds) for distributions
    #: with closed-form odds (Distribution.has_odds), one log per pixel instead of one per face
    odds_factor: Callable | None = None
    #: optional ``(ops, log_odds, **params) -> g`` where the generator depends on x only through its
    #: odds (dombi: (x/(1 − x))^p = exp(p·log odds)): a backend may evaluate it from a distribution's
    #: closed-form log-odds (the logistic's are x) instead of from F and log(1 − F)
    odds_generator: Callable | None = None


TCONORMS = Registry("tconorm")


@dataclass(frozen=True)
class TConorm(LearnableParams):
    """A validated T-conorm setting; build it with :func:`tconorm`.

    Its methods (``binary``, ``aggregate``, ...) take an ``ops`` namespace (``gendr.ops.numpy_ops``
    or a backend's) and same-shaped arrays of it (NumPy, torch on any device, Dr.Jit) with
    coverages in [0, 1], and return an array of that shape, dtype and device, differentiable in the
    inputs (and in a learnable parameter) where the family is (``.differentiable``).

    >>> import numpy as np, gendr
    >>> from gendr.ops import numpy_ops
    >>> t = gendr.tconorm("probabilistic")  # a ⊥ b = a + b − a·b
    >>> t, t.kind, t.is_tconorm
    (TConorm('probabilistic'), 'archimedean', True)
    >>> t.aggregate(numpy_ops, [np.array([0.5, 0.2]), np.array([0.5, 0.0])]).round(6)
    array([0.75, 0.2 ])
    """

    family: TConormFamily
    params: tuple[tuple[str, float], ...] = ()
    _owner_kind = "tconorm"

    @property
    def name(self) -> str:
        return self.family.name

    @property
    def kind(self) -> str:
        return self.family.kind

    @property
    def kwargs(self) -> dict[str, float]:
        return dict(self.params)

    @property
    def differentiable(self) -> bool:
        return self.kind != HARD_OR

    @property
    def is_tconorm(self) -> bool:
        """False for ``average`` (the mean over the faces), which is not a T-conorm."""
        return self.family.is_tconorm

    def odds_product_factor(self) -> float | None:
        """c where the generator is log(1 + c·x/(1 − x)) (see TConormFamily.odds_factor); None where it
        is not of that form or a parameter is learnable."""
        f = self.family.odds_factor
        return None if f is None or self.learnable else f(**self.kwargs)

    @property
    def streams(self) -> bool:
        """True when the n-ary aggregate is :meth:`from_sum` of a per-pixel sum of
        :meth:`pair_term` values (archimedean T-conorms and the mean)."""
        return self.kind in SUM_KINDS

    def label(self) -> str:
        if not self.params:
            return self.name
        return self.name + "(" + ",".join(f"{k}={short_number(v)}" for k, v in self.params) + ")"

    def __repr__(self) -> str:
        return f"TConorm({self.label()!r})"

    @quiet_numpy
    def binary(self, ops, a, b):
        """S(a, b), the paper's two-argument formula."""
        return self.family.binary(ops, a, b, **self.kwargs)

    @quiet_numpy
    def tnorm(self, ops, a, b):
        """The dual T-norm T(a, b) = 1 − S(1 − a, 1 − b) (De Morgan with the standard negation)."""
        return 1.0 - self.binary(ops, 1.0 - a, 1.0 - b)

    def _archimedean_only(self, what):
        if self.kind != ARCHIMEDEAN:
            raise ValueError(f"{self!r} has no {what}: only archimedean T-conorms have one (this is a "
                             f"{self.kind!r} aggregation)")

    @quiet_numpy
    def generator(self, ops, x, log1m_x=None):
        self._archimedean_only("additive generator")
        if log1m_x is None:
            log1m_x = ops.log1p(-x)
        return self.family.generator(ops, x, log1m_x, **self.kwargs)

    @quiet_numpy
    def odds_generator(self, ops, log_odds):
        """g(x) from log(x/(1 − x)) (families with ``odds_generator`` only; see TConormFamily)."""
        f = self.family.odds_generator
        if f is None:
            raise NotImplementedError(f"T-conorm {self.label()!r} has no generator in terms of the odds")
        return f(ops, log_odds, **self.kwargs)

    @quiet_numpy
    def generator_inverse(self, ops, s):
        self._archimedean_only("additive generator")
        return self.family.generator_inverse(ops, s, **self.kwargs)

    @property
    def generator_at_one(self) -> float:
        self._archimedean_only("additive generator")
        return self.family.generator_at_one(**self.kwargs)

    @quiet_numpy
    def aggregate(self, ops, ps, log1m_ps=None, n_faces=None):
        """The n-ary aggregate of a Python list of same-shaped arrays ``ps`` (elementwise).

        archimedean: g⁻¹(min(g(1), Σ g(p_t))) (``log1m_ps``: optional matching list of log(1 − p_t),
        entries may be None); max: the elementwise maximum; or: 1 where any p_t >= 1/2, else 0;
        mean: Σ p_t / n_faces, where ``n_faces`` (default ``len(ps)``) is the number of faces the
        mean runs over: faces not listed count as p = 0. ``n_faces`` is only accepted for the mean.
        """
        ps = list(ps)
        if not ps:
            raise ValueError(f"{self!r}.aggregate needs at least one array")
        if n_faces is not None and self.kind != MEAN:
            raise ValueError(f"{self!r}.aggregate takes n_faces only for the mean (it is not a T-conorm)")
        if self.kind == MEAN:
            n = len(ps) if n_faces is None else n_faces
            if isinstance(n, bool) or not isinstance(n, int) or n < len(ps):
                raise ValueError(f"n_faces={n!r} must be an integer >= the number of arrays ({len(ps)})")
            s = ps[0]
            for p in ps[1:]:
                s = s + p
            return self.from_sum(ops, s, n)
        if self.kind in (MAX, HARD_OR):
            m = ps[0]
            for p in ps[1:]:
                m = ops.maximum(m, p)
            return m if self.kind == MAX else _binarize(ops, m)
        log1m_ps = [None] * len(ps) if log1m_ps is None else list(log1m_ps)
        if len(log1m_ps) != len(ps):
            raise ValueError(f"aggregate got {len(ps)} arrays but {len(log1m_ps)} log1m values")
        s = None
        for p, l in zip(ps, log1m_ps):
            g = self.generator(ops, p, l)
            s = g if s is None else s + g
        return self.from_generator_sum(ops, s)

    @quiet_numpy
    def from_generator_sum(self, ops, s):
        """A = g⁻¹(min(g(1), s)) for a sum ``s`` of generator values (archimedean kinds only)."""
        g1 = self.generator_at_one
        if math.isfinite(g1):
            s = ops.minimum(s, ops.full_like(s, g1))
        return self.generator_inverse(ops, s)

    @quiet_numpy
    def pair_term(self, ops, p, log1m_p=None):
        """The per-(pixel, face) term that the streaming kinds sum: g(p) (archimedean; ``log1m_p`` =
        log(1 − p) as for :meth:`generator`), p itself (mean)."""
        if self.kind == MEAN:
            return p
        if self.kind != ARCHIMEDEAN:
            raise ValueError(f"{self!r} is a {self.kind}-reduction, not a sum of per-pair terms")
        return self.generator(ops, p, log1m_p)

    @quiet_numpy
    def from_sum(self, ops, s, n_faces: int):
        """The aggregate from a per-pixel sum ``s`` of :meth:`pair_term` values over the faces.

        archimedean: g⁻¹(min(g(1), s)) (``n_faces`` unused); mean: s / n_faces, ``n_faces`` = the
        number of faces of the mesh (F, a Python int; 0 faces gives 0)."""
        if self.kind == MEAN:
            return s * (1.0 / max(int(n_faces), 1))
        if self.kind != ARCHIMEDEAN:
            raise ValueError(f"{self!r} is a {self.kind}-reduction, not a sum of per-pair terms")
        return self.from_generator_sum(ops, s)


def tconorm(name, **params) -> TConorm:
    """Build a T-conorm spec: ``gendr.tconorm("yager", p=2)``.

    ``gendr.tconorm("average")`` builds the one aggregation that is not a T-conorm (the mean over
    the faces; ``.is_tconorm`` is False): it renders like the others but is not in the paper's grid.

    A parameter may be a scalar torch tensor (or Dr.Jit array) that requires grad: it is then
    *learnable* (``.learnable``), both backends return ∂/∂p, and its value is re-checked at every
    render (an optimizer step may leave the domain: :class:`~gendr.errors.ParameterError`). Keep it
    in the domain by parametrizing, e.g. ``p = softplus(raw)`` for p > 0.

    ``name`` may also be a :class:`TConorm` (returned unchanged). Raises
    :class:`~gendr.errors.UnknownNameError` / :class:`~gendr.errors.ParameterError`.

    Args: ``name`` of :data:`TCONORMS` (``sorted(gendr.TCONORMS)``); ``**params``: the family's
    parameters (Python floats, or 0-d tensors requiring grad: learnable, on any device).
    Returns a frozen :class:`TConorm`.

    >>> import torch, gendr
    >>> gendr.tconorm("yager", p=2)
    TConorm('yager(p=2)')
    >>> p = torch.tensor(2.0, requires_grad=True)
    >>> sorted(gendr.tconorm("yager", p=p).learnable)
    ['p']
    >>> gendr.tconorm("yager", p=-1.0)
    Traceback (most recent call last):
    ...
    gendr.errors.ParameterError: tconorm 'yager' parameter p=-1.0 ...
    """
    if isinstance(name, TConorm):
        if params:
            raise ParameterError("parameters cannot be combined with an existing TConorm object")
        return name
    fam = TCONORMS.lookup(name)
    values = validate_params(f"tconorm {name!r}", fam.params, params, learnable=True)
    return TConorm(fam, tuple((p.name, values[p.name]) for p in fam.params))


# ------------------------------------------------------------------------------------------------
# Numerical helpers (ops-generic; constants are Python floats so float32 stays float32).
# ------------------------------------------------------------------------------------------------

_LOG_HALF = math.log(0.5)


def _log(ops, p):
    """log of a parameter (a float, or a :class:`Learnable`: then differentiable)."""
    return ops.log(p.array) if isinstance(p, Learnable) else math.log(p)


def _recip(p):
    """1/p keeping learnability."""
    return Learnable(1.0 / float(p), 1.0 / p.array) if isinstance(p, Learnable) else 1.0 / p


def _pow0(ops, x, e):
    """x**e for x >= 0 and a Python float e > 0; 0 at x = 0 with a finite gradient there.

    e >= 1: the true derivative at 0 (e·0^(e−1): 1 for e = 1, else 0). e < 1: the true derivative at
    0 is +inf; this reports 0 (double where, so no inf/NaN reaches autograd). A :class:`Learnable`
    e: x^e with its e-derivative x^e·log x (0 at x = 0: both sides fed safe values), same x-derivatives.
    """
    if isinstance(e, Learnable):
        pos = x > 0.0
        y = ops.where(pos, ops.power(ops.where(pos, x, 1.0), e.array), 0.0)
        return y + ops.where(pos, 0.0, x) if e == 1.0 else y  # (x = 0 there: slope 1 for e = 1)
    if e == 1.0:
        return x
    if e > 1.0:
        return ops.power(ops.clamp(x, 0.0, None), e)
    pos = x > 0.0
    return ops.where(pos, ops.power(ops.where(pos, x, 1.0), e), 0.0)


def _inf_guard(ops, f, args, safe, p=None):
    """f(*args) where that is finite, else +inf with a zero gradient.

    The arguments are replaced by the finite ``safe`` values where f would be inf/NaN before f is
    evaluated again, so no 0·inf = NaN reaches autograd (the double-where trick); without a
    gradient (e.g. Dr.Jit's forward loops: no argument needs one and f reads no learnable ``p``)
    f is evaluated once, to the same values.
    """
    value = f(*args)
    ok = value < math.inf
    if not (ops.needs_grad(*args) or isinstance(p, Learnable)):
        return ops.where(ok, value, math.inf)
    safe_args = [ops.where(ok, a, v) for a, v in zip(args, safe)]
    return ops.where(ok, f(*safe_args), math.inf)


def _split_half(ops, x, l, lower, upper, at=0.5, p=None):
    """``lower(x, l)`` for x < ``at``, ``upper(x, l)`` for x >= ``at`` (l = log(1 − x), 0 < at < 1).

    Each branch only ever sees inputs from its own side (the other side is replaced by a safe point),
    so a branch that would be inf/NaN outside its range cannot poison the gradient. An
    ``ops.branch`` (a Dr.Jit packet whose lanes are all on one side skips the other), unless the
    sides read a learnable parameter ``p`` through their closures: then a where of both, since a
    Dr.Jit branch would take it for a constant.
    """
    lo = x < at
    xa, la = ops.where(lo, x, 0.0), ops.where(lo, l, 0.0)
    xb, lb = ops.where(lo, at, x), ops.where(lo, math.log1p(-at), l)
    if isinstance(p, Learnable):
        return ops.where(lo, lower(xa, la), upper(xb, lb))
    return ops.branch(lo, lambda xa, la, xb, lb: lower(xa, la), lambda xa, la, xb, lb: upper(xb, lb), xa, la, xb, lb)


def _split_at(ops, s, at, lower, upper):
    """``lower(s)`` for s < ``at``, ``upper(s)`` for s >= ``at`` (at > 0), each fed safe inputs only
    (0 and ``at``)."""
    lo = s < at
    return ops.where(lo, lower(ops.where(lo, s, 0.0)), upper(ops.where(lo, at, s)))


def _log_expm1_ratio(ops, z):
    """log(expm1(z) / z), smooth through z = 0 (series z/2 + z²/24 there).

    frank calls it with z = log(p)·(1 − x) <= log(p) − 1, so expm1(z) stays finite wherever the
    constant p itself is representable in the working dtype.
    """
    small = ops.abs(z) < 1e-4
    zs = ops.where(small, 1.0, z)
    return ops.where(small, z * (0.5 + z / 24.0), ops.log(ops.expm1(zs) / zs))


#: below this argument _log1p_ratio and _expm1_ratio use their series (truncation < 1e-18 relative;
#: the closed forms' derivatives lose ~eps/z to cancellation just above it: 1e-14 in float64)
_SERIES_AT = 0.01


def _log1p_ratio(ops, z):
    """log1p(z)/z for z >= 0, smooth through z = 0 (Taylor series 1 − z/2 + z²/3 − … there)."""
    small = z < _SERIES_AT
    zs, zb = ops.where(small, z, 0.0), ops.where(small, 1.0, z)
    series = 0.0 * zs
    for k in range(8, -1, -1):
        series = (-1.0) ** k / (k + 1) + zs * series
    return ops.where(small, series, ops.log1p(zb) / zb)


def _expm1_ratio(ops, y):
    """expm1(y)/y for y >= 0, smooth through y = 0 (Taylor series 1 + y/2 + y²/6 + … there)."""
    small = y < _SERIES_AT
    ys, yb = ops.where(small, y, 0.0), ops.where(small, 1.0, y)
    series = 0.0 * ys
    for k in range(6, -1, -1):
        series = 1.0 / math.factorial(k + 1) + ys * series
    return ops.where(small, series, ops.expm1(yb) / yb)


def _binarize(ops, m):
    return ops.where(m >= 0.5, ops.full_like(m, 1.0), ops.full_like(m, 0.0))


def _strict(**_):
    return math.inf


_P = "p"


# ------------------------------------------------------------------------------------------------
# The families. One entry each.
# ------------------------------------------------------------------------------------------------

TCONORMS.add(TConormFamily(
    "probabilistic", ARCHIMEDEAN,
    binary=lambda ops, a, b: a + b - a * b,
    generator=lambda ops, x, log1m_x: -log1m_x,
    generator_inverse=lambda ops, s: -ops.expm1(-s),
    generator_at_one=lambda: math.inf,
    odds_factor=lambda: 1.0,
    doc="S(a, b) = a + b − ab; generator −log(1 − x). SoftRas' and DIB-R's aggregation.",
))


TCONORMS.add(TConormFamily(
    "max", MAX,
    binary=lambda ops, a, b: ops.maximum(a, b),
    doc="S(a, b) = max(a, b), the smallest T-conorm (dual: min). Not archimedean: the n-ary aggregate "
        "is a max-reduction; its gradient flows to the arg-max only.",
))


TCONORMS.add(TConormFamily(
    "average", MEAN,
    binary=lambda ops, a, b: 0.5 * (a + b),
    doc="A = (1/F)·Σ_t p_t, the mean coverage over all F faces of the mesh (SoftRas' alpha 'sum'). "
        "Not a T-conorm. A face that does not reach the pixel (culled: coverage < eps, or beyond the "
        "cut-off) counts as p = 0 and still counts in F. binary(a, b) = (a + b)/2 is the mean of two "
        "faces. Averaging, not a fuzzy or: 0 is not neutral, 1 not absorbing, not associative, "
        "min <= A <= max; see docs/tconorms.md.",
    is_tconorm=False,
))


TCONORMS.add(TConormFamily(
    "or", HARD_OR,
    binary=lambda ops, a, b: _binarize(ops, ops.maximum(a, b)),
    doc="The hard logical or, the non-differentiable limit: on crisp {0, 1} inputs it is logical or. "
        "We extend it to soft inputs by binarizing at 1/2, then or-ing: S(a, b) = 1 if max(a, b) >= 1/2 "
        "else 0 (the n-ary aggregate is 1 where any p_t >= 1/2). Piecewise constant: zero gradient.",
))


# --- einstein ------------------------------------------------------------------------------------
TCONORMS.add(TConormFamily(
    "einstein", ARCHIMEDEAN,
    binary=lambda ops, a, b: (a + b) / (1.0 + a * b),
    generator=lambda ops, x, log1m_x: ops.log1p(x) - log1m_x,
    generator_inverse=lambda ops, s: ops.tanh(0.5 * s),
    generator_at_one=_strict,
    odds_factor=lambda: 2.0,
    doc="Einstein sum S(a, b) = (a + b)/(1 + ab) (= hamacher p = 2); generator 2·atanh(x) = "
        "log(1 + x) − log(1 − x), inverse tanh(s/2).",
))


# --- hamacher (p >= 0) ---------------------------------------------------------------------------
def _hamacher_binary(ops, a, b, p):
    # (a + b + (p − 2)ab) / (1 + (p − 1)ab), numerator and denominator written as sums of
    # nonnegative terms (no cancellation near 0 or near 1, and numerator <= denominator in floats):
    #   a + b + (p − 2)ab = b(1 − a) + a(1 − b) + p·ab,   1 + (p − 1)ab = (1 − a) + a(1 − b) + p·ab
    def s(a, b):
        pab = _a(p) * a * b
        return (b * (1.0 - a) + a * (1.0 - b) + pab) / ((1.0 - a) + a * (1.0 - b) + pab)
    if p == 0.0:  # 0/0 at a = b = 1, where the limit (and the boundary law) is 1
        ok = a * b < 1.0
        return ops.where(ok, s(ops.where(ok, a, 0.0), ops.where(ok, b, 0.0)), 1.0)
    return s(a, b)


def _hamacher_generator(ops, x, l, p):
    # g = log((p + (1 − p)(1 − x))/(1 − x)) = log1p(p·x/(1 − x))   (p > 0);   x/(1 − x)   (p = 0)
    if isinstance(p, Learnable):
        return _hamacher_scaled_generator(ops, x, l, p)
    if p == 0.0:
        return _inf_guard(ops, lambda x, l: x * ops.exp(-l), (x, l), (0.5, _LOG_HALF))
    log_p = _log(ops, p)
    return _split_half(
        ops, x, l,
        lambda x, l: ops.log1p(_a(p) * x * ops.exp(-l)),            # x < 1/2: exp(−l) <= 2
        lambda x, l: ops.softplus(log_p + ops.log(x) - l), p=p)  # x >= 1/2: log-space, no overflow


def _hamacher_inverse(ops, s, p):
    if isinstance(p, Learnable):
        return _hamacher_scaled_inverse(ops, s, p.array)
    if p == 0.0:  # s/(1 + s), written as 1 − 1/(1 + s) for large s (no inf/inf)
        return _split_at(ops, s, 1.0, lambda s: s / (1.0 + s), lambda s: 1.0 - 1.0 / (1.0 + s))
    # x = expm1(s)/(expm1(s) + p) = w/(w + p·u), w = 1 − e^−s, u = e^−s: denominator >= min(1, p)
    w, u = -ops.expm1(-s), ops.exp(-s)
    return w / (w + _a(p) * u)


# A learnable p needs ∂/∂p through p = 0, where the generator above switches form (its p = 0 branch
# has no p in it: ∂/∂p was 0 there, and inaccurate for tiny p). g/p is a generator of the same
# T-conorm and is smooth in p through 0: log1p(p·o)/p → o (o = x/(1 − x), the odds), with inverse
# r/(1 + r), r = expm1(p·s)/p → s. The float p keeps the unscaled form: the backends' odds-product
# loops (TConormFamily.odds_factor) sum its values.
def _hamacher_scaled_generator(ops, x, l, p):
    P = p.array

    def lower(x, l):  # x < 1/2: o <= 1
        o = x * ops.exp(-l)
        return o * _log1p_ratio(ops, P * o)

    def upper(x, l):  # x >= 1/2: o·h(p·o) while p·o < 1, log-space above (o itself may overflow)
        o = x * ops.exp(-l)
        big = P * o >= 1.0  # (p = 0 and o = inf: NaN, False; the inf guard takes that case)
        o_small = ops.where(big, 1.0, o)
        P_big, x_big, l_big = ops.where(big, P, 1.0), ops.where(big, x, 0.5), ops.where(big, l, _LOG_HALF)
        return ops.where(big, ops.softplus(ops.log(P_big) + ops.log(x_big) - l_big) / P_big,
                         o_small * _log1p_ratio(ops, P * o_small))

    return _split_half(ops, x, l, lower,
                       lambda x, l: _inf_guard(ops, upper, (x, l), (0.5, _LOG_HALF), p=p), p=p)


def _hamacher_scaled_inverse(ops, s, P):
    finite = s < math.inf
    s = ops.where(finite, s, 0.0)
    y = P * s
    small = y < _SERIES_AT
    r = ops.where(small, s, 0.0) * _expm1_ratio(ops, ops.where(small, y, 0.0))
    x_small = _split_at(ops, r, 1.0, lambda r: r / (1.0 + r), lambda r: 1.0 - 1.0 / (1.0 + r))
    # y >= 0.01 (so p > 0): x = expm1(y)/(expm1(y) + p) = 1/(1 + p·u/w), w = 1 − e^−y, u = e^−y.
    # (Not w/(w + p·u): its autograd ∂/∂w is 1/b − w/b² with b ≈ w, which cancels, and ∂y/∂p = s is
    # huge: 2e-4 relative error in ∂x/∂p at p = 1e-12, s = 7e11.)
    y_big, P_big = ops.where(small, 1.0, y), ops.where(small, 1.0, P)
    w, u = -ops.expm1(-y_big), ops.exp(-y_big)
    return ops.where(finite, ops.where(small, x_small, 1.0 / (1.0 + P_big * u / w)), 1.0)


TCONORMS.add(TConormFamily(
    "hamacher", ARCHIMEDEAN,
    binary=_hamacher_binary,
    params=(Param(_P, NONNEGATIVE, doc="p = 0: Hamacher sum; p = 1: probabilistic; p = 2: einstein"),),
    generator=_hamacher_generator,
    generator_inverse=_hamacher_inverse,
    generator_at_one=_strict,
    odds_factor=lambda p: float(p) if p > 0.0 else None,
    doc="S(a, b) = (a + b + (p − 2)ab)/(1 + (p − 1)ab), p >= 0; generator log((p + (1 − p)(1 − x))/(1 − x)) "
        "= log1p(p·x/(1 − x)) for p > 0, x/(1 − x) for p = 0; inverse expm1(s)/(expm1(s) + p) "
        "(p > 0), s/(1 + s) (p = 0).",
))


# --- frank (p > 0, p != 1) ----------------------------------------------------------------------
def _frank_binary(ops, a, b, p):
    q, k = _log(ops, p), _a(p) - 1.0
    return 1.0 - ops.log1p(ops.expm1(q * (1.0 - a)) * ops.expm1(q * (1.0 - b)) / k) / q


def _frank_generator(ops, x, l, p):
    # g = −log((p^(1−x) − 1)/(p − 1)) with q = log p, k = p − 1 (q/k > 0 on the whole domain).
    # Below the split x_s (chosen so that neither form cancels, also for extreme p):
    #   p > 1:  g = −log1p(p·expm1(−q·x)/k)                           x_s = min(1/2, 1/q)
    #   p < 1:  g = −log1p(−p^(1−x)·(1 − p^x)/(1 − p))                 x_s = max(1/2, 1 + 1/q)
    #           (= the same quantity; the product form cannot overflow for tiny p)
    # Above it, with y = 1 − x = exp(l) and z = q·y (accurate as x → 1; +inf with finite gradient
    # at l = −inf):  g = −l − log(q/k) − log(expm1(z)/z)
    # (the split x_s is a constant of p's float value: both sides are the same function of p)
    qf = math.log(p)
    q, k = _log(ops, p), _a(p) - 1.0
    c = ops.log(q / k) if isinstance(p, Learnable) else math.log(q / k)
    if p > 1.0:
        at = min(0.5, 1.0 / qf)
        lower = lambda x, l: -ops.log1p((_a(p) / k) * ops.expm1(-q * x))  # noqa: E731
    else:
        at = max(0.5, 1.0 + 1.0 / qf)
        lower = lambda x, l: -ops.log1p(ops.exp(q * (1.0 - x)) * ops.expm1(q * x) / (1.0 - _a(p)))  # noqa: E731
    return _split_half(ops, x, l, lower, lambda x, l: -l - c - _log_expm1_ratio(ops, q * ops.exp(l)), at, p)


def _frank_inverse(ops, s, p):
    # Solve (p^(1−x) − 1)/(p − 1) = e^−s. With w = 1 − e^−s (= −expm1(−s)), u = e^−s:
    #   small s:  x = −log1p((1/p − 1)·w) / log p      exactly 0 at s = 0, accurate for tiny s
    #   large s:  x = 1 − log1p((p − 1)·u) / log p     exactly 1 at s = inf, x <= 1
    # The switch keeps each log1p argument away from −1 (>= −1/2), also for extreme p; each form
    # only sees its own side of the switch (for extreme p the other side would reach log1p(−1)).
    q = _log(ops, p)
    s_half = math.log1p(math.sqrt(p))  # g(1/2) = log(√p + 1)
    if p > 2.0:    # small form's argument −(1 − 1/p)·w must stay >= −1/2
        s_switch = min(s_half, -math.log1p(-0.5 * p / (p - 1.0)))
    elif p < 0.5:  # large form's argument −(1 − p)·u must stay >= −1/2
        s_switch = max(s_half, math.log(2.0 * (1.0 - p)))
    else:
        s_switch = s_half
    return _split_at(ops, s, s_switch,
                     # (1 − p)/p, not 1/p − 1: that cancels near p = 1 (rel. error ~1e-16/|p − 1|)
                     lambda s: -ops.log1p((1.0 - _a(p)) / _a(p) * -ops.expm1(-s)) / q,
                     lambda s: 1.0 - ops.log1p((_a(p) - 1.0) * ops.exp(-s)) / q)


TCONORMS.add(TConormFamily(
    "frank", ARCHIMEDEAN,
    binary=_frank_binary,
    params=(Param(_P, POSITIVE_NOT_ONE, doc="p → 1: probabilistic; p → 0: max; p → ∞: Łukasiewicz"),),
    generator=_frank_generator,
    generator_inverse=_frank_inverse,
    generator_at_one=_strict,
    doc="S(a, b) = 1 − log_p(1 + (p^(1−a) − 1)(p^(1−b) − 1)/(p − 1)), p > 0, p != 1; generator "
        "−log((p^(1−x) − 1)/(p − 1)); inverse 1 − log_p(1 + (p − 1)e^−s).",
))


# --- yager (p > 0), nilpotent -------------------------------------------------------------------
TCONORMS.add(TConormFamily(
    "yager", ARCHIMEDEAN,
    binary=lambda ops, a, b, p: ops.clamp(_pow0(ops, _pow0(ops, a, p) + _pow0(ops, b, p), _recip(p)), None, 1.0),
    params=(Param(_P, POSITIVE, doc="p = 1: bounded sum min(1, a + b); p → ∞: max"),),
    generator=lambda ops, x, log1m_x, p: _pow0(ops, x, p),
    generator_inverse=lambda ops, s, p: _pow0(ops, s, _recip(p)),
    generator_at_one=lambda p: 1.0,
    doc="S(a, b) = min(1, (a^p + b^p)^(1/p)), p > 0; generator x^p, nilpotent (g(1) = 1: the aggregate "
        "reaches 1 exactly once Σ p_t^p >= 1); inverse s^(1/p).",
))


# --- aczel_alsina (p > 0) -----------------------------------------------------------------------
def _aczel_binary(ops, a, b, p):
    t = _pow0(ops, -ops.log1p(-a), p) + _pow0(ops, -ops.log1p(-b), p)
    return -ops.expm1(-_pow0(ops, t, _recip(p)))


TCONORMS.add(TConormFamily(
    "aczel_alsina", ARCHIMEDEAN,
    binary=_aczel_binary,
    params=(Param(_P, POSITIVE, doc="p = 1: probabilistic; p → ∞: max"),),
    generator=lambda ops, x, log1m_x, p: _inf_guard(ops, lambda l: _pow0(ops, -l, p), (log1m_x,), (_LOG_HALF,), p),
    generator_inverse=lambda ops, s, p: -ops.expm1(
        -_inf_guard(ops, lambda s: _pow0(ops, s, _recip(p)), (s,), (1.0,), p)),
    generator_at_one=_strict,
    doc="S(a, b) = 1 − exp(−((−log(1 − a))^p + (−log(1 − b))^p)^(1/p)), p > 0; generator (−log(1 − x))^p; "
        "inverse 1 − exp(−s^(1/p)).",
))


# --- dombi (p > 0) -------------------------------------------------------------------------------
def _dombi_binary(ops, a, b, p):
    r = _pow0(ops, _pow0(ops, a / (1.0 - a), p) + _pow0(ops, b / (1.0 - b), p), _recip(p))
    return 1.0 - 1.0 / (1.0 + r)


def _dombi_generator(ops, x, l, p):
    # g = (x/(1 − x))^p: x^p·(1 − x)^−p below 1/2, exp(p(log x − log(1 − x))) above (guarded overflow)
    return _split_half(
        ops, x, l,
        lambda x, l: _pow0(ops, x, p) * ops.exp(-_a(p) * l),
        lambda x, l: _inf_guard(ops, lambda x, l: ops.exp(_a(p) * (ops.log(x) - l)), (x, l), (0.5, _LOG_HALF), p),
        p=p)


def _dombi_inverse(ops, s, p):
    # x = r/(1 + r), r = s^(1/p); for s >= 1 as sigmoid(log(s)/p) (s = inf → 1, no inf/inf)
    def lower(s):
        r = _pow0(ops, s, _recip(p))
        return r / (1.0 + r)
    # (at s = inf the guard keeps log(s)/p's p-gradient, inf·0, from making a NaN: the result is 1 for any p)
    return _split_at(ops, s, 1.0, lower,
                     lambda s: ops.sigmoid(_inf_guard(ops, lambda s: ops.log(s) / _a(p), (s,), (1.0,), p)))


TCONORMS.add(TConormFamily(
    "dombi", ARCHIMEDEAN,
    binary=_dombi_binary,
    params=(Param(_P, POSITIVE, doc="p → ∞: max"),),
    generator=_dombi_generator,
    generator_inverse=_dombi_inverse,
    odds_generator=lambda ops, lo, p: ops.exp(_a(p) * lo),
    generator_at_one=_strict,
    doc="S(a, b) = 1 − 1/(1 + ((a/(1 − a))^p + (b/(1 − b))^p)^(1/p)), p > 0; generator (x/(1 − x))^p; "
        "inverse s^(1/p)/(1 + s^(1/p)).",
))


# --- schweizer_sklar (p < 0) ----------------------------------------------------------------------
def _schweizer_sklar_binary(ops, a, b, p):
    # 1 − ((1 − a)^p + (1 − b)^p − 1)^(1/p), with (1 − a)^p − 1 = expm1(p·log1p(−a)) (exact near 0)
    t = ops.expm1(_a(p) * ops.log1p(-a)) + ops.expm1(_a(p) * ops.log1p(-b))
    return -ops.expm1(ops.log1p(t) / _a(p))


TCONORMS.add(TConormFamily(
    "schweizer_sklar", ARCHIMEDEAN,
    binary=_schweizer_sklar_binary,
    params=(Param(_P, NEGATIVE, doc="p = −1: hamacher p = 0; p → 0: probabilistic; p → −∞: max"),),
    generator=lambda ops, x, log1m_x, p: _inf_guard(ops, lambda l: ops.expm1(_a(p) * l), (log1m_x,), (_LOG_HALF,), p),
    # guarded as dombi's inverse: s = inf (a pixel covered with p = 1) gives 1 and a zero p-gradient
    generator_inverse=lambda ops, s, p: -ops.expm1(-_inf_guard(ops, lambda s: -ops.log1p(s) / _a(p), (s,), (0.0,), p)),
    generator_at_one=_strict,
    doc="S(a, b) = 1 − ((1 − a)^p + (1 − b)^p − 1)^(1/p), p < 0; generator (1 − x)^p − 1 = "
        "expm1(p·log(1 − x)); inverse 1 − (1 + s)^(1/p).",
))
