"""gendr cameras as plain float64 NumPy geometry (DESIGN.md §3), independent of any backend.

Used to convert a gendr camera into each reference renderer's conventions and to project a mesh
(with near-plane clipping) for the ambiguity mask of the hard-limit check.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

import gendr
from gendr.cameras import Orbit
from gendr.errors import ParameterError


def _scalar(v, name) -> float:
    a = np.asarray(v.detach().cpu().numpy() if hasattr(v, "detach") else v, dtype=np.float64)
    if a.size != 1:
        raise ParameterError(f"validation needs an unbatched camera; parameter {name} has shape {a.shape}")
    return float(a.reshape(()))


def _vec3(v, name) -> np.ndarray:
    a = np.asarray(v.detach().cpu().numpy() if hasattr(v, "detach") else v, dtype=np.float64)
    if a.size != 3:
        raise ParameterError(f"validation needs an unbatched camera; parameter {name} has shape {a.shape}")
    return a.reshape(3)


@dataclass(frozen=True)
class CameraGeometry:
    """An unbatched gendr camera in NumPy: pose, lens kind and the NDC projection.

    ``R`` is the 3x3 matrix whose rows are the camera's right, up and back axes (world -> view is
    ``R @ (p - eye)``); ``pose`` the 4x4 camera-to-world matrix (columns right, up, back, eye), as
    pyrender and OpenGL expect it.
    """

    kind: str  # "perspective", "orthographic", "intrinsics"
    eye: np.ndarray
    at: np.ndarray
    up: np.ndarray
    R: np.ndarray
    near: float
    far: float
    fov_y: float = 0.0  # degrees (perspective)
    xmag: float = 0.0
    ymag: float = 0.0
    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0

    @property
    def pose(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R.T
        T[:3, 3] = self.eye
        return T

    @property
    def right(self):
        return self.R[0]

    @property
    def up_axis(self):
        return self.R[1]

    def view(self, p: np.ndarray) -> np.ndarray:
        """World points [..., 3] -> view coordinates (visible points have z < 0)."""
        return (np.asarray(p, dtype=np.float64) - self.eye) @ self.R.T

    def ndc_affine(self, H: int, W: int):
        """(sx, sy, ox, oy) as gendr's :meth:`Camera.ndc_affine`, in NumPy."""
        if self.kind == "perspective":
            sy = 1.0 / math.tan(math.radians(self.fov_y) / 2)
            return sy * H / W, sy, 0.0, 0.0
        if self.kind == "orthographic":
            return 1.0 / self.xmag, 1.0 / self.ymag, 0.0, 0.0
        return 2.0 * self.fx / W, 2.0 * self.fy / H, 2.0 * self.cx / W - 1.0, 1.0 - 2.0 * self.cy / H


def camera_geometry(camera) -> CameraGeometry:
    """Convert a gendr :class:`~gendr.Camera` (eye or :class:`~gendr.Orbit`, at, up, lens)."""
    if not isinstance(camera, gendr.Camera):
        raise ParameterError(f"expected a gendr camera, got {type(camera).__name__}")
    at = _vec3(camera.at, "at")
    up = _vec3(camera.up, "up")
    if isinstance(camera.eye, Orbit):
        az = math.radians(_scalar(camera.eye.azimuth, "azimuth"))
        el = math.radians(_scalar(camera.eye.elevation, "elevation"))
        dist = _scalar(camera.eye.distance, "distance")
        eye = at + dist * np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    else:
        eye = _vec3(camera.eye, "eye")
    back = eye - at
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    upv = np.cross(back, right)
    R = np.stack([right, upv, back])
    common = dict(eye=eye, at=at, up=up, R=R, near=float(camera.near), far=float(camera.far))
    if isinstance(camera, gendr.OrthographicCamera):
        return CameraGeometry("orthographic", xmag=_scalar(camera.xmag, "xmag"), ymag=_scalar(camera.ymag, "ymag"), **common)
    if isinstance(camera, gendr.IntrinsicsCamera):
        return CameraGeometry("intrinsics", fx=_scalar(camera.fx, "fx"), fy=_scalar(camera.fy, "fy"),
                              cx=_scalar(camera.cx, "cx"), cy=_scalar(camera.cy, "cy"), **common)
    if isinstance(camera, gendr.PerspectiveCamera):
        return CameraGeometry("perspective", fov_y=_scalar(camera.fov_y, "fov_y"), **common)
    raise ParameterError(f"unsupported camera type {type(camera).__name__}")


