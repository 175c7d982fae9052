"""T-conorms that aggregate the soft coverage of all faces at a pixel.

Each family is ONE entry in :data:`TCONORMS`. Every family except ``max`` and the hard ``or`` is a
continuous Archimedean T-conorm with an additive generator g (increasing, g(0) = 0), so the n-ary
aggregate over any number of faces is (DESIGN.md §4)

    A = g⁻¹( min( g(1), Σ_t g(p_t) ) ),      ∂A/∂p_k = g'(p_k) / g'(A),

exact, order-independent and a plain streaming sum. ``binary`` holds the paper's two-argument
formula; tests check that the generator form reproduces it.

Generators take ``(ops, x, log1m_x, **params)`` where ``log1m_x`` = log(1 − x) supplied accurately by
the distribution (−log(1 − p) loses everything in float32 as p → 1).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from .params import Param, Registry, validate_params
from .errors import ParameterError

ARCHIMEDEAN, MAX, HARD_OR = "archimedean", "max", "or"


@dataclass(frozen=True)
class TConormFamily:
    """One T-conorm family. ``kind`` is ``"archimedean"``, ``"max"`` or ``"or"``."""

    name: str
    kind: str
    binary: Callable  # (ops, a, b, **params) -> S(a, b), the paper's formula
    params: tuple[Param, ...] = ()
    generator: Callable | None = None  # (ops, x, log1m_x, **params) -> g(x)
    generator_inverse: Callable | None = None  # (ops, s, **params) -> x, for 0 <= s <= g(1)
    generator_at_one: Callable | None = None  # (**params) -> g(1) as a Python float (inf: strict)
    doc: str = ""


TCONORMS = Registry("tconorm")


@dataclass(frozen=True)
class TConorm:
    """A validated T-conorm setting; build it with :func:`tconorm`."""

    family: TConormFamily
    params: tuple[tuple[str, float], ...] = ()

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

    def label(self) -> str:
        if not self.params:
            return self.name
        return self.name + "(" + ",".join(f"{k}={v:g}" for k, v in self.params) + ")"

    def binary(self, ops, a, b):
        """S(a, b), the paper's two-argument formula."""
        return self.family.binary(ops, a, b, **self.kwargs)

    def tnorm(self, ops, a, b):
        """The dual T-norm T(a, b) = 1 − S(1 − a, 1 − b) (De Morgan with the standard negation)."""
        return 1.0 - self.binary(ops, 1.0 - a, 1.0 - b)

    def generator(self, ops, x, log1m_x=None):
        if log1m_x is None:
            log1m_x = ops.log1p(-x)
        return self.family.generator(ops, x, log1m_x, **self.kwargs)

    def generator_inverse(self, ops, s):
        return self.family.generator_inverse(ops, s, **self.kwargs)

    @property
    def generator_at_one(self) -> float:
        return self.family.generator_at_one(**self.kwargs)

    def from_generator_sum(self, ops, s):
        """A = g⁻¹(min(g(1), s)) for a sum ``s`` of generator values (archimedean kinds only)."""
        g1 = self.generator_at_one
        if math.isfinite(g1):
            s = ops.minimum(s, ops.full_like(s, g1))
        return self.generator_inverse(ops, s)


def tconorm(name, **params) -> TConorm:
    """Build a T-conorm spec: ``gendr.tconorm("yager", p=2)``.

    ``name`` may also be a :class:`TConorm` (returned unchanged). Raises
    :class:`~gendr.errors.UnknownNameError` / :class:`~gendr.errors.ParameterError`.
    """
    if isinstance(name, TConorm):
        if params:
            raise ParameterError("parameters cannot be combined with an existing TConorm object")
        return name
    fam = TCONORMS.lookup(name)
    values = validate_params(f"tconorm {name!r}", fam.params, params)
    return TConorm(fam, tuple((p.name, values[p.name]) for p in fam.params))


# ------------------------------------------------------------------------------------------------
# The families. One entry each.
# ------------------------------------------------------------------------------------------------

TCONORMS.add(TConormFamily(
    "probabilistic", ARCHIMEDEAN,
    binary=lambda ops, a, b: a + b - a * b,
    generator=lambda ops, x, log1m_x: -log1m_x,
    generator_inverse=lambda ops, s: -ops.expm1(-s),
    generator_at_one=lambda: math.inf,
    doc="S(a, b) = a + b − ab; generator −log(1 − x). SoftRas' and DIB-R's aggregation.",
))
