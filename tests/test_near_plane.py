"""Faces crossing a small near plane, in float32.

A face clipped by the near plane gets corners at ~x/near screen units (1e5 at near = 1e-5). Two
things made float32 renders of such faces wrong: the clipped corner's depth was interpolated, so
near ≲ ulp(|z|) rounded it to 0 or past the eye (near = 1e-7: the whole image wrong), and a pixel's
distance to an edge was measured from corner k, with a rounding error ~ulp(|corner|) (near = 1e-3:
alpha off by 7e-4; 1e-5: 0.06). Now the clipped corner lies on the plane exactly, and an edge from a
far corner to a nearer one is measured from the nearer one (``FAR_CORNER``). The gradients of that
rule (the corner parts of a swapped edge) are checked by test_gradcheck.py and
test_drjit_gradcheck.py, whose scene has such an edge."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

import gendr

torch = pytest.importorskip("torch")

# one face from in front of the eye (z = 0, eye at z = 3) to behind it: clipped to a quad
TRIANGLE = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 5.0]])


def _backends():
    return ["torch"] + (["drjit"] if importlib.util.find_spec("drjit") else [])


def _render(backend, dtype, near, grad=False):
    r = gendr.Renderer("logistic", "probabilistic", tau=0.01, image_size=64, backend=backend)
    v = torch.tensor(TRIANGLE, dtype=dtype, requires_grad=grad)
    img = r.render(v, [[0, 1, 2]], gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), near=near))[0, ..., 3]
    if grad:
        (img * torch.linspace(0.0, 1.0, 64, dtype=dtype)).sum().backward()
        return img.detach().double(), v.grad.double()
    return img.detach().double(), None


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("near", [1e-3, 1e-5, 1e-7])
def test_float32_renders_a_face_through_a_small_near_plane_like_float64(backend, near):
    """Tolerance 1e-5: float32 rounding of an unclipped render of this kind is ~1e-6 (coverage slope
    F'(0)/τ = 25 per screen unit times distances rounded at ~1e-7 units, measured 1.2e-6 at
    near = 0.01, where nothing is far); the errors this catches were 7e-4 and larger."""
    a32, _ = _render(backend, torch.float32, near)
    a64, _ = _render(backend, torch.float64, near)
    assert float(a64.mean()) > 0.9  # the face covers most of the image
    assert float((a32 - a64).abs().max()) <= 1e-5


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("near,tolerance", [(1e-5, 1e-4), (1e-7, 1e-3)])
def test_float32_gradients_through_a_small_near_plane_match_float64(backend, near, tolerance):
    """Relative error of the float32 vertex gradient. Measured after the change: ~1e-5 at both
    (drjit 7e-5 at 1e-7; the same ~1e-5 as an unclipped render: float32 sums of 4,096 pixel
    terms), before it 3.2e-4 at 1e-5 and NaN (torch) or 4e17 (drjit) at 1e-7."""
    _, g32 = _render(backend, torch.float32, near, grad=True)
    _, g64 = _render(backend, torch.float64, near, grad=True)
    assert float((g32 - g64).norm() / g64.norm()) <= tolerance
