"""Degenerate and out-of-domain camera values (gendr.cameras.Camera.check_values).

Each bad input raises a typed error (a ValueError) naming the parameter and its value, and for a batch
of cameras the first bad batch element: when the camera is made, for values given as Python numbers or
NumPy arrays; at render time, for tensors, on both backends, with the same message.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import gendr  # noqa: E402
from gendr import DegenerateCameraError, InputValueError, ParameterError  # noqa: E402

NAN, INF = math.nan, math.inf
V = torch.tensor([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]], dtype=torch.float64)
F = torch.tensor([[0, 1, 2]])
P, O, I = gendr.PerspectiveCamera, gendr.OrthographicCamera, gendr.IntrinsicsCamera

#: name -> (camera from a value converter v, error type, what the message must contain)
CASES = {
    "eye_equals_at": (lambda v: P(eye=v([0.5, 0.2, 1.0]), at=v([0.5, 0.2, 1.0])), DegenerateCameraError,
                      ["eye=(0.5, 0.2, 1) equals at=(0.5, 0.2, 1)", "viewing direction is undefined"]),
    "eye_at_origin": (lambda v: P(eye=v([0.0, 0.0, 0.0])), DegenerateCameraError, ["eye=(0, 0, 0) equals at=(0, 0, 0)"]),
    "orbit_distance_zero": (lambda v: P(eye=gendr.Orbit(v(10.0), v(20.0), v(0.0)), at=v([0.1, 0.0, 0.0])),
                            DegenerateCameraError, ["orbit distance=0", "at=(0.1, 0, 0)"]),
    "up_along_view": (lambda v: P(eye=v([0.0, 3.0, 0.0])), DegenerateCameraError,
                      ["up=(0, 1, 0) is parallel to the viewing direction from eye=(0, 3, 0) to at=(0, 0, 0)"]),
    "up_against_view": (lambda v: O(eye=v([0.0, -2.0, 0.0]), up=v([0.0, 5.0, 0.0])), DegenerateCameraError,
                        ["up=(0, 5, 0) is parallel", "eye=(0, -2, 0)"]),
    "up_along_view_orbit": (lambda v: gendr.orbit_camera(v(30.0), v(90.0), v(3.0)), DegenerateCameraError,
                            ["up=(0, 1, 0) is parallel", "azimuth=30, elevation=90, distance=3"]),
    "up_zero": (lambda v: I(up=v([0.0, 0.0, 0.0])), DegenerateCameraError, ["up=(0, 0, 0) must not be the zero vector"]),
    "batch_eye_on_at": (lambda v: P(eye=v([[0.0, 0.0, 3.0], [0.5, 0.5, 2.0], [0.0, 0.0, 0.0]])), DegenerateCameraError,
                        ["eye=(0, 0, 0) equals at=(0, 0, 0) (batch element 2 of 3)"]),
    "batch_orbit_elevation": (lambda v: gendr.orbit_camera(v([0.0, 10.0, 20.0, 30.0]), v([0.0, 10.0, -90.0, 10.0]), v(3.0)),
                              DegenerateCameraError, ["elevation=-90", "(batch element 2 of 4)"]),
    "batch_up": (lambda v: P(eye=v([0.0, 0.0, 3.0]), up=v([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])), DegenerateCameraError,
                 ["up=(0, 0, 1) is parallel", "(batch element 1 of 2)"]),
    "batch_at": (lambda v: P(eye=v([[0.0, 0.0, 3.0], [1.0, 1.0, 1.0]]), at=v([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])),
                 DegenerateCameraError, ["eye=(1, 1, 1) equals at=(1, 1, 1) (batch element 1 of 2)"]),
    "ortho_xmag_zero": (lambda v: O(xmag=v(0.0)), ParameterError, ["OrthographicCamera parameter xmag=0 must be > 0"]),
    "ortho_ymag_zero": (lambda v: O(ymag=v(0.0)), ParameterError, ["OrthographicCamera parameter ymag=0 must be > 0"]),
    "ortho_batch_xmag": (lambda v: O(xmag=v([1.0, 2.0, -1.0])), ParameterError,
                         ["xmag=-1 must be > 0 (batch element 2 of 3)"]),
    "intrinsics_fx_zero": (lambda v: I(fx=v(0.0)), ParameterError, ["IntrinsicsCamera parameter fx=0 must be > 0"]),
    "intrinsics_fy_zero": (lambda v: I(fy=v(0.0)), ParameterError, ["IntrinsicsCamera parameter fy=0 must be > 0"]),
    "intrinsics_batch_fy": (lambda v: I(fy=v([100.0, 0.0])), ParameterError, ["fy=0 must be > 0 (batch element 1 of 2)"]),
    "fov_zero": (lambda v: P(fov_y=v(0.0)), ParameterError, ["fov_y=0 must be in (0, 180) degrees"]),
    "fov_batch_180": (lambda v: P(fov_y=v([40.0, 180.0])), ParameterError, ["fov_y=180", "(batch element 1 of 2)"]),
    "eye_nan": (lambda v: P(eye=v([0.0, NAN, 3.0])), InputValueError, ["camera parameter eye must be finite, got (0, nan, 3)"]),
    "at_inf": (lambda v: P(at=v([INF, 0.0, 0.0])), InputValueError, ["at must be finite, got (inf, 0, 0)"]),
    "up_nan": (lambda v: P(up=v([0.0, NAN, 0.0])), InputValueError, ["up must be finite"]),
    "fov_nan": (lambda v: P(fov_y=v(NAN)), InputValueError, ["fov_y must be finite, got nan"]),
    "xmag_inf": (lambda v: O(xmag=v(INF)), InputValueError, ["xmag must be finite, got inf"]),
    "fx_nan": (lambda v: I(fx=v(NAN)), InputValueError, ["fx must be finite"]),
    "cy_inf": (lambda v: I(cy=v(-INF)), InputValueError, ["cy must be finite, got -inf"]),
    "azimuth_nan": (lambda v: gendr.orbit_camera(v(NAN), v(0.0), v(3.0)), InputValueError, ["azimuth must be finite"]),
    "batch_eye_inf": (lambda v: P(eye=v([[0.0, 0.0, 3.0], [0.0, INF, 3.0]])), InputValueError,
                      ["eye must be finite, got (0, inf, 3) (batch element 1 of 2)"]),
}

BACKENDS = ["torch", pytest.param("drjit", marks=pytest.mark.skipif(
    "drjit" not in gendr.available_backends(), reason="no drjit backend"))]


def _plain(x):
    return x


def _tensor(x):
    return torch.tensor(x, dtype=torch.float64)


def _check(err, kind, parts):
    assert type(err) is kind, (type(err), err)
    assert isinstance(err, ValueError) and isinstance(err, gendr.GendrError)
    for p in parts:
        assert p in str(err), (p, str(err))


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("convert", [_plain, np.asarray], ids=["numbers", "numpy"])
def test_plain_values_fail_when_the_camera_is_made(case, convert):
    make, kind, parts = CASES[case]
    with pytest.raises(gendr.GendrError) as e:
        make(convert)
    _check(e.value, kind, parts)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("case", list(CASES))
def test_tensor_values_fail_at_render_time(case, backend):
    make, kind, parts = CASES[case]
    camera = make(_tensor)  # tensors are not read when the camera is made
    with pytest.raises(gendr.GendrError) as e:
        gendr.Renderer(image_size=(8, 10), backend=backend).render(V, F, camera)
    _check(e.value, kind, parts)
    with pytest.raises(type(e.value)) as plain:
        make(_plain)
    assert str(plain.value) == str(e.value)  # one check, one message, wherever it runs


@pytest.mark.parametrize("backend", BACKENDS)
def test_tensor_requiring_grad_and_mixed_values(backend):
    """eye given as numbers and at as a tensor: only the render can compare them."""
    at = torch.tensor([0.0, 0.0, 3.0], dtype=torch.float64, requires_grad=True)
    camera = P(eye=(0.0, 0.0, 3.0), at=at)
    with pytest.raises(DegenerateCameraError, match=r"eye=\(0, 0, 3\) equals at=\(0, 0, 3\)"):
        gendr.Renderer(image_size=(8, 10), backend=backend).render(V, F, camera)


def test_drjit_arrays_are_checked_at_render_time():
    dr = pytest.importorskip("drjit")
    if "drjit" not in gendr.available_backends():
        pytest.skip("no drjit backend")
    from drjit.llvm.ad import Array3f64, Float64
    r = gendr.Renderer(image_size=(8, 10), backend="drjit")
    with pytest.raises(DegenerateCameraError, match=r"up=\(0, 1, 0\) is parallel"):
        r.render(V.numpy(), F.numpy(), P(eye=Array3f64(0.0, 2.0, 0.0)))
    with pytest.raises(ParameterError, match=r"xmag=0 must be > 0 \(batch element 1 of 2\)"):
        r.render(V.numpy(), F.numpy(), O(xmag=Float64([1.0, 0.0])))
    del dr


@pytest.mark.parametrize("backend", BACKENDS)
def test_nearly_degenerate_but_defined_views_render(backend):
    """Views close to the degenerate ones, but defined, pass and render finite images."""
    r = gendr.Renderer(image_size=(8, 10), backend=backend)
    ok = [gendr.orbit_camera(0.0, 89.9, 3.0), gendr.orbit_camera(0.0, 90.0, 3.0, up=(0.0, 0.0, -1.0)),
          P(eye=(0.0, 0.0, 1e-3), near=1e-4), P(eye=(1e-3, 3.0, 0.0)),
          gendr.orbit_camera(torch.tensor([0.0, 45.0], dtype=torch.float64), torch.tensor([10.0, 89.0], dtype=torch.float64), 3.0)]
    for camera in ok:
        img = r.render(V, F, camera)
        assert bool(torch.isfinite(torch.as_tensor(np.asarray(r.to_numpy(img)))).all())


def test_the_old_failures_are_typed_now():
    """up along the view failed with IndexError deep inside the torch backend; eye == at rendered."""
    for make, match in ((lambda: P(eye=torch.tensor([0.0, 3.0, 0.0], dtype=torch.float64)),
                         r"up=\(0, 1, 0\) is parallel to the viewing direction from eye=\(0, 3, 0\) to at=\(0, 0, 0\)"),
                        (lambda: P(eye=torch.zeros(3, dtype=torch.float64)),
                         r"eye=\(0, 0, 0\) equals at=\(0, 0, 0\)")):
        with pytest.raises(DegenerateCameraError, match=match) as e:
            gendr.Renderer(image_size=(8, 10)).render(V, F, make())
        assert type(e.value) is DegenerateCameraError and isinstance(e.value, ValueError)


def test_bool_complex_and_empty_camera_values():
    """True was accepted as fov_y = 1° (plain and as a tensor, both backends); a complex tensor lost
    its imaginary part; an empty NumPy batch passed construction (a tensor's failed at render time)."""
    for value in (True, [True, False], np.array([True])):
        with pytest.raises(ParameterError, match="fov_y=.* must be a number"):
            P(fov_y=value)
    for value in (torch.tensor(True), torch.tensor([True, False, True]), torch.tensor(40.0 + 0j)):
        with pytest.raises(ParameterError, match="must be a real tensor, got (bool|complex64)"):
            P(fov_y=value) if value.ndim == 0 else P(eye=value)
    with pytest.raises(gendr.ShapeError, match=r"fov_y has an empty batch: shape \[0\]"):
        P(fov_y=np.empty(0))
    with pytest.raises(gendr.ShapeError, match=r"eye has an empty batch: shape \[0, 3\]"):
        P(eye=np.zeros((0, 3)))
    if "drjit" in gendr.available_backends():
        from drjit.llvm.ad import Array3b, Bool
        with pytest.raises(ParameterError, match="fov_y must be a real tensor, got Bool"):
            P(fov_y=Bool(True))  # (the torch backend rendered it as 1°)
        with pytest.raises(ParameterError, match="eye must be a real tensor, got Array3b"):
            P(eye=Array3b(True, False, True))
