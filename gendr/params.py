"""Declared parameters with constraints, validated once with messages that name the value."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping

from .errors import ParameterError, UnknownNameError


@dataclass(frozen=True)
class Constraint:
    description: str  # e.g. "> 0"
    check: Callable[[float], bool]


REAL = Constraint("a finite real number", lambda v: math.isfinite(v))
POSITIVE = Constraint("> 0", lambda v: math.isfinite(v) and v > 0)
NONNEGATIVE = Constraint(">= 0", lambda v: math.isfinite(v) and v >= 0)
NEGATIVE = Constraint("< 0", lambda v: math.isfinite(v) and v < 0)
POSITIVE_NOT_ONE = Constraint("> 0 and != 1", lambda v: math.isfinite(v) and v > 0 and v != 1)


@dataclass(frozen=True)
class Param:
    name: str
    constraint: Constraint
    default: float | None = None
    doc: str = ""


def validate_params(owner: str, declared: tuple[Param, ...], given: Mapping[str, object]) -> dict[str, float]:
    """Return ``{name: float}`` for every declared parameter, or raise :class:`ParameterError`.

    ``owner`` names the family in messages, e.g. ``"tconorm 'yager'"``.
    """
    names = [p.name for p in declared]
    for key in given:
        if key not in names:
            accepted = ", ".join(names) if names else "no parameters"
            raise ParameterError(f"{owner} got unexpected parameter {key!r}; it accepts {accepted}")
    out = {}
    for p in declared:
        if p.name in given and given[p.name] is not None:
            raw = given[p.name]
        elif p.default is not None:
            raw = p.default
        else:
            raise ParameterError(f"{owner} needs parameter {p.name!r} ({p.constraint.description})")
        try:
            value = float(raw)
        except (TypeError, ValueError):
            raise ParameterError(f"{owner} parameter {p.name}={raw!r} must be a number {p.constraint.description}") from None
        if not p.constraint.check(value):
            raise ParameterError(f"{owner} parameter {p.name}={raw!r} is out of domain: expected {p.constraint.description}")
        out[p.name] = value
    return out


class Registry(dict):
    """Name -> entry, raising :class:`UnknownNameError` listing the valid names."""

    def __init__(self, kind: str):
        super().__init__()
        self.kind = kind

    def add(self, entry):
        if entry.name in self:
            raise ValueError(f"{self.kind} {entry.name!r} registered twice")
        self[entry.name] = entry
        return entry

    def lookup(self, name):
        if not isinstance(name, str) or name not in self:
            raise UnknownNameError(self.kind, name, sorted(self))
        return self[name]
