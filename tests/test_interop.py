"""Camera interop: kornia PinholeCamera both ways, PyTorch3D look-at + FoV (hand-computed)."""
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import gendr  # noqa: E402
from gendr import interop  # noqa: E402
from gendr.errors import ParameterError  # noqa: E402


def _points(n=50, seed=0):
    rng = np.random.default_rng(seed)
    return torch.as_tensor(rng.uniform(-0.8, 0.8, (n, 3)))


def _cameras():
    """A batched perspective orbit camera and a batched intrinsics camera with a free pose."""
    persp = gendr.orbit_camera(torch.tensor([0.0, 35.0, -120.0]), torch.tensor([10.0, -25.0, 60.0]),
                               torch.tensor([3.0, 2.5, 4.0]), at=(0.1, -0.2, 0.05), fov_y=torch.tensor([40.0, 55.0, 30.0]))
    intr = gendr.IntrinsicsCamera(eye=torch.tensor([[2.0, 1.0, 2.5], [-1.0, 2.0, -3.0]]), at=(0.0, 0.1, 0.0),
                                  up=(0.1, 1.0, 0.0), fx=torch.tensor([30.0, 45.0]), fy=torch.tensor([32.0, 40.0]),
                                  cx=torch.tensor([20.0, 14.5]), cy=torch.tensor([11.0, 13.0]))
    return [persp, intr]


@pytest.mark.parametrize("k", [0, 1])
def test_kornia_roundtrip_same_projections(k):
    kornia = pytest.importorskip("kornia")  # noqa: F841
    H, W = 24, 40
    cam = _cameras()[k]
    pts = _points()
    ours = interop.project_points(cam, pts, (H, W))  # [B, N, 2], gendr pixel convention
    B = ours.shape[0]
    pin = interop.to_kornia(cam, (H, W))
    assert pin.intrinsics.shape == (B, 4, 4) and pin.batch_size == B
    theirs = pin.project(pts[None].expand(B, -1, -1))  # OpenCV pixel convention (centres at integers)
    np.testing.assert_allclose((theirs + 0.5).numpy(), ours.numpy(), rtol=0, atol=1e-9)
    back = interop.from_kornia(pin)
    np.testing.assert_allclose(interop.project_points(back, pts, (H, W)).numpy(), ours.numpy(), rtol=0, atol=1e-9)


def test_cameras_with_one_batched_parameter():
    """A batched azimuth beside a scalar elevation, a batched cx or xmag beside scalar others: each
    batch element projects as the unbatched camera with its values (these raised torch's "Sizes of
    tensors must match" / "stack expects each tensor to be equal size" before)."""
    pts = _points(5)
    cases = [
        (gendr.orbit_camera(np.array([0.0, 40.0]), 10.0, 3.0),
         [gendr.orbit_camera(0.0, 10.0, 3.0), gendr.orbit_camera(40.0, 10.0, 3.0)]),
        (gendr.IntrinsicsCamera(eye=(0.0, 0.0, 3.0), fx=20.0, fy=20.0, cx=[8.0, 11.0], cy=6.0),
         [gendr.IntrinsicsCamera(eye=(0.0, 0.0, 3.0), fx=20.0, fy=20.0, cx=c, cy=6.0) for c in (8.0, 11.0)]),
        (gendr.OrthographicCamera(eye=(0.0, 0.0, 3.0), xmag=[1.0, 2.0], ymag=1.0),
         [gendr.OrthographicCamera(eye=(0.0, 0.0, 3.0), xmag=x, ymag=1.0) for x in (1.0, 2.0)]),
    ]
    for batched, singles in cases:
        got = interop.project_points(batched, pts, (12, 16))
        assert got.shape == (2, 5, 2)
        for b, single in enumerate(singles):
            np.testing.assert_allclose(got[b].numpy(), interop.project_points(single, pts, (12, 16))[0].numpy(),
                                       rtol=0, atol=1e-12)
        R, t = interop.world_to_view(batched)
        assert R.shape[0] == t.shape[0] in (1, 2)
        if not batched.orthographic:
            pytest.importorskip("kornia")
            pin = interop.to_kornia(batched, (12, 16))
            np.testing.assert_allclose((pin.project(pts[None].expand(2, -1, -1)) + 0.5).numpy(), got.numpy(),
                                       rtol=0, atol=1e-9)


