"""Typed errors (gendr.errors) whose messages name the bad value, from the Renderer facade."""
from __future__ import annotations

import math
import re
import subprocess
import sys

import numpy as np
import pytest
import torch

import gendr
from gendr.errors import (DTypeError, GendrError, InputValueError, ParameterError, ShapeError,
                          UnknownNameError)

V = torch.tensor([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0], [0.3, 0.3, 0.1]], dtype=torch.float64)
F = torch.tensor([[0, 1, 2], [1, 3, 2]])
CAM = gendr.PerspectiveCamera()


def renderer(**kw):
    kw.setdefault("image_size", (8, 10))
    return gendr.Renderer(**kw)


# ------------------------------------------------------------------------------------------------
# names
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kw,kind,valid", [
    ({"distribution": "logistik"}, "distribution", "logistic"),
    ({"tconorm": "probabilstic"}, "tconorm", "probabilistic"),
    ({"backend": "nope"}, "backend", "torch"),
])
def test_unknown_names_list_the_valid_ones(kw, kind, valid):
    with pytest.raises(UnknownNameError) as e:
        renderer(**kw)
    msg = str(e.value)
    assert repr(next(iter(kw.values()))) in msg and kind in msg and valid in msg
    assert isinstance(e.value, GendrError) and isinstance(e.value, ValueError)
    assert valid in e.value.valid


def test_unknown_names_list_every_registered_name():
    with pytest.raises(UnknownNameError) as e:
        gendr.distribution("nope")
    assert all(n in str(e.value) for n in gendr.DISTRIBUTIONS)
    with pytest.raises(UnknownNameError) as e:
        gendr.tconorm("nope")
    assert all(n in str(e.value) for n in gendr.TCONORMS)


@pytest.mark.parametrize("name", [None, 3, ("logistic",)])
def test_non_string_names(name):
    with pytest.raises(UnknownNameError):
        renderer(distribution=name)


# ------------------------------------------------------------------------------------------------
# parameters
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("make,bad", [
    (lambda: gendr.tconorm("yager", p=-1.0), "-1.0"),
    (lambda: gendr.tconorm("frank", p=1.0), "1.0"),
    (lambda: gendr.tconorm("schweizer_sklar", p=0.5), "0.5"),
    (lambda: gendr.tconorm("hamacher", p=-0.1), "-0.1"),
    (lambda: gendr.tconorm("dombi", p=math.inf), "inf"),
    (lambda: gendr.tconorm("yager"), "'p'"),  # missing
    (lambda: gendr.tconorm("probabilistic", p=2.0), "'p'"),  # not accepted
    (lambda: gendr.distribution("gamma", shape=0.0), "0.0"),
    (lambda: gendr.distribution("gamma"), "'shape'"),
    (lambda: gendr.distribution("logistic", shift=math.nan), "nan"),
    (lambda: gendr.distribution("logistic", squared="yes"), "'yes'"),
    (lambda: renderer(distribution="gamma"), "'shape'"),
    (lambda: renderer(tconorm="aczel_alsina"), "'p'"),
    (lambda: renderer(distribution=gendr.distribution("gamma", shape=-2.0)), "-2.0"),
])
def test_out_of_domain_parameters(make, bad):
    with pytest.raises(ParameterError) as e:
        make()
    assert bad in str(e.value)


@pytest.mark.parametrize("tau", [0.0, -0.1, math.nan, math.inf, torch.tensor(-1.0), torch.tensor(math.nan),
                                 True, None, "abc"])
def test_bad_tau(tau):
    with pytest.raises(ParameterError) as e:
        renderer(tau=tau)
    assert "tau" in str(e.value)


@pytest.mark.parametrize("tau", [0.0, -0.1, math.nan, math.inf, torch.tensor(-1.0), True, None, "abc"])
def test_with_tau_checks_like_the_constructor(tau):
    r = renderer(tau=0.05)
    with pytest.raises(ParameterError) as e:
        r.with_tau(tau)
    assert "tau" in str(e.value)
    assert r.settings.tau_value == 0.05  # the renderer it was called on is unchanged
    with pytest.raises(ShapeError):
        r.with_tau(torch.tensor([0.1, 0.2]))