def stretch_along(vertices: np.ndarray, origin: np.ndarray, axis: np.ndarray, k: float) -> np.ndarray:
    """Scale ``vertices`` by ``k`` along the unit ``axis`` through ``origin`` (identity for k = 1).

    Used where a reference camera cannot express a gendr lens exactly (pyrender's orthographic
    camera forces xmag = ymag·W/H; Mitsuba's pinhole has fx = fy): stretching the scene along the
    camera's right axis (perpendicular to the view direction, so depths and the near plane are
    unchanged) gives the same image.
    """
    if k == 1.0:
        return vertices
    d = vertices - origin
    return vertices + (k - 1.0) * np.outer(d @ axis, axis)


def project_polygons(mesh, geom: CameraGeometry, H: int, W: int):
    """Project and near-clip every face like OpenGL: returns ``(polys, valid)``.

    ``polys`` is [F, 4, 2] pixel coordinates (column, row; pixel (i, j) has its centre at
    (j + 0.5, i + 0.5)) of the clipped polygon, the 4th corner repeating the 3rd for triangles;
    ``valid`` [F] says whether some part of the face lies in front of the near plane.
    """
    v = geom.view(mesh.vertices)
    tri = v[mesh.faces]  # [F, 3, 3]
    F = len(tri)
    near = geom.near
    polys = np.zeros((F, 4, 3))
    valid = np.zeros(F, dtype=bool)
    inside = tri[..., 2] <= -near
    for f in range(F):
        if inside[f].all():
            polys[f, :3], polys[f, 3] = tri[f], tri[f, 2]
            valid[f] = True
            continue
        out = []
        for k in range(3):
            a, b = tri[f, k], tri[f, (k + 1) % 3]
            ia, ib = inside[f, k], inside[f, (k + 1) % 3]
            if ia:
                out.append(a)
            if ia != ib:
                t = (-near - a[2]) / (b[2] - a[2])
                out.append(a + t * (b - a))
        if out:
            valid[f] = True
            while len(out) < 4:
                out.append(out[-1])
            polys[f] = np.array(out[:4])
    sx, sy, ox, oy = geom.ndc_affine(H, W)
    if geom.kind == "orthographic":
        nx, ny = sx * polys[..., 0] + ox, sy * polys[..., 1] + oy
    else:
        z = np.where(valid[:, None], -polys[..., 2], 1.0)
        nx, ny = sx * polys[..., 0] / z + ox, sy * polys[..., 1] / z + oy
    col = (nx + 1.0) * W / 2.0
    row = (1.0 - ny) * H / 2.0
    return np.stack([col, row], -1), valid


def edge_distance(mesh, geom: CameraGeometry, H: int, W: int) -> np.ndarray:
    """[H, W] distance in pixels from every pixel centre to the nearest projected (clipped) face edge."""
    polys, valid = project_polygons(mesh, geom, H, W)
    polys = polys[valid]
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    px, py = jj.reshape(-1), ii.reshape(-1)
    # every edge once: a shared edge appears in two faces, and the repeated 4th corner of a triangle
    # gives a zero-length edge (its point is an endpoint of the neighbouring edges)
    A = polys.reshape(-1, 2)
    B = np.roll(polys, -1, axis=1).reshape(-1, 2)
    keep = np.any(A != B, axis=1)
    seg = np.concatenate([A[keep], B[keep]], 1)
    swap = (seg[:, 0] > seg[:, 2]) | ((seg[:, 0] == seg[:, 2]) & (seg[:, 1] > seg[:, 3]))
    seg[swap] = seg[swap][:, [2, 3, 0, 1]]
    seg = np.unique(seg, axis=0)
    if len(seg) == 0:  # only zero-area faces collapsed to points
        seg = np.concatenate([A, A], 1)
    best = np.full(px.shape, np.inf)  # squared distances
    chunk = max(1, 2_000_000 // (H * W))
    for s in range(0, len(seg), chunk):
        S = seg[s:s + chunk]
        Ex, Ey = (S[:, 2] - S[:, 0])[:, None], (S[:, 3] - S[:, 1])[:, None]
        L2 = Ex * Ex + Ey * Ey
        dx = px[None, :] - S[:, 0:1]
        dy = py[None, :] - S[:, 1:2]
        t = np.clip((dx * Ex + dy * Ey) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
        qx, qy = dx - t * Ex, dy - t * Ey
        best = np.minimum(best, (qx * qx + qy * qy).min(axis=0))
    return np.sqrt(best).reshape(H, W)