def test_interop_input_errors():
    from gendr.errors import DTypeError, InputValueError, ShapeError
    cam = gendr.orbit_camera(np.array([0.0, 40.0, 80.0]), 10.0, 3.0)
    with pytest.raises(ShapeError, match="points have batch size 2, the camera 3"):
        interop.project_points(cam, torch.zeros(2, 4, 3), 8)
    with pytest.raises(ShapeError, match=r"\[N, 3\] or \[B, N, 3\], got \[4, 2\]"):
        interop.project_points(cam, torch.zeros(4, 2), 8)
    with pytest.raises(DTypeError, match="float32 or float64 torch tensor, got ndarray"):
        interop.project_points(cam, np.zeros((4, 3)), 8)
    with pytest.raises(DTypeError, match="got Tensor of torch.float16"):  # (was projected in float16)
        interop.project_points(cam, torch.zeros(4, 3, dtype=torch.float16), 8)
    pts = torch.zeros(4, 3)
    pts[2, 1] = float("nan")
    with pytest.raises(InputValueError, match=r"points\[2, 1\] = nan"):  # (was projected to NaN)
        interop.project_points(cam, pts, 8)
    for bad in (torch.int32, torch.int64, "float32"):  # an integer dtype truncated fx and cx silently
        with pytest.raises(DTypeError, match=f"dtype={bad!r} must be torch.float32 or torch.float64"):
            interop.world_to_view(cam, dtype=bad)
        with pytest.raises(DTypeError, match=f"dtype={bad!r} must be"):
            interop.to_kornia(cam, 8, dtype=bad)
    for size in (0, -4, (8, 0)):
        with pytest.raises(ParameterError, match="is out of domain: expected > 0"):
            interop.project_points(cam, torch.zeros(4, 3), size)
    assert interop.project_points(cam, torch.zeros(4, 3), np.int64(8)).shape == (3, 4, 2)


def test_kornia_conversion_is_differentiable_and_renders_the_same():
    pytest.importorskip("kornia")
    az = torch.tensor(30.0, dtype=torch.float64, requires_grad=True)
    cam = gendr.orbit_camera(az, 20.0, 3.0, fov_y=45.0)
    pin = interop.to_kornia(cam, (16, 20))
    pin.extrinsics.sum().backward()
    assert az.grad is not None and torch.isfinite(az.grad)
    back = interop.from_kornia(interop.to_kornia(gendr.orbit_camera(30.0, 20.0, 3.0, fov_y=45.0), (16, 20)))
    from gendr.scenes import icosphere
    m = icosphere(1)
    r = gendr.Renderer("logistic", "probabilistic", tau=0.05, image_size=(16, 20), blend=None)
    a = r.render(torch.as_tensor(m.vertices), m.faces, gendr.orbit_camera(30.0, 20.0, 3.0, fov_y=45.0))
    b = r.render(torch.as_tensor(m.vertices), m.faces, back)
    np.testing.assert_allclose(b.numpy(), a.numpy(), atol=1e-9)


def test_kornia_rejects_what_it_cannot_express():
    pytest.importorskip("kornia")
    with pytest.raises(ParameterError, match="OrthographicCamera"):
        interop.to_kornia(gendr.orbit_camera(0.0, 0.0, 3.0, orthographic=True), (8, 8))
    pin = interop.to_kornia(gendr.orbit_camera(0.0, 0.0, 3.0), (8, 8))
    pin.intrinsics[:, 0, 1] = 0.3
    with pytest.raises(ParameterError, match="skew"):
        interop.from_kornia(pin)
    # a reflection has RRᵀ = I too; it was taken, and its camera mirrored x
    pin = interop.to_kornia(gendr.orbit_camera(20.0, 10.0, 3.0), (8, 8))
    pin.extrinsics[:, 0, :3] *= -1.0
    with pytest.raises(ParameterError, match=r"a reflection \(det = \[-1"):
        interop.from_kornia(pin)
    for scale in (1.001, float("nan")):
        pin = interop.to_kornia(gendr.orbit_camera(20.0, 10.0, 3.0), (8, 8), dtype=torch.float32)
        pin.extrinsics[:, :3, :3] *= scale
        with pytest.raises(ParameterError, match="not a rotation"):
            interop.from_kornia(pin)


def test_from_kornia_float32_rotations_and_far_cameras():
    """Two float32 cases: products of float32 rotations reach |RRᵀ − I| ≈ 1.2e-6, past the old
    fixed 1e-6 bound; and a camera 1e4 units from the origin (a calibration in millimetres) lost
    0.1 px through at = eye + forward. kornia's own float32 projection errs by ~1e-4 px here."""
    kornia = pytest.importorskip("kornia")
    g = torch.Generator().manual_seed(0)
    R = kornia.geometry.conversions.axis_angle_to_rotation_matrix(torch.randn(3 * 3000, 3, generator=g) * 2)
    R3 = R[:3000] @ R[3000:6000] @ R[6000:]
    err = (R3 @ R3.transpose(1, 2) - torch.eye(3)).abs().amax((1, 2))
    assert float(err.max()) > 1e-6  # the case exists in this sample
    E = torch.eye(4).repeat(len(R3), 1, 1)
    E[:, :3, :3], E[:, :3, 3] = R3, torch.tensor([0.0, 0.0, 3.0])
    K = torch.eye(4).repeat(len(R3), 1, 1)
    K[:, 0, 0] = K[:, 1, 1] = 50.0
    K[:, 0, 2] = K[:, 1, 2] = 32.0
    cam = interop.from_kornia(kornia.geometry.camera.PinholeCamera(K, E, torch.full((3000,), 64.0),
                                                                    torch.full((3000,), 64.0)))
    assert cam.batch_size() == 3000
    H = W = 1000
    for d in (1e4, 3e7):  # 3e7: at met eye in float32 (DegenerateCameraError)
        cam64 = gendr.IntrinsicsCamera(eye=(d * 0.6, d * 0.3, d * 0.742), fx=1000.0, fy=1000.0, cx=500.0, cy=500.0,
                                       near=1.0, far=1e9)
        pts = torch.tensor([[10.0, 20.0, -30.0], [0.0, 0.0, 0.0]], dtype=torch.float64) * (d / 1e3)
        truth = interop.project_points(cam64, pts, (H, W))[0]
        back = interop.from_kornia(interop.to_kornia(cam64, (H, W), dtype=torch.float32))
        got = interop.project_points(back, pts.float(), (H, W))[0].double()
        assert float((got - truth).abs().max()) < 2e-3  # px; 20x kornia's float32 error, 50x below the old one