def test_tau_string_is_rejected_like_every_other_number():
    """eps="0", gamma="1" ... are ParameterErrors ("must be a number"); tau="0.1" should be too."""
    with pytest.raises(ParameterError) as e:
        renderer(tau="0.1")
    assert "tau" in str(e.value)


def test_tau_tensor_must_be_a_scalar():
    with pytest.raises(ShapeError) as e:
        renderer(tau=torch.tensor([0.1, 0.2]))
    assert "tau" in str(e.value)


@pytest.mark.parametrize("size", [(0, 10), (10, -1), (8.0, 10), (8, 10, 3), 0, -4, 2.5, "64", None, (True, 4)])
def test_bad_image_size(size):
    with pytest.raises(ParameterError) as e:
        renderer(image_size=size)
    assert "image" in str(e.value)


@pytest.mark.parametrize("eps", [-1e-9, 1.0, 2.0, math.nan, math.inf, "0"])
def test_bad_eps(eps):
    with pytest.raises(ParameterError) as e:
        renderer(eps=eps)
    assert "eps" in str(e.value)


@pytest.mark.parametrize("kw,name", [
    ({"blend": "soft"}, "blend"), ({"gamma": 0.0}, "gamma"), ({"gamma": -1.0}, "gamma"),
    ({"background_eps": -1.0}, "background_eps"), ({"background": (1.0, 0.0)}, "background"),
    ({"ambient": -0.5}, "ambient"), ({"diffuse": math.nan}, "diffuse"),
    ({"light_direction": (0.0, 0.0, 0.0)}, "light_direction"), ({"max_pairs": 0}, "max_pairs"),
    ({"max_pairs": 10.5}, "max_pairs"),
])
def test_bad_render_settings(kw, name):
    with pytest.raises(ParameterError) as e:
        renderer(**kw)
    assert name in str(e.value)


@pytest.mark.parametrize("make,name", [
    (lambda: gendr.PerspectiveCamera(fov_y=180.0), "fov_y"),
    (lambda: gendr.PerspectiveCamera(fov_y=0.0), "fov_y"),
    (lambda: gendr.PerspectiveCamera(near=0.0), "near"),
    (lambda: gendr.PerspectiveCamera(near=2.0, far=1.0), "far"),
    (lambda: gendr.OrthographicCamera(xmag=-1.0), "xmag"),
    (lambda: gendr.IntrinsicsCamera(fx=0.0), "fx"),
    (lambda: gendr.orbit_camera(0.0, 0.0, -3.0), "distance"),
])
def test_bad_camera_parameters(make, name):
    with pytest.raises(ParameterError) as e:
        make()
    assert name in str(e.value)


def test_not_a_camera():
    with pytest.raises(ParameterError) as e:
        renderer().render(V, F, "perspective")
    assert "camera" in str(e.value)


# ------------------------------------------------------------------------------------------------
# inputs
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("shape", [(4, 2), (1, 4, 3, 1), (4,), (4, 4), (2, 0, 3)])
def test_vertices_wrong_shape(shape):
    with pytest.raises(ShapeError) as e:
        renderer().render(torch.zeros(shape, dtype=torch.float64), F, CAM)
    assert str(list(shape)) in str(e.value)


@pytest.mark.parametrize("dtype", [torch.int64, torch.int32, torch.float16, torch.bfloat16, torch.bool,
                                   torch.complex64])
def test_vertices_wrong_dtype(dtype):
    with pytest.raises(DTypeError) as e:
        renderer().render(V.to(dtype), F, CAM)
    assert str(dtype) in str(e.value) and "vertices" in str(e.value)


@pytest.mark.parametrize("dtype", [np.int64, np.int32, np.float16, np.bool_])
def test_numpy_vertices_wrong_dtype(dtype):
    with pytest.raises(DTypeError) as e:
        renderer().render(V.numpy().astype(dtype), F, CAM)
    assert np.dtype(dtype).name in str(e.value) and "vertices" in str(e.value)


def test_vertices_object_array():
    with pytest.raises(DTypeError):
        renderer().render(np.array([["a", "b", "c"]] * 4), F, CAM)


@pytest.mark.parametrize("faces", [F.double(), F.float(), F.bool(), F.numpy().astype(np.float32)])
def test_faces_wrong_dtype(faces):
    with pytest.raises(DTypeError) as e:
        renderer().render(V, faces, CAM)
    assert "faces" in str(e.value)


