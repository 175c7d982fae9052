"""Cameras (OpenGL conventions, DESIGN.md §3): the camera looks along −Z, +X right, +Y up.

Camera parameters may be Python numbers, sequences, NumPy arrays or backend tensors (which may
require grad: camera-pose optimisation differentiates through them). A leading batch dimension on
any parameter (``eye`` of shape [B, 3], ``fov_y`` of shape [B], ...) gives one camera per batch
element; unbatched parameters are shared by the whole batch.

The projection is written once, against the ops namespace: :meth:`Camera.view_coords` maps world
points into the camera frame, :meth:`Camera.ndc_affine` gives the per-axis projection
``x_ndc = sx·x/(−z) + ox`` (perspective, intrinsics) or ``x_ndc = sx·x + ox`` (orthographic).

Values are checked once, here, by :meth:`Camera.check_values`: when the camera is constructed for the
values given as Python numbers, sequences or NumPy arrays, and by every backend at render time for
all of them (tensors included). Non-finite values raise :class:`~gendr.errors.InputValueError`,
lens values out of their domain (``fov_y``, ``xmag``, ``ymag``, ``fx``, ``fy``)
:class:`~gendr.errors.ParameterError`, and a pose without a defined view
:class:`~gendr.errors.DegenerateCameraError`: ``eye`` on ``at`` (an orbit ``distance`` of 0), or ``up``
parallel to the viewing direction, both within a relative tolerance :data:`DEGENERATE_RTOL`. The
messages name the parameter, its value and, for a batch of cameras, the first bad batch element.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import DegenerateCameraError, InputValueError, ParameterError, ShapeError
from .ops import numpy_ops
from .params import is_backend_array, non_real_kind

#: kind of each array parameter, used by backends to convert them: "vec3" -> [B?, 3], "scalar" -> [B?]
VEC3, SCALAR = "vec3", "scalar"
#: eye and at coincide when |eye − at| <= DEGENERATE_RTOL·max(|eye|, |at|); up is parallel to the
#: viewing direction when the sine of their angle is <= DEGENERATE_RTOL (~0.00006 degrees): float32
#: arithmetic cannot tell such a view (or its roll) from a degenerate one
DEGENERATE_RTOL = 1e-6


@dataclass(frozen=True, eq=False)
class Orbit:
    """Eye position on a sphere around ``at``: angles in degrees, ``distance`` in world units.

    azimuth 0, elevation 0 puts the eye on +Z of ``at``; azimuth turns towards +X, elevation
    towards +Y. Each value may be a number, a [B] array (NumPy, float) or a scalar / [B] tensor of
    the render backend (torch CPU/CUDA on the vertices' device, or Dr.Jit); a tensor that requires
    grad gets a gradient from :meth:`~gendr.Renderer.render`. Used as a camera's ``eye``; see
    :func:`orbit_camera`.

    >>> import gendr
    >>> cam = gendr.PerspectiveCamera(eye=gendr.Orbit(azimuth=90.0, elevation=0.0, distance=3.0))
    >>> [round(float(c), 6) + 0.0 for c in cam.eye_position(gendr.ops.numpy_ops, {"azimuth": 90.0, "elevation": 0.0,
    ...                                                       "distance": 3.0, "at": (0.0, 0.0, 0.0)})]
    [3.0, 0.0, 0.0]
    """

    azimuth: Any
    elevation: Any
    distance: Any


def _check_positive(owner, name, value):
    if isinstance(value, numbers.Real) and not (math.isfinite(value) and value > 0):
        raise ParameterError(f"{owner} parameter {name}={value!r} must be finite and > 0")


def _plain(value) -> bool:
    """A Python number, a NumPy number or array, a (nested) sequence of them, or anything else NumPy
    reads as numbers (a memoryview, array.array): checkable when the camera is made. Backend
    tensors are checked at render time."""
    if is_backend_array(value) or isinstance(value, (str, bytes)) or value is None:
        return False
    if isinstance(value, (list, tuple)):
        return len(value) > 0 and all(_plain(v) for v in value)
    try:
        return np.asarray(value).dtype.kind in "iuf"
    except (TypeError, ValueError):
        return False


def _mixes_tensors(value) -> bool:
    """A (nested) sequence holding a backend tensor somewhere."""
    return isinstance(value, (list, tuple)) and any(is_backend_array(v) or _mixes_tensors(v) for v in value)


def batched(name: str, value, kind: str) -> np.ndarray:
    """``value`` as float64 ``[n, 3]`` (vec3) or ``[n]`` (scalar); :class:`ShapeError` otherwise."""
    a = np.asarray(value, dtype=np.float64)
    if kind == VEC3:
        a = a[None] if a.shape == (3,) else a
        if a.ndim != 2 or a.shape[1] != 3:
            raise ShapeError(f"camera parameter {name} must have shape [3] or [B, 3], got {list(a.shape)}")
    else:
        a = a[None] if a.ndim == 0 else a
        if a.ndim != 1:
            raise ShapeError(f"camera parameter {name} must be a scalar or have shape [B], got {list(a.shape)}")
    if a.shape[0] == 0:  # (as a tensor's is at render time)
        raise ShapeError(f"camera parameter {name} has an empty batch: shape {list(a.shape)}")
    return a


def _fmt(a) -> str:
    a = np.asarray(a, dtype=np.float64)
    return f"{float(a):.8g}" if a.ndim == 0 else "(" + ", ".join(f"{float(x):.8g}" for x in a) + ")"


def _first(bad: np.ndarray) -> int:
    """Index of the first True of a 1-d boolean array that has one."""
    return int(np.argmax(bad))


def _norm(v):
    return np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def _is_drjit_vector(value) -> bool:
    """A Dr.Jit vector array (Array3f, ...: shape (3, N)), not a Dr.Jit tensor ([N, 3] like NumPy)."""
    t = type(value)
    return t.__module__.startswith("drjit") and not t.__name__.startswith("Tensor")


@dataclass(frozen=True, eq=False)
class Camera:
    """Base class: pose from ``eye`` (a point or an :class:`Orbit`), ``at``, ``up``; clip planes.

    ``near``/``far`` are positive view-space depths. Faces entirely nearer than ``near`` are not
    drawn; faces crossing it are clipped (as OpenGL does). ``far`` only normalises depth for the
    softmax RGB blend (DESIGN.md §3); it does not clip: coverage and alpha beyond it are kept, but
    with the softmax blend a face beyond ``far`` (normalised depth < 0) weighs less than the
    background by exp((z̃ − ε)/γ), so its pixels take nearly the background colour.

    Args (all subclasses; OpenGL convention: the camera looks along its −Z, +Y up, +X right):
        eye: [3] or [B, 3] camera position in world units, or an :class:`Orbit`.
        at: [3] or [B, 3] point looked at (world units).
        up: [3] or [B, 3] up direction (any length > 0; must not be parallel to ``at − eye``).
        near, far: Python floats, 0 < near < far (world units).

    Array values may be Python numbers/sequences, NumPy arrays (float) or tensors of the render
    backend (torch CPU/CUDA on the vertices' device, or Dr.Jit arrays; converted to the vertices'
    dtype at render time). Tensors that require grad get gradients from
    :meth:`~gendr.Renderer.render` / :meth:`~gendr.Renderer.rasterize`; a batch (B > 1) gives one
    camera per batch element. ``near``/``far`` are not differentiable.

    Raises: :class:`~gendr.errors.ParameterError` (near/far, lens values out of domain),
    :class:`~gendr.errors.ShapeError`, :class:`~gendr.errors.InputValueError` (non-finite) and
    :class:`~gendr.errors.DegenerateCameraError` (see the module docstring); at construction for
    plain values, at render time for tensors.

    Use a subclass (:class:`PerspectiveCamera`, :class:`OrthographicCamera`,
    :class:`IntrinsicsCamera`):

    >>> import gendr
    >>> cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), at=(0.0, 0.0, 0.0))
    >>> isinstance(cam, gendr.Camera), cam.near, cam.far
    (True, 0.1, 100.0)
    >>> gendr.PerspectiveCamera(near=1.0, far=0.5)
    Traceback (most recent call last):
    ...
    gendr.errors.ParameterError: PerspectiveCamera needs far > near, got near=1.0, far=0.5
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
            if not isinstance(v, numbers.Real) or isinstance(v, bool):
                raise ParameterError(f"{name} parameter {f}={v!r} must be a number (not a tensor: not differentiable)")
            _check_positive(name, f, v)
            object.__setattr__(self, f, float(v))  # (frozen dataclass; NumPy scalars become floats)
        if not self.far > self.near:
            raise ParameterError(f"{name} needs far > near, got near={self.near!r}, far={self.far!r}")
        params = self.array_params()
        for k, (value, _) in params.items():
            if _mixes_tensors(value):
                raise ParameterError(f"{name} parameter {k}={value!r} mixes numbers and tensors: give one tensor "
                                     f"(e.g. torch.stack), which keeps its gradient")
            if is_backend_array(value) and (non_real := non_real_kind(value)):  # (a cast would make True 1°)
                raise ParameterError(f"{name} parameter {k} must be a real tensor, got {non_real}")
            if not (_plain(value) or is_backend_array(value)):
                raise ParameterError(f"{name} parameter {k}={value!r} must be a number, a sequence of numbers, "
                                     f"a float NumPy array or a torch/Dr.Jit tensor")
        plain = {k: v for k, v in params.items() if _plain(v[0])}
        if plain:  # the rest (tensors) at render time, by the backend
            self.check_values({k: batched(k, value, kind) for k, (value, kind) in plain.items()})

    #: lens parameter -> (elementwise test, what the test requires), see :meth:`check_values`
    _LENS_DOMAINS = {}

    def check_values(self, values: dict) -> None:
        """Check camera values; every backend calls this at render time.

        ``values``: parameter name (of :meth:`array_params`) -> float64 NumPy array ``[n, 3]`` (vec3)
        or ``[n]`` (scalar), n = 1 or the camera batch size B, for some or all of the parameters (a
        check runs when the values it needs are given). Raises :class:`~gendr.errors.ShapeError`
        (batch sizes that differ), :class:`~gendr.errors.InputValueError` (a non-finite value),
        :class:`~gendr.errors.ParameterError` (a lens value out of its domain) or
        :class:`~gendr.errors.DegenerateCameraError` (eye on at, up parallel to the view, up = 0).
        """
        cls, B = type(self).__name__, 1
        for k, a in values.items():
            if len(a) != 1:
                if B not in (1, len(a)):
                    raise ShapeError(f"camera parameter {k} has batch size {len(a)}, others have {B}")
                B = len(a)

        def member(i, n=B):
            return f" (batch element {i} of {n})" if n > 1 else ""

        for k, a in values.items():
            if not np.isfinite(a).all():
                i = _first(~np.isfinite(a.reshape(len(a), -1)).all(axis=1))
                raise InputValueError(f"camera parameter {k} must be finite, got {_fmt(a[i])}{member(i, len(a))}")
        for k, (ok, want) in self._LENS_DOMAINS.items():
            if k in values and not ok(values[k]).all():
                i = _first(~ok(values[k]))
                raise ParameterError(f"{cls} parameter {k}={_fmt(values[k][i])} must be {want}"
                                     f"{member(i, len(values[k]))}")
        orbit = isinstance(self.eye, Orbit)
        if orbit and "distance" in values and (values["distance"] < 0).any():  # (0: eye on at, below)
            i = _first(values["distance"] < 0)
            raise ParameterError(f"{cls} parameter distance={_fmt(values['distance'][i])} (an orbit's) must be > 0"
                                 f"{member(i, len(values['distance']))}")
        if not all(k in values for k in (("at", "azimuth", "elevation", "distance") if orbit else ("at", "eye"))):
            return
        # 3-tuples of [n] components (n = 1 or B, broadcasting), as the backends evaluate the pose
        at = tuple(values["at"].T)
        P = {"at": at, **{k: values[k] for k in ("azimuth", "elevation", "distance") if orbit}}
        eye = self.eye_position(numpy_ops, P) if orbit else tuple(values["eye"].T)
        back = tuple(e - c for e, c in zip(eye, at))
        dist = _norm(back)
        bad = dist <= DEGENERATE_RTOL * np.maximum(_norm(eye), _norm(at))

        def row(v, i):  # element i of a broadcast 3-tuple or scalar array
            return np.array([np.broadcast_to(c, (B,))[i] for c in v]) if isinstance(v, tuple) else np.broadcast_to(v, (B,))[i]

        if bad.any():
            i = _first(np.broadcast_to(bad, (B,)))
            what = (f"orbit distance={_fmt(row(P['distance'], i))} puts eye={_fmt(row(eye, i))} on at={_fmt(row(at, i))}"
                    if orbit else f"eye={_fmt(row(eye, i))} equals at={_fmt(row(at, i))}")
            raise DegenerateCameraError(f"{cls}: {what}{member(i)}: the viewing direction is undefined")
        if "up" not in values:
            return
        up = tuple(values["up"].T)
        up_len = _norm(up)
        if not (up_len > 0).all():
            i = _first(np.broadcast_to(up_len == 0, (B,)))
            raise DegenerateCameraError(f"{cls}: up={_fmt(row(up, i))} must not be the zero vector{member(i)}")
        bad = _norm(_cross(up, back)) <= DEGENERATE_RTOL * up_len * dist
        if bad.any():
            i = _first(np.broadcast_to(bad, (B,)))
            pose = (f"azimuth={_fmt(row(P['azimuth'], i))}, elevation={_fmt(row(P['elevation'], i))}, "
                    f"distance={_fmt(row(P['distance'], i))} (eye={_fmt(row(eye, i))})" if orbit
                    else f"eye={_fmt(row(eye, i))}")
            raise DegenerateCameraError(
                f"{cls}: up={_fmt(row(up, i))} is parallel to the viewing direction from {pose} to at={_fmt(row(at, i))}"
                f"{member(i)}: the camera's roll is undefined; choose an up vector across the view")

    def batch_size(self) -> int:
        """The camera batch size B (1: unbatched) from the shapes of its array parameters ([B, 3]
        or [B]), without reading their values; :class:`~gendr.errors.ShapeError` for an empty batch
        or two batch sizes that differ (the backends check the shapes themselves)."""
        B = 1
        for k, (value, kind) in self.array_params().items():
            shape = tuple(value.shape) if hasattr(value, "shape") else np.shape(value)
            if kind == VEC3 and len(shape) == 2 and _is_drjit_vector(value):
                shape = shape[::-1]  # a Dr.Jit Array3f is (3, N): N 3-vectors
            n = shape[0] if len(shape) == (2 if kind == VEC3 else 1) else 1
            if n == 0:
                raise ShapeError(f"camera parameter {k} has an empty batch (shape {list(shape)})")
            if n != 1:
                if B not in (1, n):
                    raise ShapeError(f"camera parameter {k} has batch size {n}, others have {B}")
                B = n
        return B

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
    ``PerspectiveCamera(yfov)``).

    Args: ``eye``, ``at``, ``up``, ``near``, ``far`` as for :class:`Camera`; ``fov_y``: number,
    [B] array or tensor in (0, 180) degrees (differentiable when a tensor requiring grad).

    >>> import numpy as np, torch, gendr
    >>> cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=40.0)
    >>> r = gendr.Renderer(image_size=8, backend="torch")
    >>> tri = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
    >>> img = r.render(torch.tensor(tri, dtype=torch.float32), [[0, 1, 2]], cam)
    >>> img.shape, img.dtype, round(float(img[0, 4, 4, 3]), 3)
    (torch.Size([1, 8, 8, 4]), torch.float32, 1.0)
    >>> gendr.PerspectiveCamera(fov_y=180.0)
    Traceback (most recent call last):
    ...
    gendr.errors.ParameterError: PerspectiveCamera parameter fov_y=180 must be in (0, 180) degrees
    """

    fov_y: Any = 40.0

    _LENS_DOMAINS = {"fov_y": (lambda v: (v > 0) & (v < 180), "in (0, 180) degrees")}

    def _lens_params(self):
        return {"fov_y": (self.fov_y, SCALAR)}

    def ndc_affine(self, ops, P, height, width):
        sy = 1.0 / ops.tan(P["fov_y"] * (math.pi / 360.0))
        return sy * (height / width), sy, 0.0, 0.0


@dataclass(frozen=True, eq=False)
class OrthographicCamera(Camera):
    """Parallel projection showing ``[−xmag, xmag] × [−ymag, ymag]`` of the camera plane (as
    pyrender's ``OrthographicCamera``; note pyrender itself uses xmag = ymag·W/H when rendering).

    Args: ``eye``, ``at``, ``up``, ``near``, ``far`` as for :class:`Camera`; ``xmag``, ``ymag``:
    half-widths > 0 in world units (numbers, [B] arrays or tensors; differentiable).

    >>> import gendr
    >>> cam = gendr.OrthographicCamera(eye=(0.0, 0.0, 3.0), xmag=2.0, ymag=1.0)
    >>> cam.orthographic, cam.ndc_affine(gendr.ops.numpy_ops, {"xmag": 2.0, "ymag": 1.0}, 8, 8)
    (True, (0.5, 1.0, 0.0, 0.0))
    """

    xmag: Any = 1.0
    ymag: Any = 1.0
    orthographic = True

    # (ymag first: orbit_camera's xmag defaults to its ymag, so a bad ymag is the one to name)
    _LENS_DOMAINS = {"ymag": (lambda v: v > 0, "> 0"), "xmag": (lambda v: v > 0, "> 0")}

    def _lens_params(self):
        return {"xmag": (self.xmag, SCALAR), "ymag": (self.ymag, SCALAR)}

    def ndc_affine(self, ops, P, height, width):
        return 1.0 / P["xmag"], 1.0 / P["ymag"], 0.0, 0.0


@dataclass(frozen=True, eq=False)
class IntrinsicsCamera(Camera):
    """Pinhole camera from intrinsics in pixels: focal lengths ``fx, fy`` and principal point
    ``cx, cy`` with rows counted from the top (as pyrender's ``IntrinsicsCamera``). A point at
    camera coordinates (x, y, z) lands at column ``fx·x/(−z) + cx`` and row ``cy − fy·y/(−z)``
    (pixel centres at half-integers).

    Args: ``eye``, ``at``, ``up``, ``near``, ``far`` as for :class:`Camera`; ``fx``, ``fy`` > 0
    and ``cx``, ``cy`` in pixels of the rendered image (numbers, [B] arrays or tensors;
    differentiable). The image size comes from the :class:`~gendr.Renderer`.

    >>> import gendr
    >>> cam = gendr.IntrinsicsCamera(fx=8.0, fy=8.0, cx=4.0, cy=4.0)
    >>> cam.ndc_affine(gendr.ops.numpy_ops, {"fx": 8.0, "fy": 8.0, "cx": 4.0, "cy": 4.0}, 8, 8)
    (2.0, 2.0, 0.0, 0.0)
    """

    fx: Any = 100.0
    fy: Any = 100.0
    cx: Any = 64.0
    cy: Any = 64.0

    _LENS_DOMAINS = {"fx": (lambda v: v > 0, "> 0"), "fy": (lambda v: v > 0, "> 0")}

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

    Args:
        azimuth, elevation: degrees (number, [B] array, or torch/Dr.Jit tensor; differentiable).
        distance: world units, > 0 (same kinds; differentiable).
        at, up: [3] or [B, 3], world space. fov_y: degrees; ymag/xmag: world units; near/far: as
            for :class:`Camera`.

    Returns: a :class:`Camera` whose ``eye`` is an :class:`Orbit`.

    Raises: :class:`~gendr.errors.ParameterError` for a plain ``distance`` <= 0 or non-finite
    (naming the batch element), and the camera's errors (:class:`Camera`).

    >>> import torch, gendr
    >>> cam = gendr.orbit_camera(30.0, 20.0, 3.0)
    >>> type(cam).__name__, cam.eye
    ('PerspectiveCamera', Orbit(azimuth=30.0, elevation=20.0, distance=3.0))
    >>> az = torch.tensor([0.0, 90.0], requires_grad=True)  # two views, a pose to optimise
    >>> gendr.orbit_camera(az, 0.0, 3.0, orthographic=True).xmag
    1.0
    >>> gendr.orbit_camera(0.0, 0.0, 0.0)
    Traceback (most recent call last):
    ...
    gendr.errors.ParameterError: orbit_camera parameter distance=0 must be finite and > 0
    """
    eye = Orbit(azimuth, elevation, distance)
    if _plain(distance):
        d = batched("distance", distance, SCALAR)
        bad = ~(np.isfinite(d) & (d > 0))
        if bad.any():
            i = _first(bad)
            where = f" (batch element {i} of {len(d)})" if len(d) > 1 else ""
            raise ParameterError(f"orbit_camera parameter distance={_fmt(d[i])} must be finite and > 0{where}")
    if orthographic:
        return OrthographicCamera(eye=eye, at=at, up=up, near=near, far=far, xmag=ymag if xmag is None else xmag, ymag=ymag)
    return PerspectiveCamera(eye=eye, at=at, up=up, near=near, far=far, fov_y=fov_y)
