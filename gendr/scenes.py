"""Built-in procedural meshes (pure numpy) and mesh loading.

Every scene function returns a :class:`Mesh` roughly centred at the origin and inside the unit ball,
with outward-facing counter-clockwise winding (right-handed, OpenGL convention: seen from outside, a
face's vertices go counter-clockwise, so its normal ``(v1 - v0) x (v2 - v0)`` points out of the solid).
+Y is up; composite objects (airplane, chair, teapot) stand upright and face +X or +Z.

>>> from gendr.scenes import SCENES, icosphere
>>> icosphere(3).num_faces
1280
>>> sorted(SCENES)[:3]
['airplane', 'chair', 'cube']

Meshes from files go through :func:`load_mesh` (needs ``trimesh``, imported lazily).
"""
from __future__ import annotations

import inspect
import math
import numbers
import os
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .errors import BackendUnavailableError, InputValueError, ParameterError, ShapeError, UnknownNameError

__all__ = ["Mesh", "icosphere", "cube", "torus", "thin_shape", "airplane", "chair", "teapot_like",
           "tetrahedron", "open_mesh", "degenerate_mesh", "SCENES", "get_scene", "load_mesh",
           "normalize", "concatenate", "merge_vertices", "TexturedMesh", "textured_cube", "checker_texture", "TEXTURED_SCENES",
           "get_textured_scene", "load_textured_mesh"]


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh.

    Attributes:
        vertices: float64 array ``[V, 3]``, world coordinates.
        faces: int64 array ``[F, 3]``, indices into ``vertices``; counter-clockwise seen from
            outside (outward normals) for the built-in closed scenes.

    The constructor converts the inputs (any array-like) to these dtypes and checks shapes and that
    every index lies in ``[0, V)``; it raises :class:`~gendr.errors.ShapeError` or
    :class:`~gendr.errors.InputValueError`. NumPy on the CPU, not differentiable: convert to a
    backend tensor (e.g. ``torch.tensor(mesh.vertices, requires_grad=True)``) to render.

    >>> from gendr.scenes import Mesh
    >>> m = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> m, m.vertices.dtype, m.faces.dtype, m.face_areas()
    (Mesh(V=3, F=1), dtype('float64'), dtype('int64'), array([0.5]))
    >>> Mesh([[0, 0, 0]], [[0, 1, 2]])
    Traceback (most recent call last):
    ...
    gendr.errors.InputValueError: mesh face indices must lie in [0, 1), got range [0, 2]
    """

    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self):
        try:
            v = np.ascontiguousarray(np.asarray(self.vertices, dtype=np.float64))
        except (TypeError, ValueError) as e:  # ragged lists, strings
            raise InputValueError(f"mesh vertices must be numbers of shape [V, 3]: {e}") from None
        try:
            f = np.asarray(self.faces)
        except ValueError as e:  # ragged lists
            raise ShapeError(f"mesh faces must have shape [F, 3]: {e}") from None
        if f.size == 0:
            f = f.reshape(-1, 3)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ShapeError(f"mesh vertices must have shape [V, 3], got {tuple(v.shape)}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise ShapeError(f"mesh faces must have shape [F, 3], got {tuple(f.shape)}")
        if f.size and (f.dtype.kind not in "iuf" or not np.all(np.isfinite(f)) or not np.all(np.mod(f, 1) == 0)):
            raise InputValueError(f"mesh face indices must be integers, got dtype {f.dtype}")
        if f.size and (f.min() < 0 or f.max() >= len(v)):  # (before the cast: 1e20 or a uint64 would wrap)
            lo, hi = (int(f.min()), int(f.max())) if f.dtype.kind in "iu" else (f"{f.min():.15g}", f"{f.max():.15g}")
            raise InputValueError(f"mesh face indices must lie in [0, {len(v)}), got range [{lo}, {hi}]")
        f = np.ascontiguousarray(f.astype(np.int64))
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)

    def __repr__(self) -> str:
        return f"Mesh(V={self.num_vertices}, F={self.num_faces})"

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_faces(self) -> int:
        return int(self.faces.shape[0])

    def face_normals(self, normalized: bool = True) -> np.ndarray:
        """``[F, 3]`` normals ``(v1 - v0) x (v2 - v0)`` (length = twice the area unless normalized)."""
        t = self.vertices[self.faces]
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        if normalized:
            length = np.linalg.norm(n, axis=1, keepdims=True)
            n = n / np.where(length > 0, length, 1.0)
        return n

    def face_areas(self) -> np.ndarray:
        """``[F]`` triangle areas."""
        return 0.5 * np.linalg.norm(self.face_normals(normalized=False), axis=1)

    def vertex_normals(self) -> np.ndarray:
        """``[V, 3]`` unit area-weighted vertex normals (zero for unused vertices)."""
        n = np.zeros_like(self.vertices)
        fn = self.face_normals(normalized=False)
        for k in range(3):
            np.add.at(n, self.faces[:, k], fn)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return n / np.where(length > 0, length, 1.0)

    def signed_volume(self) -> float:
        """Signed enclosed volume; > 0 for a closed mesh with outward normals."""
        t = self.vertices[self.faces]
        return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)

    @property
    def bounding_radius(self) -> float:
        """Largest distance of a vertex from the origin."""
        return float(np.linalg.norm(self.vertices, axis=1).max()) if self.num_vertices else 0.0


# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------

def concatenate(meshes) -> Mesh:
    """One mesh holding all parts (vertices are not merged, so closed parts stay closed).

    >>> from gendr import scenes
    >>> scenes.concatenate([scenes.cube(), scenes.tetrahedron()])
    Mesh(V=12, F=16)
    """
    vs, fs, offset = [], [], 0
    for m in meshes:
        vs.append(m.vertices)
        fs.append(m.faces + offset)
        offset += m.num_vertices
    if not vs:
        raise InputValueError("concatenate needs at least one mesh, got none")
    return Mesh(np.concatenate(vs), np.concatenate(fs))


def normalize(mesh: Mesh, radius: float = 1.0) -> Mesh:
    """Centre ``mesh`` on its bounding-box centre and scale it so the farthest vertex is at ``radius``
    (world units); returns a new :class:`Mesh`.

    >>> from gendr import scenes
    >>> scenes.normalize(scenes.cube(2.0)).bounding_radius
    1.0
    """
    if isinstance(radius, bool) or not (isinstance(radius, numbers.Real) and math.isfinite(radius) and radius > 0):
        raise InputValueError(f"normalize radius must be a finite number > 0, got {radius!r}")
    v = mesh.vertices
    if len(v) == 0:
        return mesh
    if not np.all(np.isfinite(v)):
        raise InputValueError("cannot normalize a mesh with non-finite vertices")
    centre = 0.5 * v.min(axis=0) + 0.5 * v.max(axis=0)  # (halves first: no overflow near 1.8e308)
    v = v - centre
    m = float(np.abs(v).max())
    if m > 0:  # the farthest vertex's distance as m·|v/m| (|v| itself overflows for coordinates ~1e200)
        u = v / m
        v = u * (float(radius) / float(np.linalg.norm(u, axis=1).max()))
    return Mesh(v, mesh.faces)


def _orient_convex(vertices: np.ndarray, faces: np.ndarray, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Flip faces of a convex (star-shaped around ``centre``) mesh so that normals point outwards."""
    t = vertices[faces]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    out = np.einsum("ij,ij->i", n, t.mean(axis=1) - np.asarray(centre, dtype=np.float64)) < 0
    faces = faces.copy()
    faces[out] = faces[out][:, ::-1]
    return faces