@pytest.mark.parametrize("faces", [torch.tensor([0, 1, 2]), torch.tensor([[0, 1, 2, 3]]), torch.zeros(1, 3, 1, dtype=torch.long)])
def test_faces_wrong_shape(faces):
    with pytest.raises(ShapeError) as e:
        renderer().render(V, faces, CAM)
    assert "faces" in str(e.value)


@pytest.mark.parametrize("bad,lo,hi", [(4, 0, 4), (-1, -1, 2), (17, 0, 17)])
def test_face_index_out_of_range(bad, lo, hi):
    faces = F.clone()
    faces[1, 1] = bad
    with pytest.raises(InputValueError) as e:
        renderer().render(V, faces, CAM)
    msg = str(e.value)
    assert "[0, 3]" in msg and f"[{lo}, {hi}]" in msg


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_vertex_names_the_index(value):
    v = V.clone()[None].repeat(2, 1, 1)
    v[1, 3, 2] = value
    with pytest.raises(InputValueError) as e:
        renderer().render(v, F, CAM)
    assert "[1, 3, 2]" in str(e.value) and str(value) in str(e.value)


@pytest.mark.parametrize("kw,name", [
    ({"vertex_colors": torch.rand(3, 3, dtype=torch.float64)}, "vertex_colors"),
    ({"vertex_colors": torch.rand(4, 4, dtype=torch.float64)}, "vertex_colors"),
    ({"vertex_colors": torch.rand(1, 1, 4, 3, dtype=torch.float64)}, "vertex_colors"),
    ({"face_colors": torch.rand(4, 3, dtype=torch.float64)}, "face_colors"),
    ({"face_colors": torch.rand(2, 2, dtype=torch.float64)}, "face_colors"),
])
def test_colours_wrong_shape(kw, name):
    with pytest.raises(ShapeError) as e:
        renderer().render(V, F, CAM, **kw)
    assert name in str(e.value)


def test_non_finite_colour():
    c = torch.rand(4, 3, dtype=torch.float64)
    c[2, 1] = math.nan
    with pytest.raises(InputValueError) as e:
        renderer().render(V, F, CAM, vertex_colors=c)
    assert "vertex_colors" in str(e.value) and "[2, 1]" in str(e.value)


def test_both_colour_kinds():
    with pytest.raises(ParameterError) as e:
        renderer().render(V, F, CAM, vertex_colors=torch.rand(4, 3, dtype=torch.float64),
                          face_colors=torch.rand(2, 3, dtype=torch.float64))
    assert "vertex_colors" in str(e.value) and "face_colors" in str(e.value)


def test_camera_batch_mismatch():
    v = V[None].repeat(2, 1, 1)
    cam = gendr.orbit_camera(torch.tensor([0.0, 10.0, 20.0], dtype=torch.float64), 0.0, 3.0)
    with pytest.raises(ShapeError) as e:
        renderer().render(v, F, cam)
    assert "2" in str(e.value) and "3" in str(e.value)


def test_camera_parameters_with_different_batches():
    cam = gendr.PerspectiveCamera(eye=torch.tensor([[0.0, 0.0, 3.0]] * 2, dtype=torch.float64),
                                  fov_y=torch.tensor([30.0, 40.0, 50.0], dtype=torch.float64))
    with pytest.raises(ShapeError) as e:
        renderer().render(V, F, cam)
    assert "fov_y" in str(e.value) or "eye" in str(e.value)


def test_camera_parameter_wrong_shape():
    with pytest.raises(ShapeError) as e:
        renderer().render(V, F, gendr.PerspectiveCamera(eye=torch.zeros(2, 2, dtype=torch.float64)))
    assert "eye" in str(e.value)


def test_non_finite_camera_parameter_is_a_value_error():
    """A NaN in a camera parameter is a bad *value*, not a bad shape."""
    cam = gendr.PerspectiveCamera(eye=torch.tensor([0.0, math.nan, 3.0], dtype=torch.float64))
    with pytest.raises((InputValueError, ParameterError)) as e:
        renderer().render(V, F, cam)
    assert "eye" in str(e.value)


