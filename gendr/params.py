"""Declared parameters with constraints, validated once with messages that name the value."""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, replace
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


class Learnable(float):
    """A parameter value that is also a backend array: a *learnable* parameter.

    It is the array's value as a Python float (structure decisions in the spec formulas, labels and
    domain checks read it as a float), and carries the array itself in :attr:`array`: the formulas
    that support learnable parameters do their arithmetic with :func:`array_of` (so gradients reach
    the array). Arithmetic on the float itself (``p - 1.0``) is a plain float, without gradient.
    ``array`` is a 0-d (or single-element) torch tensor or Dr.Jit array, any dtype the backend casts.
    """

    __slots__ = ("array",)

    def __new__(cls, value, array):
        self = super().__new__(cls, value)
        self.array = array
        return self

    def __repr__(self):
        return f"Learnable({float(self)!r})"

    def __reduce__(self):  # pickles (e.g. to worker processes) as the plain float
        return float, (float(self),)


def array_of(v):
    """The differentiable value of a parameter: the array of a :class:`Learnable`, else ``v``."""
    return v.array if isinstance(v, Learnable) else v


def is_backend_array(v) -> bool:
    """True for torch tensors and Dr.Jit arrays (the values a parameter may be learnable as)."""
    mod = type(v).__module__ or ""
    return mod.startswith("torch") or mod.startswith("drjit")


def short_number(v) -> str:
    """``v`` as ``{:g}`` (``2``, ``0.5``, ``1e-05``) where that reads back as ``v``, else its shortest
    round-trip form (``2.0000001``): labels name settings uniquely."""
    s = f"{v:g}"
    return s if float(s) == float(v) else repr(float(v))


def non_real_kind(v) -> str | None:
    """The element type of a bool or complex torch tensor / Dr.Jit array (a cast would make True 1
    or drop imaginary parts), else None. Dr.Jit arrays have no dtype: Bool, Array3b, TensorXb are bools."""
    dtype = str(getattr(v, "dtype", "")).rsplit(".", 1)[-1]
    kind = type(v).__name__
    if dtype == "bool" or dtype.startswith("complex") or (not dtype and (kind == "Bool" or kind.endswith("b"))):
        return dtype or kind
    return None


def plain_number(v) -> float | None:
    """``float(v)`` for a real number (Python or NumPy) or a NumPy array of one, else None: strings,
    bools and other objects are not numbers here (``float("2")`` and ``float(True)`` would pass)."""
    if isinstance(v, (str, bytes, bool)):
        return None  # (NumPy bools: their dtype kind "b", below)
    if hasattr(v, "__array__") and not is_backend_array(v) and getattr(v, "size", 0) == 1:
        if getattr(v, "dtype", None) is None or v.dtype.kind not in "iuf":
            return None
        v = v.reshape(-1)[0]
    if not isinstance(v, numbers.Number) or (isinstance(v, numbers.Complex) and not isinstance(v, numbers.Real)):
        return None  # (numbers.Number, not Real: Decimal and Fraction-like types convert exactly enough)
    return float(v)


def array_value(owner: str, name: str, raw) -> float:
    """The float value of a scalar backend array ``raw`` (torch: detached; Dr.Jit: via NumPy).

    Raises :class:`ParameterError` when it is not a single real number."""
    if kind := non_real_kind(raw):
        raise ParameterError(f"{owner} parameter {name} must be a real number, got a {kind} array")
    shape = tuple(getattr(raw, "shape", ()))
    if shape not in ((), (1,)):
        raise ParameterError(f"{owner} parameter {name} must be a scalar (0-d) array, got shape {list(shape)}")
    try:
        if hasattr(raw, "detach") and hasattr(raw, "item"):  # torch
            return float(raw.detach().reshape(-1)[0].item())
        if hasattr(raw, "numpy"):  # Dr.Jit
            import numpy as np
            return float(np.asarray(raw.numpy()).reshape(-1)[0])
        return float(raw)
    except (TypeError, ValueError, IndexError, RuntimeError):
        raise ParameterError(f"{owner} parameter {name}={raw!r} must be a number") from None


