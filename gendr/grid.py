"""The paper's grid of 1,242 instances: 23 distribution settings × {plain, squared} × 27 aggregations.

The parameter values are ours (the paper does not fix every one); they are data here, documented
in docs/grid.md, and every instance constructs a renderer that renders (tests/test_grid.py).
"""
from __future__ import annotations

from dataclasses import dataclass

from .distributions import Distribution, distribution
from .tconorms import TConorm, tconorm

#: (name, params, reversed): 9 symmetric, 2 Gumbel, and the one-sided families plain and reversed
DISTRIBUTION_SETTINGS = (
    ("uniform", {}, False), ("cubic_hermite", {}, False), ("wigner_semicircle", {}, False),
    ("gaussian", {}, False), ("laplace", {}, False), ("logistic", {}, False),
    ("hyperbolic_secant", {}, False), ("cauchy", {}, False), ("reciprocal", {}, False),
    ("gumbel_max", {}, False), ("gumbel_min", {}, False),
    ("exponential", {}, False), ("exponential", {}, True),
    ("gamma", {"shape": 0.5}, False), ("gamma", {"shape": 0.5}, True),
    ("gamma", {"shape": 2.0}, False), ("gamma", {"shape": 2.0}, True),
    ("gamma", {"shape": 3.0}, False), ("gamma", {"shape": 3.0}, True),
    ("gamma", {"shape": 5.0}, False), ("gamma", {"shape": 5.0}, True),
    ("levy", {}, False), ("levy", {}, True),
)

#: (name, params): max, probabilistic, einstein, and 6 parametric families × 4 values
TCONORM_SETTINGS = (
    ("max", {}), ("probabilistic", {}), ("einstein", {}),
    *(("hamacher", {"p": p}) for p in (0.0, 0.5, 4.0, 10.0)),
    *(("frank", {"p": p}) for p in (0.01, 0.1, 10.0, 100.0)),
    *(("yager", {"p": p}) for p in (0.5, 1.0, 2.0, 4.0)),
    *(("aczel_alsina", {"p": p}) for p in (0.25, 0.5, 2.0, 4.0)),
    *(("dombi", {"p": p}) for p in (0.5, 1.0, 2.0, 4.0)),
    *(("schweizer_sklar", {"p": p}) for p in (-4.0, -2.0, -1.0, -0.5)),
)


@dataclass(frozen=True)
class Instance:
    """One renderer instance of the grid: ``Renderer(instance.distribution, instance.tconorm, ...)``.

    Attributes: ``index`` (int, position in :func:`paper_grid`), ``distribution``
    (:class:`~gendr.distributions.Distribution`), ``tconorm`` (:class:`~gendr.tconorms.TConorm`);
    ``name`` is ``"<distribution label>|<tconorm label>"``.

    >>> import gendr
    >>> inst = gendr.paper_grid()[1]
    >>> inst.index, inst.name
    (1, 'uniform|probabilistic')
    >>> gendr.Renderer(inst.distribution, inst.tconorm, image_size=8, backend="torch")
    Renderer(uniform, probabilistic, tau=0.01, image_size=(8, 8), backend='torch', eps=0.0001, blend='softmax')
    """

    index: int
    distribution: Distribution
    tconorm: TConorm

    @property
    def name(self) -> str:
        return f"{self.distribution.label()}|{self.tconorm.label()}"


def paper_grid() -> list[Instance]:
    """All 1,242 instances, distribution-major: (distribution setting, plain/squared, aggregation).

    Returns a new list of :class:`Instance` (plain Python specs; no arrays).

    >>> import gendr
    >>> grid = gendr.paper_grid()
    >>> len(grid), grid[0].name, grid[-1].name
    (1242, 'uniform|max', 'levy+rev+sq|schweizer_sklar(p=-0.5)')
    """
    out = []
    for name, params, rev in DISTRIBUTION_SETTINGS:
        for squared in (False, True):
            d = distribution(name, reversed=rev, squared=squared, **params)
            for tname, tparams in TCONORM_SETTINGS:
                out.append(Instance(len(out), d, tconorm(tname, **tparams)))
    return out