# ------------------------------------------------------------------------------------------------
# the spec layer does not import torch
# ------------------------------------------------------------------------------------------------
def test_import_gendr_does_not_import_torch():
    code = ("import gendr, sys; "
            "gendr.distribution('gamma', shape=2.0); gendr.tconorm('yager', p=2.0); gendr.paper_grid(); "
            "gendr.PerspectiveCamera(); "
            "assert 'torch' not in sys.modules, sorted(m for m in sys.modules if 'torch' in m)")
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("backend, option", [("torch", "freeze"), ("drjit", "compile"), ("torch", "devcie")])
def test_unknown_backend_option_is_a_parameter_error(backend, option):
    if backend not in gendr.available_backends():
        pytest.skip(f"backend {backend} not installed")
    with pytest.raises(ParameterError, match=f"backend '{backend}' has no option '{option}'"):
        gendr.Renderer(backend=backend, **{option: True})


# ------------------------------------------------------------------------------------------------
# inputs a user plausibly passes (an audit of the public API, 2026-11-24): the same typed error from
# both backends, raised before any work, naming the value
# ------------------------------------------------------------------------------------------------
def _backends():
    return [b for b in ("torch", "drjit") if b in gendr.available_backends()]


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("kw,verts_batch,name", [
    ({"vertex_colors": torch.rand(2, 4, 3, dtype=torch.float64)}, 1, "vertex_colors"),
    ({"vertex_colors": torch.rand(3, 4, 3, dtype=torch.float64)}, 2, "vertex_colors"),
    ({"face_colors": torch.rand(3, 2, 3, dtype=torch.float64)}, 2, "face_colors"),
    ({"texture": torch.rand(3, 4, 4, 3, dtype=torch.float64), "uvs": torch.rand(4, 2, dtype=torch.float64)}, 2,
     "texture"),
    ({"texture": torch.rand(4, 4, 3, dtype=torch.float64), "uvs": torch.rand(3, 4, 2, dtype=torch.float64)}, 2, "uvs"),
])
def test_colour_and_texture_batches_must_be_one_or_the_render_batch(backend, kw, verts_batch, name):
    """(torch raised a raw RuntimeError for colours and used the first textures; drjit ignored extra
    colour sets and raised for textures)"""
    v = V if verts_batch == 1 else V[None].repeat(verts_batch, 1, 1)
    with pytest.raises(ShapeError, match=f"{name} has batch size") as e:
        renderer(backend=backend).render(v, F, CAM, **kw)
    assert f"B = {verts_batch}" in str(e.value)


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("value", [-0.01, 0.0, math.nan])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_a_tensor_tau_is_checked_at_every_render(backend, value, dtype):
    """An optimizer step may move a learnable τ out of its domain (it rendered garbage before); the
    error names the domain, also in float32 (not float32's range, which float64 would not cure)."""
    tau = torch.tensor(0.01, dtype=dtype, requires_grad=True)
    r = renderer(backend=backend, tau=tau)
    r.render(V.to(dtype), F, CAM)
    with torch.no_grad():
        tau.fill_(value)
    with pytest.raises(ParameterError, match="tau=tensor.* is out of domain: expected finite and > 0"):
        r.render(V.to(dtype), F, CAM)


@pytest.mark.parametrize("make,name", [
    (lambda: gendr.PerspectiveCamera(fov_y=None), "fov_y=None"),
    (lambda: gendr.PerspectiveCamera(fov_y="40"), "fov_y='40'"),
    (lambda: gendr.PerspectiveCamera(eye="abc"), "eye='abc'"),
    (lambda: gendr.PerspectiveCamera(eye=np.array([0, 0, 3], dtype=object)), "eye=array"),
    (lambda: gendr.orbit_camera(None, 0.0, 3.0), "azimuth=None"),
    (lambda: gendr.PerspectiveCamera(eye=[0.0, 0.0, torch.tensor(3.0, requires_grad=True)]), "mixes numbers and tensors"),
    (lambda: gendr.orbit_camera(0.0, 0.0, 3.0, orthographic=True, ymag=0.0), "ymag=0"),
    (lambda: gendr.PerspectiveCamera(eye=gendr.Orbit(0.0, 0.0, -3.0)), "distance=-3"),
])
def test_camera_values_that_are_not_numbers_fail_at_construction(make, name):
    """(they were accepted and failed at render time with raw TypeErrors, differently per backend)"""
    test_strings_and_bools_are_not_numbers(make, name)