class LearnableParams:
    """Learnable-parameter bookkeeping shared by the frozen specs :class:`~gendr.TConorm` and
    :class:`~gendr.Distribution`: both hold ``family`` (with ``params``, the declared
    :class:`Param` list) and ``params``, a tuple of ``(name, value)``; a value given as a torch
    tensor / Dr.Jit array is a :class:`Learnable`. ``_owner`` names the spec in messages."""

    _owner_kind = ""

    @property
    def learnable(self) -> dict:
        """``{name: array}`` of the parameters given as torch tensors / Dr.Jit arrays (empty: none).
        Both backends return their gradients."""
        return {k: v.array for k, v in self.params if isinstance(v, Learnable)}

    def with_arrays(self, arrays):
        """The same setting with the learnable parameters' arrays replaced by ``arrays``
        (``{name: array}``, e.g. cast to the render dtype, or detached), values unchanged."""
        if not arrays:
            return self
        return replace(self, params=tuple((k, Learnable(float(v), arrays[k]) if k in arrays else v)
                                          for k, v in self.params))

    def refreshed(self):
        """Re-read the learnable parameters' current values (an optimizer may have changed them in
        place) and check their domain: :class:`~gendr.errors.ParameterError` naming the value if
        one left it. Returns ``self`` when there is nothing learnable."""
        if not self.learnable:
            return self
        owner = f"{self._owner_kind} {self.name!r}"
        out = []
        for prm, (k, v) in zip(self.family.params, self.params):
            if isinstance(v, Learnable):
                value = array_value(owner, k, v.array)
                if not prm.constraint.check(value):
                    raise ParameterError(f"{owner} parameter {k}={value!r} (a learnable {type(v.array).__name__}, "
                                         f"at render time) is out of domain: expected {prm.constraint.description}")
                v = Learnable(value, v.array)
            out.append((k, v))
        return replace(self, params=tuple(out))


def validate_params(owner: str, declared: tuple[Param, ...], given: Mapping[str, object],
                    learnable: bool = False) -> dict[str, float]:
    """Return ``{name: float}`` for every declared parameter, or raise :class:`ParameterError`.

    ``owner`` names the family in messages, e.g. ``"tconorm 'yager'"``. With ``learnable``, a
    torch tensor or Dr.Jit array value is checked (scalar, in the domain at its current value) and
    returned as a :class:`Learnable` that keeps the array; otherwise every value becomes a float.
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
        if learnable and is_backend_array(raw):
            value = array_value(owner, p.name, raw)
            if not p.constraint.check(value):
                raise ParameterError(f"{owner} parameter {p.name}={value!r} (a {type(raw).__name__}) is out of "
                                     f"domain: expected {p.constraint.description}")
            out[p.name] = Learnable(value, raw)
            continue
        value = plain_number(raw)
        if value is None:
            raise ParameterError(f"{owner} parameter {p.name}={raw!r} must be a number {p.constraint.description}")
        if not p.constraint.check(value):
            raise ParameterError(f"{owner} parameter {p.name}={raw!r} is out of domain: expected {p.constraint.description}")
        out[p.name] = value
    return out


class Registry(dict):
    """Name -> entry, raising :class:`UnknownNameError` listing the valid names."""

    #: every registry, so that a name of one given for another says so (arguments swapped)
    _all: list = []

    def __init__(self, kind: str):
        super().__init__()
        self.kind = kind
        Registry._all.append(self)

    def add(self, entry):
        if entry.name in self:
            raise ValueError(f"{self.kind} {entry.name!r} registered twice")
        self[entry.name] = entry
        return entry

    def lookup(self, name):
        if not isinstance(name, str) or name not in self:
            other = [r.kind for r in Registry._all if r is not self and isinstance(name, str) and name in r]
            raise UnknownNameError(self.kind, name, sorted(self), f"{name!r} is a {other[0]}" if other else "")
        return self[name]
