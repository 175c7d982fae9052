"""Shape targets given as silhouette images with their cameras: ``target="images:PATH.npz"``.

The file is a NumPy ``.npz`` archive (``np.savez(path, images=..., azimuth=..., ...)``):

``images``
    ``[N, H, W]`` silhouettes, one per view: floats in [0, 1] (soft masks allowed), bool, or uint8
    (0..255, divided by 255).
camera position, one of
    ``azimuth``, ``elevation`` (degrees), ``distance``: gendr's orbit cameras
    (:func:`gendr.orbit_camera`: azimuth 0 on +Z turning towards +X, elevation towards +Y), each a
    scalar or ``[N]``; or ``eye`` ``[N, 3]`` with optional ``at`` and ``up`` (``[3]`` or ``[N, 3]``;
    default the origin and +Y). The camera looks along −Z of its frame (OpenGL, DESIGN.md §3).
lens, one of
    ``fov_y``: vertical field of view in degrees, scalar or ``[N]`` (a pinhole camera); or ``fx``,
    ``fy``, ``cx``, ``cy``: intrinsics in pixels, rows counted from the top, scalars or ``[N]``.
optional
    ``near``, ``far``: scalars (defaults 0.1, 100).

The shape experiment's template is a sphere of radius 0.5 at the origin whose vertices stay inside
[−1, 1]³: the object must lie there, in the cameras' world frame. The config keeps the path (part of
the key of a result row), rows record the file's sha256 under ``data`` (which data they saw); the
camera and image size come from the file, so ``views``, ``elevation``, ``distance``, ``fov_y`` and
``image_size`` of the config are not used.
"""
from __future__ import annotations

import numpy as np

from gendr.errors import GendrError, InputValueError, ShapeError

__all__ = ["IMAGES_PREFIX", "is_images_target", "images_path", "load_image_target", "save_image_target"]

IMAGES_PREFIX = "images:"
_POSITION = (("azimuth", "elevation", "distance"), ("eye",))
_LENS = (("fov_y",), ("fx", "fy", "cx", "cy"))


def is_images_target(target) -> bool:
    return isinstance(target, str) and target.startswith(IMAGES_PREFIX)


def images_path(target: str):
    """The file of an ``images:PATH`` target (``images:paper:FILE`` resolves like mesh files)."""
    from .common import resolve_data_path
    return resolve_data_path(target[len(IMAGES_PREFIX):])


def _scalar_or_n(z, key, n, path):
    a = np.asarray(z[key], dtype=np.float64)
    if a.ndim == 0:
        v = float(a)
        if not np.isfinite(v):
            raise InputValueError(f"{path}: {key}={v!r} must be finite")
        return v
    if a.shape != (n,):
        raise ShapeError(f"{path}: {key} must be a scalar or have shape [{n}] (one per image), got {list(a.shape)}")
    if not np.isfinite(a).all():
        raise InputValueError(f"{path}: {key} must be finite, got {a.tolist()}")
    import torch
    return torch.from_numpy(np.asarray(z[key], dtype=np.float32).copy())


def _clip_plane(z, key, path):
    """near / far: one number (the renderer's clip planes are not per view)."""
    a = np.asarray(z[key])
    if a.size != 1 or not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise InputValueError(f"{path}: {key} must be one real number, got {a.tolist()!r}")
    return float(a.reshape(()))


def _vec3(z, key, n, path, default=None):
    if key not in z:
        return default
    a = np.asarray(z[key], dtype=np.float32)
    if a.shape not in ((3,), (n, 3)):
        raise ShapeError(f"{path}: {key} must have shape [3] or [{n}, 3], got {list(a.shape)}")
    if not np.isfinite(a).all():
        raise InputValueError(f"{path}: {key} must be finite")
    import torch
    return tuple(float(x) for x in a) if a.ndim == 1 else torch.from_numpy(a.copy())


