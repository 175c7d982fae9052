"""gendr — a generalized differentiable mesh renderer (Petersen et al., CVPR 2022).

The spec layer: distributions, T-conorms, cameras, the paper's grid and the :class:`Renderer` facade.
It imports no array backend; backends are plug-ins found through the ``gendr.backends`` entry point.
"""
from .errors import (GendrError, UnknownNameError, ParameterError, ShapeError, DTypeError,
                     InputValueError, BackendUnavailableError, DegenerateCameraError)
from .distributions import Distribution, distribution, DISTRIBUTIONS
from .tconorms import TConorm, tconorm, TCONORMS

__version__ = "0.1.0"
from .cameras import Camera, PerspectiveCamera, OrthographicCamera, IntrinsicsCamera, Orbit, orbit_camera
from .renderer import Renderer, RenderSettings, available_backends
from .grid import Instance, paper_grid
from .gbuffer import GBuffer

#: the public API (``from gendr import *``); submodules load on first use (the end of this file)
__all__ = ["Renderer", "RenderSettings", "available_backends",
           "distribution", "Distribution", "DISTRIBUTIONS", "tconorm", "TConorm", "TCONORMS",
           "Camera", "PerspectiveCamera", "OrthographicCamera", "IntrinsicsCamera", "Orbit", "orbit_camera",
           "Instance", "paper_grid", "GBuffer",
           "GendrError", "UnknownNameError", "ParameterError", "ShapeError", "DTypeError", "InputValueError",
           "BackendUnavailableError", "DegenerateCameraError"]

#: submodules loaded on first use (``gendr.scenes.icosphere(2)`` after ``import gendr``), so that
#: ``import gendr`` stays light: interop's converters import torch only when called, images Pillow
_LAZY_SUBMODULES = ("scenes", "images", "interop", "textures", "ops", "cli")


def __getattr__(name):
    if name in _LAZY_SUBMODULES:
        import importlib
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