@pytest.mark.parametrize("backend", _backends())
def test_a_negative_tensor_orbit_distance_is_an_error(backend):
    """(rendered silently from the opposite side)"""
    cam = gendr.orbit_camera(0.0, 0.0, torch.tensor(-3.0, dtype=torch.float64))
    with pytest.raises(ParameterError, match="distance=-3"):
        renderer(backend=backend).render(V, F, cam)


def test_numpy_numbers_are_numbers():
    r = renderer(image_size=np.int64(8), tau=np.array([0.02]), eps=np.float32(0.0))
    assert r.settings.image_size == (8, 8) and r.settings.tau_value == 0.02
    assert gendr.PerspectiveCamera(near=np.float32(0.5)).near == 0.5
    assert gendr.tconorm("yager", p=np.array([2.0])).kwargs == {"p": 2.0}
    # a NumPy bool is a bool (refused under NumPy 2, whose np.bool_ is named "bool")
    assert renderer(cull_backfaces=np.bool_(True)).settings.cull_backfaces is True


@pytest.mark.parametrize("make,name", [
    (lambda: gendr.tconorm("yager", p="2"), "p='2'"),
    (lambda: gendr.tconorm("yager", p=True), "p=True"),
    (lambda: gendr.distribution("logistic", shift="0.1"), "shift='0.1'"),
    (lambda: gendr.distribution("logistic", shift=torch.tensor(0.1, requires_grad=True)), "is not learnable"),
    (lambda: renderer(cull_backfaces="no"), "cull_backfaces='no'"),
    (lambda: renderer(background="red"), "background='red'"),
    (lambda: renderer(light_direction="abc"), "light_direction='abc'"),
])
def test_strings_and_bools_are_not_numbers(make, name):
    with pytest.raises(ParameterError) as e:
        make()
    assert name in str(e.value)


@pytest.mark.parametrize("backend", _backends())
def test_empty_batches_and_ragged_faces(backend):
    r = renderer(backend=backend)
    with pytest.raises(ShapeError, match=r"got \[0, 4, 3\]"):
        r.render(V[None][:0], F, CAM)
    with pytest.raises(ShapeError, match="azimuth has an empty batch"):
        r.render(V, F, gendr.orbit_camera(np.zeros(0), 0.0, 3.0))
    with pytest.raises(ShapeError, match=r"faces must be a regular array"):
        r.render(V, [[0, 1, 2], [0, 1]], CAM)
    img = r.to_numpy(r.render(V, [], CAM))  # no faces: an empty image
    assert img.shape == (1, 8, 10, 4) and float(img[..., 3].max()) == 0.0
    # ... also textured, with uv_faces=[] (a DTypeError 'float64' before: [] is float64 to NumPy)
    img = r.to_numpy(r.render(V, [], CAM, texture=np.ones((2, 2, 3)), uvs=np.zeros((1, 2)), uv_faces=[]))
    assert img.shape == (1, 8, 10, 4) and float(img[..., 3].max()) == 0.0


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("faces, dtype", [(None, "object"), ([["a", "b", "c"]], "<U1"), (np.zeros((1, 3)), "float64"),
                                          ([[True, False, True]], "bool")])
def test_faces_that_are_not_integers_are_a_dtype_error_on_every_backend(backend, faces, dtype):
    """(None or strings were torch's raw TypeError on the torch backend, a DTypeError on drjit)"""
    with pytest.raises(DTypeError, match=f"faces must be an integer array, got {dtype}"):
        renderer(backend=backend).render(V, faces, CAM)


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("dtype", [torch.complex64, torch.bool, torch.float16])
def test_torch_colours_follow_the_numpy_dtype_rule(backend, dtype):
    """Colour tensors, like NumPy colours, are float32/64 or integers: a complex tensor lost its
    imaginary part with only a warning; bool and half were cast where NumPy's are refused."""
    colours = torch.ones(len(V), 3, dtype=dtype)
    with pytest.raises(DTypeError, match=f"vertex_colors must be float32, float64 or integers, got {dtype}"):
        renderer(backend=backend).render(V, F, CAM, vertex_colors=colours)