def _one_of(z, groups, what, path):
    present = [g for g in groups if any(k in z for k in g)]
    if len(present) != 1:
        opts = " or ".join("(" + ", ".join(g) + ")" for g in groups)
        raise InputValueError(f"{path}: give the {what} as exactly one of {opts}; found keys {sorted(z)}")
    missing = [k for k in present[0] if k not in z]
    if missing:
        raise InputValueError(f"{path}: the {what} needs {', '.join(present[0])}; missing {', '.join(missing)}")
    return present[0]


def load_image_target(target: str):
    """``(camera, silhouettes)`` of an ``images:PATH`` target: a batched :class:`gendr.Camera` of N
    views and a float32 tensor ``[N, H, W]`` in [0, 1]. Raises
    :class:`~gendr.errors.InputValueError` (missing file, keys or values out of range) and
    :class:`~gendr.errors.ShapeError` (array shapes), each naming the file, the key and the value."""
    import torch
    import gendr
    path = images_path(target)
    if not path.is_file():
        raise InputValueError(f"images target {target!r}: file {str(path)!r} does not exist")
    try:
        z = dict(np.load(path, allow_pickle=False))
    except Exception as exc:  # noqa: BLE001 - any unreadable file is the same user error
        raise InputValueError(f"images target {target!r}: {str(path)!r} is not a readable .npz file ({exc})") from None
    if "images" not in z:
        raise InputValueError(f"{path}: no 'images' array; found keys {sorted(z)}")
    im = np.asarray(z["images"])
    if im.ndim != 3 or min(im.shape) < 1:
        raise ShapeError(f"{path}: images must have shape [N, H, W] (N >= 1 silhouettes), got {list(im.shape)}")
    if im.dtype == np.uint8:
        im = im.astype(np.float32) / 255.0
    elif im.dtype == np.bool_:
        im = im.astype(np.float32)
    elif np.issubdtype(im.dtype, np.floating):
        im = im.astype(np.float32)
        if not np.isfinite(im).all() or im.min() < 0 or im.max() > 1:
            raise InputValueError(f"{path}: float images must lie in [0, 1], got values in "
                                  f"[{np.nanmin(im):g}, {np.nanmax(im):g}]")
    else:
        raise InputValueError(f"{path}: images of dtype {im.dtype} are not silhouettes; use float in [0, 1], bool "
                              f"or uint8")
    n = im.shape[0]
    pos = _one_of(z, _POSITION, "camera position", path)
    lens = _one_of(z, _LENS, "camera lens", path)
    clip = {k: _clip_plane(z, k, path) for k in ("near", "far") if k in z}
    if pos[0] == "azimuth":
        eye = gendr.Orbit(*(_scalar_or_n(z, k, n, path) for k in pos))
    else:
        eye = _vec3(z, "eye", n, path)
        if not isinstance(eye, torch.Tensor):
            raise ShapeError(f"{path}: eye must have shape [{n}, 3] (one per image), got [3]")
    at = _vec3(z, "at", n, path, (0.0, 0.0, 0.0))
    up = _vec3(z, "up", n, path, (0.0, 1.0, 0.0))
    lens_values = {k: _scalar_or_n(z, k, n, path) for k in lens}
    try:
        if lens == ("fov_y",):
            cam = gendr.PerspectiveCamera(eye=eye, at=at, up=up, **clip, **lens_values)
        else:
            cam = gendr.IntrinsicsCamera(eye=eye, at=at, up=up, **clip, **lens_values)
    except GendrError as exc:
        raise InputValueError(f"{path}: {exc}") from None
    return cam, torch.from_numpy(im)


def save_image_target(path, images, **camera):
    """Write an ``images:`` file: ``images`` [N, H, W] and the camera arrays (see the module
    docstring), e.g. ``save_image_target("t.npz", sil, azimuth=az, elevation=30.0, distance=4.0,
    fov_y=35.0)``. Returns ``"images:" + path``."""
    arrays = {k: np.asarray(v.detach().cpu() if hasattr(v, "detach") else v) for k, v in camera.items()}
    np.savez(path, images=np.asarray(images.detach().cpu() if hasattr(images, "detach") else images), **arrays)
    return IMAGES_PREFIX + str(path)
