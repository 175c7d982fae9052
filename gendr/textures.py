"""UV texture maps: conventions, input checks and a NumPy reference sampler (no backend imported).

Conventions (docs/conventions.md, "Textures"; chosen to match Mitsuba 3's ``bitmap`` texture and
OpenGL/pyrender, so that the validation compares like with like):

* A texture is an array ``[Ht, Wt, C]`` or ``[B, Ht, Wt, C]``, C = 3 (RGB) or 4 (RGBA; the alpha
  channel is read but not used: coverage comes from the geometry only), float32/float64 albedo,
  linear (no sRGB decoding). Row 0 is the **top** of the image.
* UV coordinates follow OBJ / OpenGL (and trimesh, which converts glTF's to them): u runs left to
  right, **v bottom to top**. Texel (row r, column c) has its centre at
  ``u = (c + ½)/Wt, v = 1 − (r + ½)/Ht``; continuous texel coordinates are
  ``x = u·Wt − ½`` (columns) and ``y = (1 − v)·Ht − ½`` (rows).
* ``bilinear``: the four texels around (x, y), weights (1 − fx, fx) × (1 − fy, fy) with
  ``fx = x − floor(x)``. ``nearest``: texel (floor((1 − v)·Ht), floor(u·Wt)). No mip-mapping.
* Wrap: ``repeat`` (default; index mod size, as Mitsuba's default and OpenGL's ``GL_REPEAT``) or
  ``clamp`` (clamp to the edge texel, ``GL_CLAMP_TO_EDGE`` / Mitsuba ``clamp``). The samplers reduce
  u and v to one period first (:func:`one_period`), so any finite uv samples exactly.
* The lit colour of a pixel is ``texture(uv)·(ambient + diffuse·lambert)``, with uv and the Lambert
  factor interpolated with perspective-correct barycentrics (Gouraud lighting, as without texture).

Differentiability: the sampled colour is differentiable w.r.t. the texture (bilinear: its four
weights; nearest: a one-hot selection) and w.r.t. uv (bilinear only; nearest is piecewise
constant), hence w.r.t. vertices and camera through the barycentrics.
"""
from __future__ import annotations

import numpy as np

from .errors import DTypeError, InputValueError, ParameterError, ShapeError, require_finite

FILTERS = ("bilinear", "nearest")
WRAPS = ("repeat", "clamp")

__all__ = ["FILTERS", "WRAPS", "sample_numpy", "one_period", "check_textured_inputs"]


def _wrap_index(i, n, wrap):
    if wrap == "repeat":
        return np.mod(i, n)
    return np.clip(i, 0, n - 1)


def one_period(u, wrap):
    """``u`` (or v) reduced to what the wrap mode samples alike: u − floor(u) for ``repeat``, u
    clipped to [−1, 2] for ``clamp`` (beyond it every u samples the edge texel). Same samples and
    gradients, but texel coordinates stay small and exact for any finite uv (1e17, 3e38 in float32)."""
    return u - np.floor(u) if wrap == "repeat" else np.clip(u, -1.0, 2.0)


def sample_numpy(texture, uv, filter="bilinear", wrap="repeat"):
    """Reference sampler in float64 NumPy: ``texture`` [Ht, Wt, C], ``uv`` [..., 2] -> [..., C].

    ``filter``: ``"bilinear"`` or ``"nearest"``; ``wrap``: ``"repeat"`` or ``"clamp"`` (conventions
    in the module docstring; v runs bottom to top, texture row 0 is the top). Not differentiable
    (NumPy); the backends' samplers are, and are tested against this one.

    >>> import numpy as np
    >>> from gendr.textures import sample_numpy
    >>> tex = np.zeros((2, 2, 3)); tex[0, 1] = 1.0  # top-right texel white
    >>> sample_numpy(tex, [[0.75, 0.75], [0.5, 0.5]])  # its centre, and the image centre
    array([[1.  , 1.  , 1.  ],
           [0.25, 0.25, 0.25]])
    """
    tex = np.asarray(texture, dtype=np.float64)
    uv = np.asarray(uv, dtype=np.float64)
    Ht, Wt = tex.shape[:2]
    u, v = one_period(uv[..., 0], wrap), one_period(uv[..., 1], wrap)
    if filter == "nearest":
        c = _wrap_index(np.floor(u * Wt).astype(np.int64), Wt, wrap)
        r = _wrap_index(np.floor((1.0 - v) * Ht).astype(np.int64), Ht, wrap)
        return tex[r, c]
    x, y = u * Wt - 0.5, (1.0 - v) * Ht - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    c0, r0 = x0.astype(np.int64), y0.astype(np.int64)
    c = [_wrap_index(c0 + k, Wt, wrap) for k in (0, 1)]
    r = [_wrap_index(r0 + k, Ht, wrap) for k in (0, 1)]
    top = tex[r[0], c[0]] * (1 - fx) + tex[r[0], c[1]] * fx
    bot = tex[r[1], c[0]] * (1 - fx) + tex[r[1], c[1]] * fx
    return top * (1 - fy) + bot * fy