def _rotation(axis, degrees: float) -> np.ndarray:
    """3x3 right-handed rotation about ``axis`` by ``degrees`` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    th = math.radians(degrees)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(th) * k + (1 - math.cos(th)) * (k @ k)


def _transform(mesh: Mesh, scale=(1.0, 1.0, 1.0), rotation=None, translate=(0.0, 0.0, 0.0)) -> Mesh:
    """x -> R (S x) + t. A mirroring scale (det < 0) flips the faces to keep them outward."""
    s = np.broadcast_to(np.asarray(scale, dtype=np.float64), (3,))
    v = mesh.vertices * s
    if rotation is not None:
        v = v @ np.asarray(rotation).T
    faces = mesh.faces if np.prod(s) > 0 else mesh.faces[:, ::-1]
    return Mesh(v + np.asarray(translate, dtype=np.float64), faces)


def _box(centre=(0.0, 0.0, 0.0), half=(0.5, 0.5, 0.5), rotation=None) -> Mesh:
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    # two triangles per side; orientation fixed by _orient_convex
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64)
    faces = _orient_convex(corners, faces)
    return _transform(Mesh(corners, faces), half, rotation, centre)


def _frustum(p0, p1, r0: float, r1: float, segments: int = 24) -> Mesh:
    """Closed truncated cone (cylinder when r0 == r1) from point p0 (radius r0) to p1 (radius r1)."""
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    axis = p1 - p0
    h = float(np.linalg.norm(axis))
    ang = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    ring = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
    bottom = ring * r0 + [0.0, 0.0, -h / 2]
    top = ring * r1 + [0.0, 0.0, h / 2]
    v = np.concatenate([bottom, top, [[0.0, 0.0, -h / 2], [0.0, 0.0, h / 2]]])
    i = np.arange(segments)
    j = (i + 1) % segments
    cb, ct = 2 * segments, 2 * segments + 1
    faces = np.concatenate([
        np.stack([i, j, j + segments], 1), np.stack([i, j + segments, i + segments], 1),
        np.stack([np.full_like(i, cb), j, i], 1), np.stack([np.full_like(i, ct), i + segments, j + segments], 1),
    ]).astype(np.int64)
    faces = _orient_convex(v, faces)
    # rotate +Z onto the axis direction
    d = axis / h
    z = np.array([0.0, 0.0, 1.0])
    c = float(np.dot(z, d))
    if c > 1 - 1e-12:
        R = np.eye(3)
    elif c < -1 + 1e-12:
        R = _rotation((1.0, 0.0, 0.0), 180.0)
    else:
        R = _rotation(np.cross(z, d), math.degrees(math.acos(c)))
    return _transform(Mesh(v, faces), 1.0, R, 0.5 * (p0 + p1))


def _torus_z(R: float, r: float, n_major: int, n_minor: int) -> Mesh:
    """Torus around the Z axis, outward winding."""
    u = np.linspace(0.0, 2 * math.pi, n_major, endpoint=False)[:, None]
    w = np.linspace(0.0, 2 * math.pi, n_minor, endpoint=False)[None, :]
    x = (R + r * np.cos(w)) * np.cos(u)
    y = (R + r * np.cos(w)) * np.sin(u)
    z = np.broadcast_to(r * np.sin(w), x.shape)
    v = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    i = np.arange(n_major)[:, None]
    j = np.arange(n_minor)[None, :]
    a = i * n_minor + j
    b = ((i + 1) % n_major) * n_minor + j
    c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    d = i * n_minor + (j + 1) % n_minor
    # ∂P/∂u × ∂P/∂w points outwards, so (a, b, c) ordered u-then-w is counter-clockwise from outside
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return Mesh(v, faces.astype(np.int64))


_ICOSAHEDRON_FACES = np.array([
    [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
    [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
    [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)


def _check_int(name: str, value, lo: int, hi: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo or (hi is not None and value > hi):
        rng = f">= {lo}" if hi is None else f"in [{lo}, {hi}]"
        raise InputValueError(f"{name} must be an integer {rng}, got {value!r}")
    return int(value)


def _check_pos(name: str, value) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = float("nan")
    if not (math.isfinite(x) and x > 0):
        raise InputValueError(f"{name} must be a finite number > 0, got {value!r}")
    return x


# ------------------------------------------------------------------------------------------------
# scenes
# ------------------------------------------------------------------------------------------------

def icosphere(subdivisions: int = 3, radius: float = 1.0) -> Mesh:
    """Geodesic sphere: an icosahedron subdivided ``subdivisions`` times (each face into 4).

    Faces: 20·4^s (s = 3: 1,280 faces, 642 vertices; s = 5: 20,480 faces). Vertices: 10·4^s + 2.
    ``subdivisions``: int in [0, 8]; ``radius``: world units > 0 (else InputValueError).

    >>> from gendr.scenes import icosphere
    >>> icosphere(1), icosphere(1, radius=2.0).bounding_radius
    (Mesh(V=42, F=80), 2.0)
    """
    s = _check_int("icosphere subdivisions", subdivisions, 0, 8)
    radius = _check_pos("icosphere radius", radius)
    t = (1.0 + math.sqrt(5.0)) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t],
                  [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=np.float64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    f = _orient_convex(v, _ICOSAHEDRON_FACES)
    for _ in range(s):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = v[uniq[:, 0]] + v[uniq[:, 1]]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inverse.reshape(-1) + len(v)
        nf = len(f)
        ab, bc, ca = m[:nf], m[nf:2 * nf], m[2 * nf:]
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        f = np.concatenate([np.stack([a, ab, ca], 1), np.stack([b, bc, ab], 1),
                            np.stack([c, ca, bc], 1), np.stack([ab, bc, ca], 1)])
        v = np.concatenate([v, mid])
    return Mesh(v * radius, f)


def cube(size: float = 1.0) -> Mesh:
    """Axis-aligned cube with edge length ``size`` centred at the origin (8 vertices, 12 faces).

    The default ``size=1`` fits in the unit ball (half diagonal 0.866).

    >>> from gendr.scenes import cube
    >>> m = cube(1.0)
    >>> m, round(m.signed_volume(), 6), round(m.bounding_radius, 3)
    (Mesh(V=8, F=12), 1.0, 0.866)
    """
    size = _check_pos("cube size", size)
    return _box(half=(size / 2,) * 3)


def torus(R: float = 0.7, r: float = 0.3, n_major: int = 48, n_minor: int = 24) -> Mesh:
    """Ring torus lying in the XZ plane (axis +Y): major radius ``R``, tube radius ``r``.

    ``2·n_major·n_minor`` faces; genus 1 (Euler characteristic 0). Default fits the unit ball (R + r = 1).

    >>> from gendr.scenes import torus
    >>> torus(n_major=8, n_minor=4)
    Mesh(V=32, F=64)
    """
    R, r = _check_pos("torus R", R), _check_pos("torus r", r)
    if r >= R:
        raise InputValueError(f"torus needs r < R (a ring torus), got R={R!r}, r={r!r}")
    n_major = _check_int("torus n_major", n_major, 3)
    n_minor = _check_int("torus n_minor", n_minor, 3)
    # rotate the Z axis onto +Y: (x, y, z) -> (x, z, -y)
    return _transform(_torus_z(R, r, n_major, n_minor), 1.0, _rotation((1.0, 0.0, 0.0), -90.0))


def thin_shape(length: float = 1.8, width: float = 0.03) -> Mesh:
    """A needle: a long thin box (``length`` x ``width`` x ``width``) turned diagonally in the image.

    Tests soft coverage of features thinner than a pixel.
    """
    length, width = _check_pos("thin_shape length", length), _check_pos("thin_shape width", width)
    R = _rotation((0.0, 1.0, 0.0), 20.0) @ _rotation((0.0, 0.0, 1.0), 30.0)
    return _box(half=(length / 2, width / 2, width / 2), rotation=R)


def airplane() -> Mesh:
    """An airplane from primitives: ellipsoid fuselage (nose at +X), wings, engines, tail plane, fin."""
    body = _transform(icosphere(2), (0.9, 0.11, 0.11))
    wings = _box(centre=(0.05, 0.0, 0.0), half=(0.14, 0.018, 0.78))
    engines = [_frustum((0.22, -0.08, z), (-0.02, -0.08, z), 0.05, 0.04, 16) for z in (-0.38, 0.38)]
    tail = _box(centre=(-0.74, 0.02, 0.0), half=(0.08, 0.014, 0.28))
    fin = _box(centre=(-0.76, 0.17, 0.0), half=(0.08, 0.15, 0.014))
    return normalize(concatenate([body, wings, *engines, tail, fin]), radius=0.95)


def chair() -> Mesh:
    """A chair: seat, back rest (at -Z) and four legs, standing on -Y."""
    seat = _box(centre=(0.0, 0.0, 0.0), half=(0.4, 0.04, 0.4))
    back = _box(centre=(0.0, 0.46, -0.37), half=(0.4, 0.42, 0.03))
    legs = [_box(centre=(sx * 0.34, -0.42, sz * 0.34), half=(0.035, 0.38, 0.035))
            for sx in (-1, 1) for sz in (-1, 1)]
    return normalize(concatenate([seat, back, *legs]), radius=0.95)


def teapot_like() -> Mesh:
    """An asymmetric teapot: ellipsoid body, spout (+X), ring handle (-X), lid and knob on top."""
    body = _transform(icosphere(3), (0.5, 0.36, 0.5))
    spout = _frustum((0.36, -0.06, 0.0), (0.8, 0.26, 0.0), 0.09, 0.035, 20)
    handle = _transform(_torus_z(0.2, 0.04, 32, 12), 1.0, None, (-0.5, 0.03, 0.0))
    lid = _frustum((0.0, 0.3, 0.0), (0.0, 0.38, 0.0), 0.26, 0.2, 32)
    knob = _transform(icosphere(1), 0.07, None, (0.0, 0.44, 0.0))
    return normalize(concatenate([body, spout, handle, lid, knob]), radius=0.95)


def tetrahedron() -> Mesh:
    """Regular tetrahedron inscribed in the unit ball (4 vertices, 4 faces).

    >>> from gendr.scenes import tetrahedron
    >>> tetrahedron(), round(tetrahedron().bounding_radius, 6)
    (Mesh(V=4, F=4), 1.0)
    """
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=np.float64) / math.sqrt(3.0)
    f = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]], dtype=np.int64)
    return Mesh(v, _orient_convex(v, f))


def open_mesh(rings: int = 8, segments: int = 32) -> Mesh:
    """An open hemispherical bowl (opening towards +Y): not watertight, its inside shows back faces.

    Normals point away from the sphere's centre (out of the bowl's convex side).
    """
    rings = _check_int("open_mesh rings", rings, 1)
    segments = _check_int("open_mesh segments", segments, 3)
    # polar angle from the bottom pole (-Y) up to the rim (equator)
    theta = np.linspace(0.0, math.pi / 2, rings + 1)[1:]
    phi = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    ring = np.stack([np.sin(theta)[:, None] * np.cos(phi), -np.cos(theta)[:, None] * np.ones_like(phi),
                     np.sin(theta)[:, None] * np.sin(phi)], axis=-1).reshape(-1, 3)
    v = np.concatenate([[[0.0, -1.0, 0.0]], ring])
    j = np.arange(segments)
    jn = (j + 1) % segments
    faces = [np.stack([np.zeros_like(j), 1 + j, 1 + jn], 1)]
    for k in range(rings - 1):
        a, b = 1 + k * segments + j, 1 + k * segments + jn
        c, d = a + segments, b + segments
        faces += [np.stack([a, c, d], 1), np.stack([a, d, b], 1)]
    faces = _orient_convex(v, np.concatenate(faces).astype(np.int64))
    # centre vertically: y in [-1, 0] -> scaled into the unit ball around the origin
    return _transform(Mesh(v, faces), 0.88, None, (0.0, 0.44, 0.0))


def degenerate_mesh() -> Mesh:
    """A stress test: a tetrahedron plus zero-area faces (repeated index, collinear vertices), a tiny
    face (area ~1e-14), a needle sliver, a duplicated face and an unused vertex."""
    tet = tetrahedron()
    v = list(tet.vertices * 0.7)
    f = [tuple(x) for x in tet.faces]
    base = len(v)
    v += [[-0.6, -0.6, 0.2], [0.0, 0.0, 0.2], [0.6, 0.6, 0.2],   # collinear
          [0.3, -0.5, 0.5], [0.3 + 1e-7, -0.5, 0.5], [0.3, -0.5 + 1e-7, 0.5],   # tiny
          [-0.8, 0.1, -0.3], [0.8, 0.1 + 1e-4, -0.3], [0.8, 0.1, -0.3],   # sliver
          [0.9, -0.4, 0.0]]   # unused
    f += [(0, 0, 1),                        # repeated index: zero area
          (base, base + 1, base + 2),       # collinear: zero area
          (base + 3, base + 4, base + 5),   # tiny
          (base + 6, base + 7, base + 8),   # sliver
          f[0]]                             # duplicate
    return Mesh(np.array(v), np.array(f, dtype=np.int64))


#: name -> scene function (call with no arguments for the defaults)
SCENES: dict[str, Callable[..., Mesh]] = {
    "icosphere": icosphere,
    "cube": cube,
    "torus": torus,
    "thin_shape": thin_shape,
    "airplane": airplane,
    "chair": chair,
    "teapot_like": teapot_like,
    "tetrahedron": tetrahedron,
    "open_mesh": open_mesh,
    "degenerate_mesh": degenerate_mesh,
}

#: scenes that are closed 2-manifolds with outward winding (every part watertight)
CLOSED_SCENES = ("icosphere", "cube", "torus", "thin_shape", "airplane", "chair", "teapot_like", "tetrahedron")


def get_scene(name: str, **kwargs) -> Mesh:
    """Build the built-in scene ``name`` (keyword arguments go to its function).

    Raises :class:`~gendr.errors.UnknownNameError` listing the valid names, and
    :class:`~gendr.errors.ParameterError` for a keyword the scene does not take.

    >>> from gendr.scenes import get_scene
    >>> get_scene("torus", n_major=8, n_minor=4)
    Mesh(V=32, F=64)
    >>> get_scene("sphere")
    Traceback (most recent call last):
    ...
    gendr.errors.UnknownNameError: unknown scene 'sphere' (did you mean 'icosphere'?); valid scene names: airplane, ...
    """
    if not isinstance(name, str) or name not in SCENES:
        raise UnknownNameError("scene", name, sorted(SCENES))
    return _call_scene(SCENES[name], "scene", name, kwargs)


def _call_scene(make, kind, name, kwargs):
    accepted = inspect.signature(make).parameters
    for key in kwargs:
        if key not in accepted:
            raise ParameterError(f"{kind} {name!r} got unexpected parameter {key!r}; it accepts "
                                 f"{', '.join(accepted) or 'no parameters'}")
    return make(**kwargs)


def _trimesh_load(path):
    """``(path as str, trimesh.Trimesh, material file names)`` of a mesh file, scenes concatenated, as
    stored (no processing); the names are those an OBJ's ``mtllib`` lines give (:func:`_scan_obj`;
    none for other formats). Typed errors naming the path (missing, not a file, unreadable, no trimesh)."""
    if not isinstance(path, (str, os.PathLike)):
        raise InputValueError(f"mesh file path must be a str or os.PathLike, got {path!r}")
    p = os.fspath(path)
    if not os.path.isfile(p):
        raise InputValueError(f"mesh file {p!r} does not exist" if not os.path.exists(p)
                              else f"mesh path {p!r} is not a file")
    try:
        import trimesh
    except ImportError as e:  # pragma: no cover - trimesh is a dev dependency
        raise BackendUnavailableError(f"reading mesh file {p!r} needs trimesh (pip install trimesh): {e}") from None
    materials = _scan_obj(p) if p.lower().endswith(".obj") else set()
    try:
        return p, trimesh.load(p, force="mesh", process=False), materials
    except Exception as e:  # trimesh raises many kinds
        raise InputValueError(f"cannot read mesh file {p!r}: {type(e).__name__}: {e}") from None


def _scan_obj(path) -> set:
    """One pass over an OBJ file, beside trimesh's parse: the material file names its ``mtllib``
    lines give (a name with spaces: the rest of the line; or several names), and InputValueError
    at a face index 0. OBJ indices start at 1 (negative: relative); trimesh reads a 0 as the last
    vertex (a wrong, degenerate face) instead of refusing it."""
    names = set()
    with open(path, errors="replace") as f:
        for n, line in enumerate(f, 1):
            toks = line.split()
            if toks[:1] == ["f"] and any(tok.split("/")[0] == "0" for tok in toks[1:]):
                raise InputValueError(f"mesh file {path!r} line {n}: {line.strip()!r} has index 0; OBJ indices "
                                      f"start at 1 (or are negative, counting back from the last vertex)")
            if toks[:1] == ["mtllib"] and len(toks) > 1:
                rest = line.split(None, 1)[1]
                names.update((rest.strip(), *rest.split()))
    return names


def load_mesh(path) -> Mesh:
    """Read a triangle mesh file (OBJ, PLY, STL, OFF, GLB/GLTF, ... anything trimesh reads).

    Scenes with several geometries are concatenated into one mesh (transforms applied); polygons are
    triangulated. Vertices are trimesh's, not the file's ``v`` lines: one per distinct (position,
    normal, uv) of the face corners, unused ones dropped, groups possibly reordered; a file that gives
    each face its own normals (``f a//n``) comes back as a triangle soup, one vertex per corner
    (flat-shaded, its faces unconnected): :func:`merge_vertices` joins vertices at equal positions.
    Raises
    :class:`~gendr.errors.InputValueError` naming the path when it cannot be read, holds no faces or
    has non-finite vertices, and :class:`~gendr.errors.BackendUnavailableError` without trimesh.

    >>> import os, tempfile
    >>> from gendr.scenes import load_mesh
    >>> path = os.path.join(tempfile.mkdtemp(), "tri.obj")
    >>> _ = open(path, "w").write("v 0 0 0\\nv 1 0 0\\nv 0 1 0\\nf 1 2 3\\n")
    >>> load_mesh(path)
    Mesh(V=3, F=1)
    """
    p, loaded, _ = _trimesh_load(path)
    faces = getattr(loaded, "faces", None)
    vertices = getattr(loaded, "vertices", None)
    if faces is None or vertices is None or len(faces) == 0:
        raise InputValueError(f"mesh file {p!r} contains no triangle faces")
    vertices = np.asarray(vertices, dtype=np.float64)
    if not np.all(np.isfinite(vertices)):
        raise InputValueError(f"mesh file {p!r} has non-finite vertex coordinates")
    try:
        return Mesh(vertices, np.asarray(faces))
    except (ShapeError, InputValueError) as e:
        raise InputValueError(f"mesh file {p!r}: {e}") from None


def merge_vertices(mesh: Mesh) -> Mesh:
    """``mesh`` with vertices at identical positions merged into one (first occurrence order kept,
    faces re-indexed); the mesh itself where all positions differ.

    >>> from gendr.scenes import Mesh, merge_vertices
    >>> soup = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [3, 4, 5]])
    >>> m = merge_vertices(soup)
    >>> m, m.faces.tolist()
    (Mesh(V=4, F=2), [[0, 1, 2], [1, 3, 2]])
    """
    v = np.asarray(mesh.vertices)
    _, first, inverse = np.unique(v, axis=0, return_index=True, return_inverse=True)
    if len(first) == len(v):
        return mesh
    order = np.argsort(first)  # unique rows in order of first occurrence
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return Mesh(v[np.sort(first)], rank[np.asarray(inverse).reshape(-1)][np.asarray(mesh.faces)])


# ------------------------------------------------------------------------------------------------
# textured meshes
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class TexturedMesh(Mesh):
    """A triangle mesh with a UV texture map (OBJ-style: faces index positions and uvs separately).

    Attributes (besides :class:`Mesh`'s):
        uvs: float64 ``[T, 2]`` texture coordinates (u right, v up; docs/conventions.md, Textures).
        uv_faces: int64 ``[F, 3]`` indices into ``uvs`` per face corner.
        texture: float64 ``[Ht, Wt, C]``, C = 3 or 4, albedo in [0, 1] (a uint8 texture is divided by
            255, a uint16 one by 65535), row 0 at the top.

    Render with ``Renderer.render(m.vertices, m.faces, cam, texture=m.texture, uvs=m.uvs,
    uv_faces=m.uv_faces)``. Raises ShapeError / InputValueError for bad shapes or indices.

    >>> from gendr.scenes import textured_cube
    >>> m = textured_cube()
    >>> m, m.uvs.shape, m.uv_faces.shape, m.texture.dtype
    (TexturedMesh(V=8, F=12, T=24, texture=(32, 48, 3)), (24, 2), (12, 3), dtype('float64'))
    """

    uvs: np.ndarray = None
    uv_faces: np.ndarray = None
    texture: np.ndarray = None

    def __post_init__(self):
        super().__post_init__()
        uv = np.ascontiguousarray(np.asarray(self.uvs, dtype=np.float64))
        uvf = np.asarray(self.uv_faces)
        tex = np.asarray(self.texture)
        # 8- and 16-bit images mean 0..255 and 0..65535 (the Renderer refuses integer textures; here
        # the meaning is clear); other integers or bools have none
        if tex.dtype.kind in "iub" and tex.dtype not in (np.uint8, np.uint16):
            raise InputValueError(f"mesh texture of dtype {tex.dtype}: give float albedo in [0, 1], or uint8 / uint16 "
                                  f"image values")
        scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(tex.dtype, 1.0)
        tex = np.ascontiguousarray(tex.astype(np.float64) / scale)
        if uv.ndim != 2 or uv.shape[1] != 2 or not np.all(np.isfinite(uv)):
            raise ShapeError(f"mesh uvs must be finite with shape [T, 2], got {tuple(uv.shape)}")
        if uvf.shape != self.faces.shape or (uvf.size and not np.issubdtype(uvf.dtype, np.integer)):
            raise ShapeError(f"mesh uv_faces must be integers of shape {tuple(self.faces.shape)}, got "
                             f"{tuple(uvf.shape)} {uvf.dtype}")
        uvf = np.ascontiguousarray(uvf.astype(np.int64))
        if uvf.size and (uvf.min() < 0 or uvf.max() >= len(uv)):
            raise InputValueError(f"mesh uv_faces must lie in [0, {len(uv)}), got range [{int(uvf.min())}, {int(uvf.max())}]")
        if tex.ndim != 3 or tex.shape[2] not in (3, 4) or not np.all(np.isfinite(tex)):
            raise ShapeError(f"mesh texture must be finite with shape [Ht, Wt, 3|4], got {tuple(tex.shape)}")
        object.__setattr__(self, "uvs", uv)
        object.__setattr__(self, "uv_faces", uvf)
        object.__setattr__(self, "texture", tex)

    def __repr__(self) -> str:
        return f"TexturedMesh(V={self.num_vertices}, F={self.num_faces}, T={len(self.uvs)}, texture={self.texture.shape})"

    def corner_uvs(self) -> np.ndarray:
        """``[F, 3, 2]`` the uv of every face corner."""
        return self.uvs[self.uv_faces]


def checker_texture(height: int = 32, width: int = 48, square: int = 4) -> np.ndarray:
    """A procedural ``[height, width, 3]`` texture: a 3×2 atlas of cells (one per cube side), each a
    checker of ``square``-texel squares in two colours of its own times a smooth diagonal gradient.
    Values are multiples of 1/255 (exact in 8-bit references). float64 NumPy, row 0 at the top.

    >>> from gendr.scenes import checker_texture
    >>> t = checker_texture(8, 12, square=2)
    >>> t.shape, t.dtype, bool(((t >= 0) & (t <= 1)).all())
    ((8, 12, 3), dtype('float64'), True)
    """
    h, w = _check_int("texture height", height, 2), _check_int("texture width", width, 2)
    sq = _check_int("checker square", square, 1)
    r, c = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    cell = (r * 2 // h) * 3 + (c * 3 // w)  # 0..5
    palette = np.array([[230, 60, 40], [40, 170, 60], [50, 80, 220], [240, 200, 30], [200, 60, 200], [30, 200, 210]])
    checker = ((r // sq) + (c // sq)) % 2
    base = np.where(checker[..., None] == 1, palette[cell], 255 - palette[cell] // 2)
    grad = 0.55 + 0.45 * (r / max(h - 1, 1) + c / max(w - 1, 1)) / 2
    return np.round(base * grad[..., None]) / 255.0


def textured_cube(size: float = 1.0, texture: np.ndarray | None = None) -> TexturedMesh:
    """The cube of :func:`cube` (8 positions, 12 faces) with a texture atlas: side k uses cell
    (k mod 3, k div 3) of a 3×2 grid of :func:`checker_texture` (inset by 5 % so bilinear filtering
    never reads a neighbouring cell). 24 uvs indexed per face corner (``uv_faces`` ≠ ``faces``, as in
    an OBJ file).

    >>> import torch, gendr
    >>> from gendr.scenes import textured_cube
    >>> m = textured_cube()
    >>> r = gendr.Renderer(image_size=8, backend="torch", blend="hard")
    >>> img = r.render(torch.tensor(m.vertices), m.faces, gendr.orbit_camera(30.0, 20.0, 3.0),
    ...                texture=torch.tensor(m.texture), uvs=torch.tensor(m.uvs), uv_faces=m.uv_faces)
    >>> img.shape, img.dtype
    (torch.Size([1, 8, 8, 4]), torch.float64)
    """
    size = _check_pos("cube size", size)
    tex = checker_texture() if texture is None else texture
    positions, uvs, faces, uv_faces = [], [], [], []
    key = {}
    axes = np.eye(3)
    sides = [(a, sgn) for a in range(3) for sgn in (1.0, -1.0)]
    for k, (a, sgn) in enumerate(sides):
        n = axes[a] * sgn
        t1 = axes[(a + 1) % 3] * sgn  # t1 x t2 = n (right-handed, counter-clockwise seen from outside)
        t2 = axes[(a + 2) % 3]
        cu, cv = k % 3, k // 3
        corner_ids, uv_ids = [], []
        for s1, s2 in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            p = 0.5 * size * (n + s1 * t1 + s2 * t2)
            pk = tuple(np.round(p, 12))
            if pk not in key:
                key[pk] = len(positions)
                positions.append(p)
            corner_ids.append(key[pk])
            uv_ids.append(len(uvs))
            # v up: cell row cv counted from the top of the image
            uvs.append(((cu + 0.05 + 0.9 * (s1 + 1) / 2) / 3, 1 - (cv + 0.05 + 0.9 * (1 - s2) / 2) / 2))
        for tri in ((0, 1, 2), (0, 2, 3)):
            faces.append([corner_ids[i] for i in tri])
            uv_faces.append([uv_ids[i] for i in tri])
    return TexturedMesh(np.array(positions), np.array(faces), uvs=np.array(uvs), uv_faces=np.array(uv_faces),
                        texture=tex)


TEXTURED_SCENES: dict[str, Callable[..., TexturedMesh]] = {"textured_cube": textured_cube}


def get_textured_scene(name: str, **kwargs) -> TexturedMesh:
    """Build the built-in textured scene ``name`` (:data:`TEXTURED_SCENES`); raises
    :class:`~gendr.errors.UnknownNameError` for another name.

    >>> from gendr.scenes import get_textured_scene
    >>> get_textured_scene("textured_cube")
    TexturedMesh(V=8, F=12, T=24, texture=(32, 48, 3))
    """
    if not isinstance(name, str) or name not in TEXTURED_SCENES:
        raise UnknownNameError("textured scene", name, sorted(TEXTURED_SCENES))
    return _call_scene(TEXTURED_SCENES[name], "textured scene", name, kwargs)


def _obj_has_texture_map(path, names) -> bool:
    """Whether one of the material files ``names`` (an OBJ's ``mtllib``, next to ``path``) exists
    with a ``map_Kd`` line: where none does, trimesh gives the mesh a default material, a grey 2×2
    image, not an error."""
    folder = os.path.dirname(path)
    for name in names:
        mtl = os.path.join(folder, name)
        if os.path.isfile(mtl):
            with open(mtl, errors="replace") as f:  # (keys are case-insensitive, as trimesh reads them)
                if any(line.split()[:1] == ["map_kd"] for line in map(str.lower, f)):
                    return True
    return False


def load_textured_mesh(path) -> TexturedMesh:
    """Read a textured mesh (OBJ + MTL + image, or GLB/GLTF) through trimesh: vertices, faces, the
    per-vertex uvs trimesh makes (it splits vertices along uv seams, so ``uv_faces`` = ``faces``) and
    the base-colour image as float albedo [Ht, Wt, 3|4] in [0, 1] (8-bit values / 255, not
    sRGB-decoded). Raises InputValueError naming the path when the file has no uvs or no image."""
    p, loaded, materials = _trimesh_load(path)
    if p.lower().endswith(".obj") and not _obj_has_texture_map(p, materials):  # (trimesh makes up a grey 2×2 one)
        raise InputValueError(f"mesh file {p!r} has no texture image: no map_Kd in a material file it names")
    visual = getattr(loaded, "visual", None)
    uv = getattr(visual, "uv", None)
    if uv is None or len(uv) != len(loaded.vertices):
        raise InputValueError(f"mesh file {p!r} has no per-vertex texture coordinates")
    material = getattr(visual, "material", None)
    image = getattr(material, "image", None)
    if image is None:
        image = getattr(material, "baseColorTexture", None)
    if image is None:
        raise InputValueError(f"mesh file {p!r} has no texture image (map_Kd / baseColorTexture)")
    img = np.asarray(image.convert("RGBA" if "A" in image.getbands() else "RGB"), dtype=np.float64) / 255.0
    faces = np.asarray(loaded.faces)
    try:
        return TexturedMesh(np.asarray(loaded.vertices, dtype=np.float64), faces, uvs=np.asarray(uv), uv_faces=faces,
                            texture=img)
    except (ShapeError, InputValueError) as e:
        raise InputValueError(f"mesh file {p!r}: {e}") from None