def _pytorch3d_pixels(pts, dist, elev, azim, fov, H, W, at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)):
    """PyTorch3D's pipeline written out from its documentation (look_at_view_transform,
    FoVPerspectiveCameras with aspect_ratio 1, NDC +X left / +Y up with the shorter side in [−1, 1],
    screen (0, 0) the top-left corner of the top-left pixel), in NumPy float64."""
    e, a = math.radians(elev), math.radians(azim)
    at, up = np.asarray(at), np.asarray(up)
    C = dist * np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)]) + at
    z = (at - C) / np.linalg.norm(at - C)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], 1)  # columns: the camera axes in world coordinates
    T = -R.T @ C
    Xv = pts @ R + T  # row vectors, as PyTorch3D
    t = math.tan(math.radians(fov) / 2)
    xn, yn = Xv[:, 0] / (Xv[:, 2] * t), Xv[:, 1] / (Xv[:, 2] * t)
    s = min(H, W) / 2.0
    return np.stack([W / 2.0 - xn * s, H / 2.0 - yn * s], -1)


@pytest.mark.parametrize("H,W", [(20, 20), (16, 28), (30, 18)])
def test_pytorch3d_look_at_matches_hand_computed_projection(H, W):
    pts = _points(40, 1).numpy()
    for dist, elev, azim, fov, at, up in [(2.7, 20.0, 30.0, 60.0, (0, 0, 0), (0, 1, 0)),
                                          (3.5, -40.0, 160.0, 45.0, (0.1, 0.2, -0.1), (0.2, 1.0, 0.1))]:
        cam = interop.from_pytorch3d_look_at(dist, elev, azim, fov=fov, at=at, up=up, image_size=(H, W))
        ours = interop.project_points(cam, torch.as_tensor(pts), (H, W))[0].numpy()
        np.testing.assert_allclose(ours, _pytorch3d_pixels(pts, dist, elev, azim, fov, H, W, at, up), atol=1e-9)


def test_pytorch3d_eye_and_radians():
    pts = _points(10, 2)
    # lists with degrees=False (raised TypeError: can't multiply sequence) equal the degree form
    c = interop.from_pytorch3d_look_at(2.0, [math.radians(10), 0.0], [math.radians(50), 1.0],
                                      fov=math.radians(60), degrees=False)
    np.testing.assert_allclose(c.eye.azimuth, [50.0, math.degrees(1.0)])
    # a bad fov is named as given, not as the fov_y it converts to for H > W (was "fov_y=-169.92")
    with pytest.raises(ParameterError, match=r"fov=200 must be a field of view in \(0, 180\) degrees"):
        interop.from_pytorch3d_look_at(fov=200, image_size=(32, 16))
    # in radians, 4 rad = 229°: named in the unit given, whatever the image's shape (said "(0, 180)
    # degrees" of fov=4.0 for H > W, and "fov_y=229.18" for H <= W)
    for size in ((32, 16), (16, 32), None):
        with pytest.raises(ParameterError, match=r"fov=4.0 must be a field of view in \(0, π\) radians"):
            interop.from_pytorch3d_look_at(fov=4.0, degrees=False, image_size=size)
    a = interop.from_pytorch3d_look_at(2.0, math.radians(10), math.radians(50), fov=math.radians(50), degrees=False)
    b = interop.from_pytorch3d_look_at(2.0, 10.0, 50.0, fov=50.0)
    np.testing.assert_allclose(interop.project_points(a, pts, 16).numpy(), interop.project_points(b, pts, 16).numpy(),
                               atol=1e-9)


def test_spec_layer_does_not_import_kornia_or_backends():
    import subprocess
    import sys
    code = ("import sys, gendr, gendr.interop; bad = [m for m in ('torch', 'kornia', 'gendr_torch', 'drjit') "
            "if m in sys.modules]; print(bad); sys.exit(1 if bad else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