def check_settings(texture_filter, texture_wrap):
    if texture_filter not in FILTERS:
        raise ParameterError(f"Renderer parameter texture_filter={texture_filter!r} must be one of {FILTERS}")
    if texture_wrap not in WRAPS:
        raise ParameterError(f"Renderer parameter texture_wrap={texture_wrap!r} must be one of {WRAPS}")


def check_textured_inputs(be, verts, faces_a, texture, uvs, uv_faces):
    """Convert and check a texture and its UVs through backend ``be``; returns (texture, uvs,
    uv_faces) as backend arrays. Shapes: texture [Ht, Wt, C] or [B, Ht, Wt, C] (C in {3, 4},
    float32/float64, finite; cast to the vertices' dtype), uvs [T, 2] or [B, T, 2] (finite), uv_faces
    [F, 3] integer indices in [0, T) (default: ``faces``, then T must equal V)."""
    if uvs is None:
        raise ParameterError("a texture needs uvs ([T, 2] or [B, T, 2] texture coordinates)")
    try:  # dtype first: textures are float albedo
        be.float_array(texture, "texture")
    except DTypeError as e:
        raise DTypeError(f"{e}: textures are float albedo in [0, 1] (an 8-bit image: divide by 255)") from None
    tex = be.float_array(texture, "texture", like=verts)
    if len(tex.shape) not in (3, 4) or tex.shape[-1] not in (3, 4) or tex.shape[-2] < 1 or tex.shape[-3] < 1:
        raise ShapeError(f"texture must have shape [Ht, Wt, 3|4] or [B, Ht, Wt, 3|4], got {list(tex.shape)}")
    require_finite(be, tex, "texture")
    be.float_array(uvs, "uvs")
    uv = be.float_array(uvs, "uvs", like=verts)
    if len(uv.shape) not in (2, 3) or uv.shape[-1] != 2 or uv.shape[-2] < 1:
        raise ShapeError(f"uvs must have shape [T, 2] or [B, T, 2], got {list(uv.shape)}")
    require_finite(be, uv, "uvs")
    T, F = uv.shape[-2], faces_a.shape[0]
    if uv_faces is None:
        V = verts.shape[-2]
        if T != V:
            raise ShapeError(f"without uv_faces, uvs must hold one uv per vertex: [{V}, 2], got {list(uv.shape)} "
                             f"(give uv_faces [F, 3] to index uvs separately, as OBJ files do)")
        uvf = faces_a
    else:
        if isinstance(uv_faces, (list, tuple)) and len(uv_faces) == 0:
            uv_faces = np.zeros((0, 3), dtype=np.int64)  # as faces=[] ([] is float64 to NumPy)
        uvf = be.index_array(uv_faces, "uv_faces")
        if len(uvf.shape) != 2 or tuple(uvf.shape) != (F, 3):
            raise ShapeError(f"uv_faces must have shape [F, 3] = [{F}, 3] (one uv index per face corner), "
                             f"got {list(uvf.shape)}")
        if F > 0:
            lo, hi = be.index_range(uvf)
            if lo < 0 or hi >= T:
                raise InputValueError(f"uv_faces indices must lie in [0, {T - 1}] (T = {T} uvs), got range [{lo}, {hi}]")
    return tex, uv, uvf