def test_a_drjit_tau_on_the_torch_backend_is_a_parameter_error():
    """(it was float()'s TypeError deep in the torch rasterizer)"""
    pytest.importorskip("drjit")
    from drjit.llvm.ad import Float
    with pytest.raises(ParameterError, match="of type Float: the torch backend takes a number or a torch tensor"):
        renderer(backend="torch", tau=Float(0.1)).render(V, F, CAM)


def test_torch_device_is_checked_at_construction():
    """(a CUDA device on a CPU-only torch failed at the first render with an AssertionError)"""
    from gendr.errors import BackendUnavailableError
    with pytest.raises(ParameterError, match="device='gpu'"):
        renderer(backend="torch", device="gpu")
    if not torch.cuda.is_available():
        with pytest.raises(BackendUnavailableError, match="device='cuda'"):
            renderer(backend="torch", device="cuda")
    assert renderer(backend="torch", device="cpu").backend.device.type == "cpu"


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("as_torch", [False, True])
def test_uint8_colours_are_refused_like_uint8_textures(backend, as_torch):
    """(255 rendered as RGB 255: an 8-bit image's colours are 0..255, gendr's albedo 0..1)"""
    c = np.full((4, 3), 255, np.uint8)
    with pytest.raises(DTypeError, match="vertex_colors are uint8"):
        renderer(backend=backend).render(V, F, CAM, vertex_colors=torch.as_tensor(c) if as_torch else c)


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("colours,words", [
    (np.full((4, 3), 255, np.int64), "int64 in [255, 255]"),
    (torch.full((4, 3), 2, dtype=torch.int32), "int32 in [2, 2]"),
    ([[0, 0, -1]] * 4, "int64 in [-1, 0]"),
])
def test_integer_colours_beyond_0_1_are_refused(backend, colours, words):
    """(int64 255 rendered 255 times too bright, where uint8 was refused)"""
    with pytest.raises(DTypeError, match=re.escape(f"vertex_colors are {words}: integer colours must be 0 or 1")):
        renderer(backend=backend).render(V, F, CAM, vertex_colors=colours)


