"""Interop with other libraries' cameras: kornia's ``PinholeCamera`` and PyTorch3D's look-at + FoV.

Nothing here is imported by ``gendr`` itself; torch and kornia are imported inside the functions
(the spec layer stays free of both). All functions are differentiable w.r.t. their tensor inputs.

Conventions (docs/conventions.md, "Interop"):

* gendr (OpenGL): camera frame +X right, +Y up, looking along −Z; pixel (row i, col j) has its
  centre at image coordinates (j + ½, i + ½) (column, row; rows from the top).
* kornia (OpenCV): camera frame +X right, +Y down, looking along +Z, i.e. (x, −y, −z) of gendr's;
  ``K`` maps to pixel coordinates whose integer values are pixel *centres*
  (``kornia.utils.create_meshgrid(..., normalized_coordinates=False)``), so kornia's principal
  point is gendr's minus ½ pixel: cx_k = cx − ½, cy_k = cy − ½. Extrinsics: world → camera, 4×4.
* PyTorch3D: camera frame +X left, +Y up, looking along +Z, i.e. (−x, y, −z) of gendr's, the same
  image (not mirrored). NDC +X left, +Y up; the *shorter* image side spans [−1, 1].
"""
from __future__ import annotations

import math

import numpy as np

from .cameras import Camera, IntrinsicsCamera, PerspectiveCamera
from .errors import DTypeError, InputValueError, ParameterError, ShapeError
from .renderer import image_size_pair


def _torch():
    import torch
    return torch


def _float_dtype(dtype, owner):
    """``dtype`` (None: float64) if it is torch.float32 or torch.float64, else DTypeError: an
    integer dtype would truncate focal lengths and principal points without a word."""
    torch = _torch()
    if dtype is None:
        return torch.float64
    if dtype not in (torch.float32, torch.float64):
        raise DTypeError(f"{owner}: dtype={dtype!r} must be torch.float32 or torch.float64")
    return dtype


def _intrinsics(camera, H, W, dtype, device):
    """(fx, fy, cx, cy) in gendr's pixel convention, [Bc] tensors."""
    torch = _torch()

    def t(v):
        return (v.to(dtype=dtype, device=device) if isinstance(v, torch.Tensor)
                else torch.as_tensor(v, dtype=dtype, device=device)).reshape(-1)
    if isinstance(camera, IntrinsicsCamera):  # a batched cx beside a scalar fx: [Bc] each
        return torch.broadcast_tensors(t(camera.fx), t(camera.fy), t(camera.cx), t(camera.cy))
    if isinstance(camera, PerspectiveCamera):
        f = (H / 2.0) / torch.tan(t(camera.fov_y) * (math.pi / 360.0))
        return f, f, torch.full_like(f, W / 2.0), torch.full_like(f, H / 2.0)
    raise ParameterError(f"to_kornia needs a PerspectiveCamera or an IntrinsicsCamera (a pinhole), got "
                         f"{type(camera).__name__}")


def world_to_view(camera: Camera, dtype=None, device=None):
    """gendr's world → camera (OpenGL frame) transform as ``(R [Bc, 3, 3], t [Bc, 3])``:
    x_view = R·x_world + t. Differentiable w.r.t. tensor pose parameters.

    ``dtype``: torch.float32 or torch.float64 (default; else DTypeError); ``device``: torch device (default CPU); Bc: the
    camera's batch size (1 for an unbatched camera). Needs torch and the torch backend.

    >>> import gendr
    >>> from gendr.interop import world_to_view
    >>> R, t = world_to_view(gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0)))
    >>> R.shape, R.dtype, [float(v) + 0.0 for v in t[0]]
    (torch.Size([1, 3, 3]), torch.float64, [0.0, 0.0, -3.0])
    """
    torch = _torch()
    from gendr_torch.ops import torch_ops as ops  # (lazy: the spec layer imports no backend)
    from gendr_torch.raster import camera_tensors
    dtype = _float_dtype(dtype, "world_to_view")
    P, _ = camera_tensors(camera, dtype, device or "cpu")
    r, u, b, e = camera.basis(ops, P)  # each a 3-tuple of [Bc|1, 1]: broadcast (a batched eye, a fixed up)
    c = torch.broadcast_tensors(*r, *u, *b, *e)
    R = torch.stack([torch.cat(c[k:k + 3], -1) for k in (0, 3, 6)], -2)  # rows r, u, b: [Bc, 3, 3]
    eye = torch.cat(c[9:12], -1)  # [Bc, 3]
    return R, -(R @ eye[..., None])[..., 0]


