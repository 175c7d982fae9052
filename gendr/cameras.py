"""Cameras (OpenGL conventions, DESIGN.md §3): the camera looks along −Z, +X right, +Y up.

Camera parameters may be Python numbers, sequences, NumPy arrays or backend tensors (which may
require grad: camera-pose optimisation differentiates through them). A leading batch dimension on
any parameter (``eye`` of shape [B, 3], ``fov_y`` of shape [B], ...) gives one camera per batch
element; unbatched parameters are shared by the whole batch.

The projection is written once, against the ops namespace: :meth:`Camera.view_coords` maps world
points into the camera frame, :meth:`Camera.ndc_affine` gives the per-axis projection
``x_ndc = sx·x/(−z) + ox`` (perspective, intrinsics) or ``x_ndc = sx·x + ox`` (orthographic).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from .errors import ParameterError

#: kind of each array parameter, used by backends to convert them: "vec3" -> [B?, 3], "scalar" -> [B?]
VEC3, SCALAR = "vec3", "scalar"


@dataclass(frozen=True, eq=False)
class Orbit:
    """Eye position on a sphere around ``at``: angles in degrees, ``distance`` in world units.

    azimuth 0, elevation 0 puts the eye on +Z of ``at``; azimuth turns towards +X, elevation
    towards +Y. Each value may be a number, a [B] array or a tensor requiring grad.
    """

    azimuth: Any
    elevation: Any
    distance: Any


def _check_positive(owner, name, value):
    if isinstance(value, (int, float)) and not (math.isfinite(value) and value > 0):
        raise ParameterError(f"{owner} parameter {name}={value!r} must be finite and > 0")


@dataclass(frozen=True, eq=False)
class Camera:
    """Base class: pose from ``eye`` (a point or an :class:`Orbit`), ``at``, ``up``; clip planes.

    ``near``/``far`` are positive view-space depths. Faces entirely nearer than ``near`` are not
    drawn; faces crossing it are clipped (as OpenGL does). ``far`` only normalises depth for the
    softmax RGB blend (DESIGN.md §3); it does not clip.
    """

    eye: Any = (0.0, 0.0, 3.0)
    at: Any = (0.0, 0.0, 0.0)
    up: Any = (0.0, 1.0, 0.0)
    near: float = 0.1
    far: float = 100.0

    orthographic = False

    def __post_init__(self):
        name = type(self).__name__
        for f in ("near", "far"):
            v = getattr(self, f)
            if not isinstance(v, (int, float)) or isinstance(v, bool):
                raise ParameterError(f"{name} parameter {f}={v!r} must be a Python number")
            _check_positive(name, f, v)
        if not self.far > self.near:
            raise ParameterError(f"{name} needs far > near, got near={self.near!r}, far={self.far!r}")

    # --- what backends convert -------------------------------------------------------------
    def array_params(self) -> dict[str, tuple[Any, str]]:
        """``{name: (value, kind)}`` for every array-like parameter (kind ``"vec3"`` or ``"scalar"``)."""
        out = {"at": (self.at, VEC3), "up": (self.up, VEC3)}
        if isinstance(self.eye, Orbit):
            out.update(azimuth=(self.eye.azimuth, SCALAR), elevation=(self.eye.elevation, SCALAR),
                       distance=(self.eye.distance, SCALAR))
        else:
            out["eye"] = (self.eye, VEC3)
        out.update(self._lens_params())
        return out

    def _lens_params(self) -> dict[str, tuple[Any, str]]:
        return {}

    # --- the math, written against the ops namespace ------------------------------------------
    # ``P`` maps names to converted arrays: a vec3 as a tuple of 3 components, a scalar as one
    # array, each broadcastable against per-vertex arrays of shape [B, V].
    def eye_position(self, ops, P):
        if "eye" in P:
            return P["eye"]
        deg = math.pi / 180.0
        az, el, dist = P["azimuth"] * deg, P["elevation"] * deg, P["distance"]
        ax, ay, az_ = P["at"]
        ce = ops.cos(el)
        return (ax + dist * ce * ops.sin(az), ay + dist * ops.sin(el), az_ + dist * ce * ops.cos(az))

    def basis(self, ops, P):
        """Orthonormal (right, up, back) of the camera frame, each a 3-tuple of components."""
        ex, ey, ez = self.eye_position(ops, P)
        ax, ay, az = P["at"]
        bx, by, bz = _normalize(ops, (ex - ax, ey - ay, ez - az))  # back = −forward
        rx, ry, rz = _normalize(ops, _cross(P["up"], (bx, by, bz)))
        ux, uy, uz = _cross((bx, by, bz), (rx, ry, rz))
        return (rx, ry, rz), (ux, uy, uz), (bx, by, bz), (ex, ey, ez)

    def view_coords(self, ops, P, x, y, z):
        """World points (component arrays) -> camera-frame coordinates; visible points have z < 0."""
        r, u, b, e = self.basis(ops, P)
        dx, dy, dz = x - e[0], y - e[1], z - e[2]
        return (r[0] * dx + r[1] * dy + r[2] * dz,
                u[0] * dx + u[1] * dy + u[2] * dz,
                b[0] * dx + b[1] * dy + b[2] * dz)

    def ndc_affine(self, ops, P, height: int, width: int):
        """``(sx, sy, ox, oy)`` of the projection to NDC (see the module docstring)."""
        raise NotImplementedError


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _normalize(ops, v):
    inv = 1.0 / ops.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return v[0] * inv, v[1] * inv, v[2] * inv


@dataclass(frozen=True, eq=False)
class PerspectiveCamera(Camera):
    """Pinhole camera with vertical field of view ``fov_y`` in degrees; aspect = W/H (as pyrender's
    ``PerspectiveCamera(yfov)``)."""

    fov_y: Any = 40.0

    def __post_init__(self):
        super().__post_init__()
        if isinstance(self.fov_y, (int, float)) and not 0 < self.fov_y < 180:
            raise ParameterError(f"PerspectiveCamera parameter fov_y={self.fov_y!r} must lie in (0, 180) degrees")

    def _lens_params(self):
        return {"fov_y": (self.fov_y, SCALAR)}

    def ndc_affine(self, ops, P, height, width):
        sy = 1.0 / ops.tan(P["fov_y"] * (math.pi / 360.0))
        return sy * (height / width), sy, 0.0, 0.0


@dataclass(frozen=True, eq=False)
class OrthographicCamera(Camera):
    """Parallel projection showing ``[−xmag, xmag] × [−ymag, ymag]`` of the camera plane (as
    pyrender's ``OrthographicCamera``; note pyrender itself uses xmag = ymag·W/H when rendering)."""

    xmag: Any = 1.0
    ymag: Any = 1.0
    orthographic = True

    def __post_init__(self):
        super().__post_init__()
        for f in ("xmag", "ymag"):
            _check_positive("OrthographicCamera", f, getattr(self, f))

    def _lens_params(self):
        return {"xmag": (self.xmag, SCALAR), "ymag": (self.ymag, SCALAR)}

    def ndc_affine(self, ops, P, height, width):
        return 1.0 / P["xmag"], 1.0 / P["ymag"], 0.0, 0.0


@dataclass(frozen=True, eq=False)
class IntrinsicsCamera(Camera):
    """Pinhole camera from intrinsics in pixels: focal lengths ``fx, fy`` and principal point
    ``cx, cy`` with rows counted from the top (as pyrender's ``IntrinsicsCamera``). A point at
    camera coordinates (x, y, z) lands at column ``fx·x/(−z) + cx`` and row ``cy − fy·y/(−z)``
    (pixel centres at half-integers)."""

    fx: Any = 100.0
    fy: Any = 100.0
    cx: Any = 64.0
    cy: Any = 64.0

    def __post_init__(self):
        super().__post_init__()
        for f in ("fx", "fy"):
            _check_positive("IntrinsicsCamera", f, getattr(self, f))

    def _lens_params(self):
        return {k: (getattr(self, k), SCALAR) for k in ("fx", "fy", "cx", "cy")}

    def ndc_affine(self, ops, P, height, width):
        return (2.0 / width) * P["fx"], (2.0 / height) * P["fy"], (2.0 / width) * P["cx"] - 1.0, 1.0 - (2.0 / height) * P["cy"]


def orbit_camera(azimuth, elevation, distance, *, at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=40.0,
                 near=0.1, far=100.0, orthographic=False, ymag=1.0, xmag=None) -> Camera:
    """A camera on a sphere around ``at`` looking at it (angles in degrees; any of them may be a
    [B] array or a tensor requiring grad — a batch of views of one mesh, or a pose to optimise).

    ``orthographic=True`` gives an :class:`OrthographicCamera` with ``ymag`` (and ``xmag``, default
    ``ymag``); otherwise a :class:`PerspectiveCamera` with ``fov_y``.
    """
    eye = Orbit(azimuth, elevation, distance)
    if isinstance(distance, (int, float)):
        _check_positive("orbit_camera", "distance", distance)
    if orthographic:
        return OrthographicCamera(eye=eye, at=at, up=up, near=near, far=far, xmag=ymag if xmag is None else xmag, ymag=ymag)
    return PerspectiveCamera(eye=eye, at=at, up=up, near=near, far=far, fov_y=fov_y)