@pytest.mark.parametrize("backend", _backends())
def test_integer_colours_0_1_render_as_floats(backend):
    r = renderer(backend=backend)
    as_int = r.to_numpy(r.render(V, F, CAM, vertex_colors=np.array([[1, 0, 1]] * 4, np.int16)))
    as_float = r.to_numpy(r.render(V, F, CAM, vertex_colors=np.array([[1.0, 0.0, 1.0]] * 4, np.float32)))
    np.testing.assert_array_equal(as_int, as_float)


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("scale,fov", [(1e20, 60.0), (1.0, 1e-30)])
def test_corners_beyond_float32_range_are_an_error_not_garbage(backend, scale, fov):
    """(a triangle covering the view rendered alpha 0 with torch and 0.5 with drjit: its squared
    edge lengths overflowed float32); float64 holds them and renders it covering the view"""
    tri = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]]) * scale
    r, cam = renderer(backend=backend), gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=fov)
    with pytest.raises(gendr.errors.InputValueError, match="beyond what float32 edge lengths can hold"):
        r.render(tri.astype(np.float32), [[0, 1, 2]], cam)
    alpha = r.to_numpy(r.render(tri, [[0, 1, 2]], cam))[..., 3]
    assert alpha.min() > 0.99


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("dist,tcn,words", [
    ("logistic", gendr.tconorm("frank", p=1e40), "tconorm 'frank' parameter p=1e+40"),
    ("logistic", gendr.tconorm("frank", p=1e-40), "tconorm 'frank' parameter p=1e-40"),
    (gendr.distribution("gamma", shape=1e-40), "probabilistic", "distribution 'gamma' parameter shape=1e-40"),
    (gendr.distribution("logistic", shift=1e40), "probabilistic", "distribution 'logistic' parameter shift=1e+40"),
])
def test_parameters_float32_cannot_hold_are_an_error(backend, dist, tcn, words):
    """(frank p = 1e40 rendered alpha -inf in float32, p = 1e-40 +inf; gamma shape 1e300, now beyond its
    domain (0, 20], raised a raw torch overflow error); float64 renders them, alpha in [0, 1]"""
    r = renderer(backend=backend, distribution=dist, tconorm=tcn, tau=0.3)
    with pytest.raises(ParameterError, match=re.escape(words) + " is beyond what float32 holds"):
        r.render(V.float(), F, CAM)
    if "gamma" not in words:  # (gamma at shape 1e-40: its quantile search warns of log1p(-1); alpha is fine)
        alpha = r.to_numpy(r.render(V, F, CAM))[..., 3]
        assert np.isfinite(alpha).all() and alpha.min() >= 0.0 and alpha.max() <= 1.0


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("tau,words", [(1e-39, "tau=1e-39 is below 1.7"), (1e39, "tau=1e+39 is beyond what float32 holds")])
def test_tau_float32_cannot_hold_is_an_error(backend, tau, words):
    """τ follows the parameters' rule: a float32 render refuses one outside float32's range, and
    one below tau_floor (a subnormal τ overflowed d/τ to +inf: reversed gamma(2) gave 111 NaN vertex
    gradients in a 16² torch render); float64 renders both."""
    r = renderer(backend=backend, distribution=gendr.distribution("gamma", shape=2.0, reversed=True), tau=tau)
    with pytest.raises(ParameterError, match=re.escape(words)):
        r.render(V.float(), F, CAM)
    alpha = r.to_numpy(r.render(V, F, CAM))[..., 3]
    assert np.isfinite(alpha).all() and alpha.min() >= 0.0 and alpha.max() <= 1.0


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_tau_below_its_floor_is_an_error_and_above_it_gradients_are_finite(backend, dtype):
    """Below gendr.renderer.tau_floor (16·sqrt(tiny)) −d/τ² overflows and torch's dL/dτ was NaN
    (float32 τ = 3e-20, float64 1e-156: 0·inf, even with no pixel depending on τ): now a
    ParameterError. At twice the floor every gradient is finite."""
    from gendr.renderer import tau_floor
    floor = tau_floor(str(dtype).replace("torch.", ""))
    assert floor == pytest.approx({torch.float32: 1.74e-18, torch.float64: 2.39e-153}[dtype], rel=1e-2)
    with pytest.raises(ParameterError, match=re.escape(f"tau={floor / 10:g} is below {floor:.3g}")):
        renderer(backend=backend, tau=floor / 10).render(V.to(dtype), F, CAM)
    tau = torch.tensor(2 * floor, dtype=torch.float64, requires_grad=True)
    v = V.to(dtype).clone().requires_grad_(True)
    r = renderer(backend=backend, tau=tau)
    r.render(v, F, CAM)[..., 3].sum().backward()
    assert torch.isfinite(tau.grad) and torch.isfinite(v.grad).all()


@pytest.mark.parametrize("backend", _backends())
def test_a_learnable_parameter_float32_cannot_hold_is_an_error(backend):
    """The float32 range check reads a learnable parameter's current value: an optimizer step that
    moved frank's p to 1e-39 rendered alpha up to +inf in float32 (the check read the value of the
    previous render)."""
    p = torch.tensor(2.0, requires_grad=True)
    r = renderer(backend=backend, tconorm=gendr.tconorm("frank", p=p), tau=0.3)
    r.render(V.float(), F, CAM)
    with torch.no_grad():
        p.fill_(1e-39)
    with pytest.raises(ParameterError, match=re.escape("tconorm 'frank' parameter p=1e-39 is beyond what float32")):
        r.render(V.float(), F, CAM)


def test_unknown_names_suggest_the_close_one_or_the_other_registry():
    """The "did you mean" was the CLI's only; arguments swapped (a T-conorm given as the
    distribution) said only 'unknown distribution'."""
    with pytest.raises(gendr.UnknownNameError, match=r"'gausian' \(did you mean 'gaussian'\?\)"):
        gendr.Renderer(distribution="gausian")
    with pytest.raises(gendr.UnknownNameError, match=r"unknown distribution 'probabilistic' \('probabilistic' is a tconorm\)"):
        gendr.Renderer("probabilistic", "logistic")
    with pytest.raises(gendr.UnknownNameError, match=r"unknown tconorm 'logistic' \('logistic' is a distribution\)"):
        gendr.tconorm("logistic")


def test_one_based_faces_get_a_hint():
    """(faces read 1-based, as OBJ files store them: the range was named, its likely cause not)"""
    with pytest.raises(InputValueError, match=r"got range \[1, 4\] \(1-based, as in OBJ files\? subtract 1\)"):
        renderer().render(V, F + 1, CAM)  # (F spans [0, 3], V = 4)