def project_points(camera: Camera, points, image_size):
    """Pixel coordinates (column, row) of world points in gendr's convention (pixel centres at
    j + ½, rows from the top), by the same spec formulas the backends project with:
    ``points`` [B?, N, 3] float32/float64 tensor (finite; else DTypeError / InputValueError)
    → [B, N, 2] (differentiable). Points behind a perspective
    camera project mirrored, as with any pinhole formula.

    ``image_size``: (H, W) or int. The result has the points' dtype and device; it is
    differentiable w.r.t. the points and the camera's tensor parameters.

    >>> import torch, gendr
    >>> from gendr.interop import project_points
    >>> cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0))
    >>> project_points(cam, torch.tensor([[0.0, 0.0, 0.0]]), 8)  # the image centre
    tensor([[[4., 4.]]])
    """
    torch = _torch()
    from gendr_torch.ops import torch_ops as ops
    from gendr_torch.raster import camera_tensors
    H, W = image_size_pair(image_size, "project_points")
    if not isinstance(points, torch.Tensor) or points.dtype not in (torch.float32, torch.float64):
        raise DTypeError(f"project_points: points must be a float32 or float64 torch tensor, got "
                         f"{type(points).__name__}{'' if not hasattr(points, 'dtype') else ' of ' + str(points.dtype)}")
    if points.ndim not in (2, 3) or points.shape[-1] != 3:
        raise ShapeError(f"project_points: points must be [N, 3] or [B, N, 3], got {list(points.shape)}")
    bad = (~torch.isfinite(points.detach())).nonzero()
    if len(bad):
        i = tuple(int(v) for v in bad[0])
        raise InputValueError(f"project_points: points must be finite; points{list(i)} = {float(points[i])}")
    pts = points if points.ndim == 3 else points[None]
    Bc = camera.batch_size()
    if pts.shape[0] not in (1, Bc) and Bc != 1:
        raise ShapeError(f"project_points: points have batch size {pts.shape[0]}, the camera {Bc}; give 1 or {Bc}")
    P, _ = camera_tensors(camera, pts.dtype, pts.device)
    xv, yv, zv = camera.view_coords(ops, P, *pts.unbind(-1))
    sx, sy, ox, oy = camera.ndc_affine(ops, P, H, W)
    if camera.orthographic:
        nx, ny = sx * xv + ox, sy * yv + oy
    else:
        nx, ny = sx * xv / -zv + ox, sy * yv / -zv + oy
    return torch.stack(torch.broadcast_tensors((nx + 1.0) * (W / 2.0), (1.0 - ny) * (H / 2.0)), -1)


_CV = (1.0, -1.0, -1.0)  # OpenGL camera frame -> OpenCV camera frame (and back): diag(1, −1, −1)


