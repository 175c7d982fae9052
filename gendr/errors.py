"""Typed errors. Every message names the bad value and what was expected."""


class GendrError(Exception):
    """Base class of every error gendr raises on purpose."""


class UnknownNameError(GendrError, ValueError):
    """A distribution, T-conorm, backend, scene ... name that does not exist."""

    def __init__(self, kind: str, name, valid):
        self.kind, self.name, self.valid = kind, name, tuple(valid)
        super().__init__(f"unknown {kind} {name!r}; valid {kind} names: {', '.join(self.valid)}")


class ParameterError(GendrError, ValueError):
    """A parameter outside its domain, missing, or not accepted by its family."""


class ShapeError(GendrError, ValueError):
    """An array with the wrong number of dimensions or sizes."""


class DTypeError(GendrError, TypeError):
    """An array of an unsupported dtype."""


class DegenerateCameraError(ParameterError):
    """A camera pose without a defined view: eye on at, or up parallel to the viewing direction."""


class InputValueError(GendrError, ValueError):
    """Input values that are invalid: non-finite vertices, face indices out of range, ..."""


class BackendUnavailableError(GendrError, ImportError):
    """A backend is registered but cannot be imported (its dependencies are missing)."""
