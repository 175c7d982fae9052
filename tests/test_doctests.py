"""The docstring examples of the public API run, and every public entry point has one.

Each example is cheap (8x8 images, tiny meshes, the torch backend on CPU) and downloads nothing.
"""
from __future__ import annotations

import doctest
import importlib
import inspect

import pytest

import gendr

FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE

#: modules whose docstring examples run
MODULES = ("gendr", "gendr.errors", "gendr.distributions", "gendr.tconorms", "gendr.cameras",
           "gendr.renderer", "gendr.grid", "gendr.gbuffer", "gendr.scenes", "gendr.textures",
           "gendr.interop", "gendr.images")

#: the public entry points: what ``gendr/__init__.py`` exports (classes and functions; the registries
#: DISTRIBUTIONS / TCONORMS are data), the Renderer's methods, the scene helpers, the interop
#: functions and the texture sampler
PUBLIC = (
    *[n for n, o in vars(gendr).items() if not n.startswith("_") and (inspect.isclass(o) or inspect.isfunction(o))],
    "Renderer.render", "Renderer.rasterize",
    "scenes.Mesh", "scenes.TexturedMesh", "scenes.icosphere", "scenes.cube", "scenes.torus",
    "scenes.tetrahedron", "scenes.get_scene", "scenes.get_textured_scene", "scenes.textured_cube",
    "scenes.checker_texture", "scenes.load_mesh", "scenes.normalize", "scenes.concatenate",
    "interop.world_to_view", "interop.project_points", "interop.to_kornia", "interop.from_kornia",
    "interop.from_pytorch3d_look_at",
    "textures.sample_numpy",
)


def _resolve(dotted: str):
    obj = gendr
    parts = dotted.split(".")
    if parts[0] in ("scenes", "interop", "textures"):
        obj = importlib.import_module(f"gendr.{parts.pop(0)}")
    for p in parts:
        obj = getattr(obj, p)
    return obj


def test_public_names_cover_the_package_exports():
    exported = {n for n in PUBLIC if "." not in n}
    for n in ("Renderer", "distribution", "tconorm", "orbit_camera", "paper_grid", "Instance", "GBuffer",
              "PerspectiveCamera", "OrthographicCamera", "IntrinsicsCamera", "ParameterError"):
        assert n in exported, n


@pytest.mark.parametrize("name", PUBLIC)
def test_public_name_has_a_documented_example(name):
    doc = inspect.getdoc(_resolve(name)) or ""
    assert ">>>" in doc, f"{name}: its docstring has no example (>>>)"


@pytest.mark.parametrize("module", MODULES)
def test_docstring_examples_pass(module):
    pytest.importorskip("torch")
    mod = importlib.import_module(module)
    result = doctest.testmod(mod, optionflags=FLAGS, verbose=False, report=True)
    assert result.failed == 0, f"{module}: {result.failed} of {result.attempted} doctest examples failed"