def to_kornia(camera: Camera, image_size, *, dtype=None, device=None):
    """A ``kornia.geometry.camera.PinholeCamera`` that projects world points to the same pixels.

    camera : a :class:`PerspectiveCamera` or :class:`IntrinsicsCamera` (batched or not; tensors may
        require grad: the result's matrices are differentiable w.r.t. them).
    image_size : (H, W) or int.
    dtype : torch.float32 or torch.float64 (default), the matrices' dtype; device : torch device.

    Returns a PinholeCamera with intrinsics/extrinsics [B, 4, 4], height/width [B] (B: the camera's
    batch size). Its ``project`` gives pixel coordinates = gendr's (column, row) − ½.

    Raises :class:`~gendr.errors.ParameterError` for an orthographic camera or a bad
    ``image_size``, :class:`~gendr.errors.DTypeError` for another dtype. Needs torch and kornia.

    >>> import gendr
    >>> from gendr.interop import to_kornia
    >>> pc = to_kornia(gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0)), 8)
    >>> type(pc).__name__, pc.intrinsics.shape, pc.extrinsics.dtype, float(pc.height[0])
    ('PinholeCamera', torch.Size([1, 4, 4]), torch.float64, 8.0)
    """
    torch = _torch()
    from kornia.geometry.camera import PinholeCamera
    H, W = image_size_pair(image_size, "to_kornia")
    dtype = _float_dtype(dtype, "to_kornia")
    R, t = world_to_view(camera, dtype, device)
    fx, fy, cx, cy = _intrinsics(camera, H, W, dtype, R.device)
    B = max(R.shape[0], fx.shape[0])
    flip = torch.tensor(_CV, dtype=dtype, device=R.device)
    E = torch.zeros(B, 4, 4, dtype=dtype, device=R.device)
    E[:, :3, :3] = flip[:, None] * R
    E[:, :3, 3] = flip * t
    E[:, 3, 3] = 1.0
    K = torch.zeros(B, 4, 4, dtype=dtype, device=R.device)
    K[:, 0, 0], K[:, 1, 1] = fx.expand(B), fy.expand(B)
    K[:, 0, 2], K[:, 1, 2] = (cx - 0.5).expand(B), (cy - 0.5).expand(B)
    K[:, 2, 2] = K[:, 3, 3] = 1.0
    hw = torch.ones(B, dtype=dtype, device=R.device)
    return PinholeCamera(K, E, hw * H, hw * W)


def from_kornia(pinhole, *, near=0.1, far=100.0) -> IntrinsicsCamera:
    """A batched :class:`IntrinsicsCamera` ([B] intrinsics, [B, 3] eye/at/up) equivalent to a
    ``kornia.geometry.camera.PinholeCamera`` (render it at ``image_size=(int(pinhole.height[0]),
    int(pinhole.width[0]))``). Differentiable w.r.t. the pinhole's tensors. Needs zero skew and a
    rotation in the extrinsics (a proper one, det +1, to max(1e-6, 100 ulp) of the dtype; raises
    :class:`ParameterError` otherwise; :class:`ShapeError` unless intrinsics and extrinsics are
    [B, 4, 4]). The camera's values are tensors of the pinhole's dtype and device.

    kornia has no clip planes: give ``near``/``far`` (view depths) for the scene, or the
    defaults apply (0.1, 100).

    >>> import torch, gendr
    >>> from gendr.interop import from_kornia, project_points, to_kornia
    >>> cam = from_kornia(to_kornia(gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0)), 8))
    >>> type(cam).__name__
    'IntrinsicsCamera'
    >>> project_points(cam, torch.tensor([[0.0, 0.0, 0.0]], dtype=torch.float64), 8)  # round trip
    tensor([[[4., 4.]]], dtype=torch.float64)
    """
    torch = _torch()
    K, E = pinhole.intrinsics, pinhole.extrinsics
    if K.ndim != 3 or K.shape[-2:] != (4, 4) or E.shape != K.shape:
        raise ShapeError(f"pinhole intrinsics/extrinsics must be [B, 4, 4], got {list(K.shape)}, {list(E.shape)}")
    if bool((K[:, 0, 1].detach().abs() > 1e-12 * K[:, 0, 0].detach().abs()).any()):
        raise ParameterError(f"from_kornia: skewed intrinsics (K[0, 1] = {K[:, 0, 1].detach().tolist()}) "
                             f"have no gendr camera")
    Rc, tc = E[:, :3, :3], E[:, :3, 3]
    err = float((Rc @ Rc.transpose(1, 2) - torch.eye(3, dtype=Rc.dtype, device=Rc.device)).detach().abs().max())
    tol = max(1e-6, 100 * torch.finfo(Rc.dtype).eps)  # a float32 product of a few rotations: ~1e-6
    if not err <= tol:  # (NaN fails too)
        raise ParameterError(f"from_kornia: the extrinsics' 3x3 block is not a rotation (|RRᵀ − I| = {err:.3g} > {tol:.3g})")
    det = torch.linalg.det(Rc.detach())
    if bool((det < 0).any()):  # a reflection passes RRᵀ = I; gendr's frame would mirror x silently
        raise ParameterError(f"from_kornia: the extrinsics' 3x3 block is a reflection (det = {det.tolist()}), "
                             f"not a rotation")
    eye = -(Rc.transpose(1, 2) @ tc[..., None])[..., 0]  # camera centre in the world
    forward, down = Rc[:, 2], Rc[:, 1]  # OpenCV +Z (viewing direction) and +Y (down), world frame
    # at as far along the view as the eye is from the origin: at − eye then keeps its precision in
    # float32 (at = eye + forward lost 0.1 px at |eye| = 1e4 and met eye at 3e7)
    reach = 1.0 + eye.detach().norm(dim=-1, keepdim=True)
    return IntrinsicsCamera(eye=eye, at=eye + forward * reach, up=-down, near=near, far=far,
                            fx=K[:, 0, 0], fy=K[:, 1, 1], cx=K[:, 0, 2] + 0.5, cy=K[:, 1, 2] + 0.5)


