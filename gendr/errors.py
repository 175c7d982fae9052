"""Typed errors. Every message names the bad value and what was expected.

Each error also derives from the built-in exception a caller would catch without knowing gendr
(``ValueError``, ``TypeError`` or ``ImportError``), so ``except ValueError`` keeps working.
"""
import difflib


class GendrError(Exception):
    """Base class of every error gendr raises on purpose.

    >>> import gendr
    >>> try:
    ...     gendr.distribution("no_such_distribution")
    ... except gendr.GendrError as exc:
    ...     print(type(exc).__name__)
    UnknownNameError
    """


class UnknownNameError(GendrError, ValueError):
    """A distribution, T-conorm, backend, scene ... name that does not exist.

    Attributes: ``kind`` (e.g. ``"tconorm"``), ``name`` (the name given) and ``valid`` (tuple of the
    valid names).

    >>> import gendr
    >>> try:
    ...     gendr.tconorm("maximum")
    ... except gendr.UnknownNameError as exc:
    ...     print(exc.kind, exc.name, "max" in exc.valid, isinstance(exc, ValueError))
    tconorm maximum True True
    """

    def __init__(self, kind: str, name, valid, hint: str = ""):
        self.kind, self.name, self.valid = kind, name, tuple(valid)
        close = difflib.get_close_matches(name, [str(v) for v in self.valid], n=1) if isinstance(name, str) else []
        if close and not hint:
            hint = f"did you mean {close[0]!r}?"
        super().__init__(f"unknown {kind} {name!r}" + (f" ({hint})" if hint else "")
                         + f"; valid {kind} names: {', '.join(self.valid)}")


class ParameterError(GendrError, ValueError):
    """A parameter outside its domain, missing, or not accepted by its family.

    >>> import gendr
    >>> gendr.Renderer(tau=-1.0)
    Traceback (most recent call last):
    ...
    gendr.errors.ParameterError: Renderer parameter tau=-1.0 is out of domain: expected finite and > 0
    """


class ShapeError(GendrError, ValueError):
    """An array with the wrong number of dimensions or sizes.

    >>> import gendr
    >>> gendr.PerspectiveCamera(eye=(0.0, 3.0))
    Traceback (most recent call last):
    ...
    gendr.errors.ShapeError: camera parameter eye must have shape [3] or [B, 3], got [2]
    """


class DTypeError(GendrError, TypeError):
    """An array of an unsupported dtype (e.g. integer vertices, float face indices).

    >>> import numpy as np, gendr
    >>> r = gendr.Renderer(image_size=8, backend="torch")
    >>> r.render(np.zeros((3, 3), dtype=np.int32), [[0, 1, 2]], gendr.PerspectiveCamera())
    Traceback (most recent call last):
    ...
    gendr.errors.DTypeError: ...
    """


class DegenerateCameraError(ParameterError):
    """A camera pose without a defined view: eye on at, or up parallel to the viewing direction.

    >>> import gendr
    >>> gendr.PerspectiveCamera(eye=(0.0, 0.0, 0.0), at=(0.0, 0.0, 0.0))
    Traceback (most recent call last):
    ...
    gendr.errors.DegenerateCameraError: PerspectiveCamera: eye=(0, 0, 0) equals at=(0, 0, 0): ...
    """


class InputValueError(GendrError, ValueError):
    """Input values that are invalid: non-finite vertices, face indices out of range, ...

    >>> import numpy as np, gendr
    >>> r = gendr.Renderer(image_size=8, backend="torch")
    >>> r.render(np.eye(3), [[0, 1, 3]], gendr.PerspectiveCamera())
    Traceback (most recent call last):
    ...
    gendr.errors.InputValueError: face indices must lie in [0, 2] (V = 3), got range [0, 3]
    """


class BackendUnavailableError(GendrError, ImportError):
    """A backend is registered but cannot be imported (its dependencies are missing).

    Raised by :class:`~gendr.Renderer` when its ``backend`` cannot be loaded; the message names the
    extra to install (``pip install gendr[drjit]``).

    >>> import gendr
    >>> issubclass(gendr.BackendUnavailableError, ImportError)
    True
    """


def require_finite(backend, a, name):
    """Raise :class:`InputValueError` naming the first non-finite entry of the backend array ``a``
    as it will be rendered, i.e. after the cast to the render dtype (1e300 is inf in float32)."""
    bad = backend.first_nonfinite(a)
    if bad is not None:
        dtype = str(a.dtype).replace("torch.", "")
        raise InputValueError(f"{name} must be finite in {dtype} (the render dtype); {name}{list(bad[0])} = {bad[1]}")


def refuse_second_derivatives(grads):
    """NotImplementedError under ``create_graph=True`` unless every incoming gradient (torch
    tensors, read by duck typing: this layer imports no array library) is a constant 0, e.g. the
    alpha channel's where a loss reads only RGB. For the backends' analytic backward passes, which
    have first derivatives only."""
    if any(g is not None and (g.requires_grad or bool(g.any())) for g in grads):
        raise NotImplementedError("gendr's renders have first derivatives only: backward(create_graph=True) "
                                  "(double backward, Hessians) is not supported")
