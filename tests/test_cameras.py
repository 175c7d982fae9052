"""Cameras through the renderer: equivalences, hand-computed projections, batches, gradients.

Images are non-square (H = 16, W = 20) on purpose. "Hard" renders use heaviside coverage with the
logical "or" (alpha exactly 0 or 1): a tiny triangle (a fraction of a pixel) around a world point
covers exactly the pixel whose centre the point projects to.
"""
from __future__ import annotations

import math

import pytest
import torch

import gendr

H, W = 16, 20
DT = torch.float64


def soft_renderer(**kw):
    kw.setdefault("blend", "softmax")
    return gendr.Renderer("logistic", "probabilistic", tau=0.05, image_size=(H, W), eps=0.0, gamma=0.05, **kw)


def hard_renderer():
    return gendr.Renderer("heaviside", "or", tau=0.05, image_size=(H, W), eps=0.0, blend=None)


def mesh():
    """Two overlapping coloured triangles at different depths, and a third one at the side."""
    v = torch.tensor([[-0.7, -0.5, 0.0], [0.6, -0.4, 0.1], [-0.1, 0.7, -0.1],
                      [-0.2, -0.2, 0.4], [0.7, 0.2, 0.3], [0.1, 0.6, 0.35],
                      [0.5, -0.8, -0.3], [0.9, -0.5, -0.2], [0.8, -0.1, -0.4]], dtype=DT)
    f = torch.tensor([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    c = torch.rand(9, 3, generator=torch.Generator().manual_seed(0), dtype=DT)
    return v, f, c


def tiny_triangle(point, size=0.01):
    """A small counter-clockwise triangle (seen from +Z... any winding counts) around a world point."""
    p = torch.as_tensor(point, dtype=DT)
    offs = torch.tensor([[-size, -size, 0.0], [size, -size, 0.0], [0.0, size, 0.0]], dtype=DT)
    return p + offs, torch.tensor([[0, 1, 2]])


def covered_pixels(camera, point, size=0.01):
    v, f = tiny_triangle(point, size)
    alpha = hard_renderer().render(v, f, camera)[0, ..., 3]
    assert set(alpha.unique().tolist()) <= {0.0, 1.0}
    return [tuple(ij) for ij in alpha.nonzero().tolist()]


# ------------------------------------------------------------------------------------------------
# equivalences
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("fov", [30.0, 55.0])
def test_intrinsics_equal_perspective(fov):
    """fx = fy = (H/2)/tan(fov_y/2), cx = W/2, cy = H/2 is the perspective camera (aspect W/H)."""
    v, f, c = mesh()
    eye, at = (0.3, 0.2, 2.8), (0.05, 0.0, 0.0)
    focal = (H / 2) / math.tan(math.radians(fov) / 2)
    persp = gendr.PerspectiveCamera(eye=eye, at=at, fov_y=fov)
    intr = gendr.IntrinsicsCamera(eye=eye, at=at, fx=focal, fy=focal, cx=W / 2, cy=H / 2)
    for r in (soft_renderer(), soft_renderer(blend="hard")):
        a, b = r.render(v, f, persp, vertex_colors=c), r.render(v, f, intr, vertex_colors=c)
        assert (a - b).abs().max() < 1e-12
    # and the hard silhouette is identical pixel for pixel
    assert torch.equal(hard_renderer().render(v, f, persp), hard_renderer().render(v, f, intr))


@pytest.mark.parametrize("d", [2.0, 3.5])
def test_orbit_zero_angles_is_eye_on_plus_z(d):
    v, f, c = mesh()
    a = soft_renderer().render(v, f, gendr.orbit_camera(0.0, 0.0, d), vertex_colors=c)
    b = soft_renderer().render(v, f, gendr.PerspectiveCamera(eye=(0.0, 0.0, d)), vertex_colors=c)
    assert (a - b).abs().max() < 1e-12


def test_orbit_orthographic_matches_orthographic_camera():
    v, f, c = mesh()
    a = soft_renderer().render(v, f, gendr.orbit_camera(0.0, 0.0, 3.0, orthographic=True, ymag=1.2, xmag=1.4),
                               vertex_colors=c)
    b = soft_renderer().render(v, f, gendr.OrthographicCamera(eye=(0.0, 0.0, 3.0), xmag=1.4, ymag=1.2),
                               vertex_colors=c)
    assert (a - b).abs().max() < 1e-12


# ------------------------------------------------------------------------------------------------
# projections computed by hand
# ------------------------------------------------------------------------------------------------
def _pixel_of_ndc(xn, yn):
    """(row, col) of the pixel containing NDC (xn, yn) (row 0 at the top)."""
    return math.floor((1 - yn) * H / 2), math.floor((xn + 1) * W / 2)


@pytest.mark.parametrize("row,col", [(3, 4), (12, 15), (8, 10), (0, 19)])
def test_perspective_projects_to_expected_pixel(row, col):
    fov, dist = 40.0, 3.0
    xn, yn = 2 * (col + 0.5) / W - 1, 1 - 2 * (row + 0.5) / H  # the pixel centre in NDC
    t = math.tan(math.radians(fov) / 2)
    # camera at (0, 0, 3) looking down −Z: a point at depth 3 (z = 0) with x_ndc = x/(3·t·W/H)
    point = (xn * dist * t * W / H, yn * dist * t, 0.0)
    assert covered_pixels(gendr.PerspectiveCamera(eye=(0.0, 0.0, dist), fov_y=fov), point, 0.005) == [(row, col)]


@pytest.mark.parametrize("cx,cy", [(10.5, 7.5), (13.5, 5.5), (2.5, 12.5)])
def test_intrinsics_principal_point_is_the_optical_axis(cx, cy):
    """The optical axis lands at column cx, row cy (pixel centres at half-integers)."""
    cam = gendr.IntrinsicsCamera(eye=(0.0, 0.0, 3.0), fx=30.0, fy=26.0, cx=cx, cy=cy)
    assert covered_pixels(cam, (0.0, 0.0, 0.0), 0.005) == [(math.floor(cy), math.floor(cx))]


@pytest.mark.parametrize("cx,cy", [(10.0, 8.0), (13.3, 5.6), (4.25, 12.75)])
@pytest.mark.parametrize("row,col", [(2, 3), (9, 16), (14, 11)])
def test_intrinsics_projects_to_expected_pixel(cx, cy, row, col):
    """A point at camera depth z lands at (u, v) = (cx + fx·x/z, cy − fy·y/z) in pixels."""
    fx, fy, depth = 30.0, 26.0, 3.0
    u, v = col + 0.5, row + 0.5  # the pixel centre
    point = ((u - cx) * depth / fx, (cy - v) * depth / fy, 0.0)
    cam = gendr.IntrinsicsCamera(eye=(0.0, 0.0, depth), fx=fx, fy=fy, cx=cx, cy=cy)
    assert covered_pixels(cam, point, 0.005) == [(row, col)]


@pytest.mark.parametrize("xmag,ymag", [(1.0, 1.0), (2.0, 0.8)])
def test_orthographic_projects_to_expected_pixel(xmag, ymag):
    cam = gendr.OrthographicCamera(eye=(0.0, 0.0, 5.0), xmag=xmag, ymag=ymag)
    for row, col in [(2, 17), (13, 3)]:
        xn, yn = 2 * (col + 0.5) / W - 1, 1 - 2 * (row + 0.5) / H
        assert covered_pixels(cam, (xn * xmag, yn * ymag, -1.0), 0.005) == [(row, col)]


def test_orbit_azimuth_90_looks_from_plus_x():
    """azimuth 90: the eye is on +X; world −Z is to the right, +Y up."""
    cam = gendr.orbit_camera(90.0, 0.0, 3.0, fov_y=40.0)
    t = math.tan(math.radians(20.0))
    row, col = 5, 14
    xn, yn = 2 * (col + 0.5) / W - 1, 1 - 2 * (row + 0.5) / H
    point = (0.0, yn * 3.0 * t, -xn * 3.0 * t * W / H)
    assert covered_pixels(cam, point, 0.005) == [(row, col)]


def test_orbit_elevation_90_looks_down():
    """elevation 90 with up = −Z: the eye is above, looking down −Y (image up = world −Z)."""
    cam = gendr.orbit_camera(0.0, 90.0, 3.0, up=(0.0, 0.0, -1.0), fov_y=40.0)
    t = math.tan(math.radians(20.0))
    row, col = 11, 6
    xn, yn = 2 * (col + 0.5) / W - 1, 1 - 2 * (row + 0.5) / H
    point = (xn * 3.0 * t * W / H, 0.0, -yn * 3.0 * t)
    pts = covered_pixels(cam, point, 0.005)
    assert pts == [(row, col)]


def test_orthographic_extents():
    """The image shows exactly [−xmag, xmag] × [−ymag, ymag]: a quad that size covers every pixel
    centre; shrunk by 3/4 of a pixel on every side, it misses the border pixels."""
    xmag, ymag = 1.7, 0.9
    cam = gendr.OrthographicCamera(eye=(0.0, 0.0, 2.0), xmag=xmag, ymag=ymag)

    def quad(a, b):
        v = torch.tensor([[-a, -b, 0.0], [a, -b, 0.0], [a, b, 0.0], [-a, b, 0.0]], dtype=DT)
        return v, torch.tensor([[0, 1, 2], [0, 2, 3]])

    alpha = hard_renderer().render(*quad(xmag, ymag), cam)[0, ..., 3]
    assert alpha.min() == 1.0
    alpha = hard_renderer().render(*quad(xmag * (1 - 1.5 / W), ymag * (1 - 1.5 / H)), cam)[0, ..., 3]
    assert alpha[1:-1, 1:-1].min() == 1.0
    assert alpha[0].max() == 0 and alpha[-1].max() == 0 and alpha[:, 0].max() == 0 and alpha[:, -1].max() == 0


# ------------------------------------------------------------------------------------------------
# batches and gradients
# ------------------------------------------------------------------------------------------------
def test_batched_cameras_equal_separate_renders():
    v, f, c = mesh()
    az = torch.tensor([0.0, 30.0, -45.0, 120.0], dtype=DT)
    el = torch.tensor([0.0, 10.0, -20.0, 35.0], dtype=DT)
    r = soft_renderer()
    batched = r.render(v, f, gendr.orbit_camera(az, el, 3.0), vertex_colors=c)
    assert batched.shape == (4, H, W, 4)
    for k in range(4):
        single = r.render(v, f, gendr.orbit_camera(float(az[k]), float(el[k]), 3.0), vertex_colors=c)
        assert (batched[k] - single[0]).abs().max() < 1e-12, k
    # a batch of eyes, with a batch of 4 meshes as well
    eyes = torch.tensor([[0.0, 0.0, 3.0], [0.5, 0.2, 2.8], [-0.4, 0.3, 3.2], [0.1, -0.6, 2.9]], dtype=DT)
    vb = v[None] + 0.05 * torch.randn(4, *v.shape, generator=torch.Generator().manual_seed(1), dtype=DT)
    batched = r.render(vb, f, gendr.PerspectiveCamera(eye=eyes), vertex_colors=c)
    for k in range(4):
        single = r.render(vb[k], f, gendr.PerspectiveCamera(eye=tuple(eyes[k].tolist())), vertex_colors=c)
        assert (batched[k] - single[0]).abs().max() < 1e-12, k


@pytest.mark.parametrize("backend", ["torch", "drjit"])
def test_batched_lens_parameters_equal_separate_renders(backend):
    """A batch of fields of view (and of orthographic magnifications) with a batch of orbit eyes
    (torch used to broadcast [B, 1] lens parameters against [B, F, K] corners and fail)."""
    if backend == "drjit":
        pytest.importorskip("drjit")
    v, f, c = mesh()
    r = gendr.Renderer("logistic", "probabilistic", tau=0.02, image_size=(H, W), backend=backend)
    az = torch.tensor([10.0, 70.0, -40.0], dtype=DT)
    fov = torch.tensor([30.0, 50.0, 65.0], dtype=DT)
    mag = torch.tensor([1.2, 1.5, 0.9], dtype=DT)
    for batched_cam, single in (
            (gendr.orbit_camera(az, 20.0, 3.0, fov_y=fov),
             lambda k: gendr.orbit_camera(float(az[k]), 20.0, 3.0, fov_y=float(fov[k]))),
            (gendr.orbit_camera(az, 20.0, 3.0, orthographic=True, ymag=mag),
             lambda k: gendr.orbit_camera(float(az[k]), 20.0, 3.0, orthographic=True, ymag=float(mag[k])))):
        batched = r.render(v, f, batched_cam, vertex_colors=c)
        for k in range(3):
            one = r.render(v, f, single(k), vertex_colors=c)
            assert (batched[k] - one[0]).abs().max() < 1e-12, k  # float64, as the sibling batch tests


@pytest.mark.parametrize("kind", ["eye", "fov_y", "orbit", "intrinsics", "xmag"])
def test_gradients_flow_to_camera_parameters(kind):
    v, f, c = mesh()
    p = {"eye": [0.1, 0.0, 3.0], "fov_y": 40.0, "orbit": [15.0, 10.0, 3.0], "intrinsics": [20.0, 10.5],
         "xmag": [1.3, 1.0]}[kind]
    p = torch.tensor(p, dtype=DT, requires_grad=True)
    cam = {"eye": lambda: gendr.PerspectiveCamera(eye=p),
           "fov_y": lambda: gendr.PerspectiveCamera(fov_y=p),
           "orbit": lambda: gendr.orbit_camera(p[0], p[1], p[2]),
           "intrinsics": lambda: gendr.IntrinsicsCamera(eye=(0.0, 0.0, 3.0), fx=p[0], fy=p[0], cx=p[1], cy=8.0),
           "xmag": lambda: gendr.OrthographicCamera(xmag=p[0], ymag=p[1])}[kind]()
    img = soft_renderer().render(v, f, cam, vertex_colors=c)
    w = torch.randn(img.shape, generator=torch.Generator().manual_seed(2), dtype=DT)
    (g,) = torch.autograd.grad((img * w).sum(), p)
    assert torch.isfinite(g).all()
    assert (g != 0).all(), g


def test_float32_camera_parameters_with_float64_vertices():
    """Camera tensors of another dtype are converted to the vertices' dtype (gradients flow back)."""
    v, f, c = mesh()
    eye = torch.tensor([0.1, 0.0, 3.0], dtype=torch.float32, requires_grad=True)
    img = soft_renderer().render(v, f, gendr.PerspectiveCamera(eye=eye), vertex_colors=c)
    assert img.dtype == DT
    img.sum().backward()
    assert eye.grad is not None and eye.grad.dtype == torch.float32 and torch.isfinite(eye.grad).all()


def test_a_drjit_array3f_pose_is_a_batch_of_its_width():
    """A Dr.Jit Array3f has shape (3, N): N eyes, not a batch of 3 (it was read as batch 3, so
    batch-2 vertices or colours were refused). It renders as the same eyes given as a [2, 3] array."""
    import numpy as np
    pytest.importorskip("drjit")
    from drjit.llvm.ad import Array3f, Float
    from gendr import scenes
    m = scenes.icosphere(1)
    verts = np.stack([m.vertices, 0.9 * m.vertices])
    eyes = Array3f(Float(0.0, 3.0), Float(0.0, 0.0), Float(3.0, 0.0))
    assert gendr.PerspectiveCamera(eye=eyes).batch_size() == 2
    assert gendr.PerspectiveCamera(eye=Array3f(0.0, 0.0, 3.0)).batch_size() == 1
    r = gendr.Renderer(image_size=8, backend="drjit")
    got = r.render(verts, m.faces, gendr.PerspectiveCamera(eye=eyes), vertex_colors=np.ones((2, len(m.vertices), 3)))
    want = r.render(verts, m.faces, gendr.PerspectiveCamera(eye=np.array([[0.0, 0.0, 3.0], [3.0, 0.0, 0.0]])))
    assert np.asarray(got).shape == (2, 8, 8, 4)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