def from_pytorch3d_look_at(dist=1.0, elev=0.0, azim=0.0, *, fov=60.0, degrees=True, eye=None,
                           at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), image_size=None, znear=1.0,
                           zfar=100.0) -> PerspectiveCamera:
    """The gendr camera of PyTorch3D's ``FoVPerspectiveCameras(fov=fov, degrees=degrees, R=R, T=T,
    znear, zfar)`` with ``R, T = look_at_view_transform(dist, elev, azim, degrees, eye, at, up)``
    (PyTorch3D's defaults; ``aspect_ratio`` 1, its default) rendered at ``image_size`` (H, W).

    Same image, pixel for pixel: PyTorch3D's camera frame is gendr's with x and z negated
    (+X left, +Y up, looking along +Z), and its NDC (+X left, +Y up) is not mirrored. Its camera
    position for (dist, elev, azim) is gendr's ``Orbit(azim, elev, dist)`` (elevation towards +Y,
    azimuth from +Z towards +X). Its ``fov`` is the field of view of the *shorter* image side (the
    side its NDC spans [−1, 1]); gendr's ``fov_y`` is vertical, so for H > W it becomes
    2·atan(tan(fov/2)·H/W). ``image_size`` is needed only when H > W (None: square / H <= W).
    ``znear``/``zfar`` become ``near``/``far``. Angles in degrees unless ``degrees=False``;
    dist/elev/azim/fov may be numbers, [B] arrays or tensors (requiring grad).

    Returns a :class:`PerspectiveCamera` (PyTorch3D itself is not needed).

    >>> from gendr.interop import from_pytorch3d_look_at
    >>> cam = from_pytorch3d_look_at(dist=2.7, elev=10.0, azim=30.0)
    >>> cam.eye, cam.fov_y, cam.near, cam.far
    (Orbit(azimuth=30.0, elevation=10.0, distance=2.7), 60.0, 1.0, 100.0)
    """
    from .cameras import Orbit

    def to_deg(v):
        if degrees:
            return v
        return (np.asarray(v, dtype=float) if isinstance(v, (list, tuple)) else v) * (180.0 / math.pi)
    fov_d = to_deg(fov)
    # checked here, in the caller's unit: converted, a bad fov would be named as a fov_y in degrees
    # (past 180° the H > W conversion even makes it negative)
    v = np.asarray(fov_d.detach().cpu() if hasattr(fov_d, "detach") else fov_d, dtype=float)
    if not np.all((v > 0.0) & (v < 180.0)):
        domain = "(0, 180) degrees" if degrees else "(0, π) radians"
        raise ParameterError(f"from_pytorch3d_look_at parameter fov={fov!r} must be a field of view in {domain}")
    if image_size is not None:
        H, W = image_size_pair(image_size, "from_pytorch3d_look_at")
        if H > W:
            ratio = H / W
            if isinstance(fov_d, (int, float)):
                fov_d = 2.0 * math.degrees(math.atan(math.tan(math.radians(fov_d) / 2.0) * ratio))
            else:
                torch = _torch()
                fov_d = 2.0 * torch.rad2deg(torch.atan(torch.tan(torch.deg2rad(torch.as_tensor(fov_d)) / 2.0) * ratio))
    pos = eye if eye is not None else Orbit(to_deg(azim), to_deg(elev), dist)
    return PerspectiveCamera(eye=pos, at=at, up=up, near=znear, far=zfar, fov_y=fov_d)
