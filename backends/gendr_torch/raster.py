"""The PyTorch rasterizer: faces -> (pixel, face) pairs -> per-pixel aggregates (DESIGN.md §5).

Never materialises B·H·W·F. Per face we build a screen-space bounding box grown by the culling
distance of the distribution (coverage < eps beyond it) and enumerate the rows of each box. Rows
are evaluated as [rows, width] blocks (narrow ones transposed, see Block) of at most ``max_pairs``
pairs (memory O(pixels + faces + max_pairs)), per-face and per-row data broadcasting along the
row. Alpha is one autograd Function (:class:`SoftAlpha`): its backward recomputes each block and
applies the analytic derivative of the distance, with the coverage/generator derivative from
local autograd on the spec formulas, so nothing per pair is stored. Max-type aggregates and the
RGB blends work on bands of image rows (every pair of a pixel in one block); the blends are plain
autograd per band, checkpointed when there are several bands. Gradients are exact w.r.t.
everything upstream (vertices, camera, τ, colours).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.checkpoint import checkpoint

from gendr.cameras import VEC3
from gendr.errors import ShapeError
from gendr.renderer import (FAR_CORNER, LAMBERT_KINK_ULPS, ZERO_AREA_ULPS, check_screen_reach,
                            host_array, softmax_min_coverage)
from gendr.tconorms import MAX, MEAN

from .fused import FusedChains
from .ops import first_order_only, torch_ops as ops


# ---------------------------------------------------------------------------------------------
# camera parameters -> tensors
# ---------------------------------------------------------------------------------------------
def camera_tensors(camera, dtype, device):
    """Convert and check (:meth:`gendr.cameras.Camera.check_values`) the camera's array parameters;
    returns (P, batch) with P's arrays shaped [Bc, 1]."""
    P, batch, values = {}, 1, {}
    for name, (value, kind) in camera.array_params().items():
        if isinstance(value, np.ndarray):  # torch.as_tensor refuses negative strides and '>f8'
            value = np.ascontiguousarray(host_array(value, f"camera parameter {name}"))
        t = value.to(device=device, dtype=dtype) if isinstance(value, torch.Tensor) else torch.as_tensor(value, dtype=dtype, device=device)
        if kind == VEC3:
            if t.shape == (3,):
                t = t[None]
            if t.ndim != 2 or t.shape[1] != 3:
                raise ShapeError(f"camera parameter {name} must have shape [3] or [B, 3], got {list(t.shape)}")
        else:
            if t.ndim == 0:
                t = t[None]
            if t.ndim != 1:
                raise ShapeError(f"camera parameter {name} must be a scalar or have shape [B], got {list(t.shape)}")
        n = t.shape[0]
        if n != 1:
            if batch not in (1, n):
                raise ShapeError(f"camera parameter {name} has batch size {n}, others have {batch}")
            batch = n
        P[name] = tuple(t[:, k, None] for k in range(3)) if kind == VEC3 else t[:, None]
        values[name] = t
    # the spec's checks (non-finite, lens domains, eye on at, up along the view) on one host copy
    host = torch.cat([t.detach().reshape(-1) for t in values.values()]).to("cpu", torch.float64).numpy()
    sizes = [t.numel() for t in values.values()]
    camera.check_values({name: part.reshape(values[name].shape)
                         for name, part in zip(values, np.split(host, np.cumsum(sizes)[:-1]))})
    return P, batch


# ---------------------------------------------------------------------------------------------
# per-face preparation (O(B·F), ordinary autograd)
# ---------------------------------------------------------------------------------------------
@dataclass
class Faces:
    """Screen-space face data, flattened over (batch, face) = B·F rows."""

    B: int
    F: int
    K: int  # polygon corners (3, or 4 when some face is clipped by the near plane)
    X: torch.Tensor  # [B·F, K] polygon corners in screen units (autograd to vertices/camera)
    Y: torch.Tensor
    box: torch.Tensor  # [4, B·F] float: Xmin, Xmax, Ymin, Ymax of the polygon (screen units)
    valid: torch.Tensor  # [B·F] bool: some part in front of the near plane
    front: torch.Tensor  # [B·F] bool: counter-clockwise on screen
    shade: torch.Tensor | None  # [21 (+6 uv) (+9 normals), B·F]: barycentric affine coeffs (9), view
    #                              depths (3), colours (9); with a texture the corners' u (3), v (3);
    #                              for the G-buffer the corners' unit normals (3 × xyz)
    near: float
    far: float
    tex: torch.Tensor | None = None  # [Bt, Ht, Wt, C] texture (Bt = 1 or B)
    normal_row: int = 21  # first row of the normals in shade


UV_ROW = 21  # first row of the corners' texture coordinates in Faces.shade


def _screen(camera, P, H, W, xv, yv, zv):
    """View-space polygon corners ``[B, F, K]`` -> screen units. Lens parameters come as [Bc, 1]
    (the per-vertex layout): one more axis so a batch of them (e.g. fov_y [B]) meets the corners'."""
    sx, sy, ox, oy = (v[..., None] if isinstance(v, torch.Tensor) else v for v in camera.ndc_affine(ops, P, H, W))
    if camera.orthographic:
        nx, ny = sx * xv + ox, sy * yv + oy
    else:
        nx, ny = sx * xv / -zv + ox, sy * yv / -zv + oy
    return nx * (W / H), ny


def _expand_b(t, B):
    return t.expand(B, *t.shape[1:]) if t.shape[0] != B else t


def prepare_faces(settings, camera, verts, faces, colors, per_face, texture=None, normals=False) -> Faces:
    """``texture``: (texture, uvs, uv_faces) tensors or None; ``normals``: append the corners' unit
    normals to the shading data (G-buffer; also computes it without a blend)."""
    H, W = settings.image_size
    dtype, device = verts.dtype, verts.device
    P, Bc = camera_tensors(camera, dtype, device)
    if verts.ndim == 2:
        verts = verts[None]
    Bv = verts.shape[0]
    if Bv != 1 and Bc != 1 and Bv != Bc:
        raise ShapeError(f"vertex batch size {Bv} and camera batch size {Bc} do not match")
    B, F = max(Bv, Bc), faces.shape[0]
    x, y, z = verts.unbind(-1)
    xv, yv, zv = camera.view_coords(ops, P, x, y, z)  # [B, V]
    xv, yv, zv = (_expand_b(t, B) for t in (xv, yv, zv))
    tri = torch.stack([xv, yv, zv], -1)[:, faces]  # [B, F, 3 corners, 3 xyz]

    # --- near-plane clipping (Sutherland–Hodgman against z = -near; at most 4 corners) ---
    near = camera.near
    inside = tri[..., 2] <= -near
    if bool(inside.all()):
        poly, valid, K = tri, torch.ones(B, F, dtype=torch.bool, device=device), 3
    else:
        nxt, in_n = tri.roll(-1, 2), inside.roll(-1, 2)
        dz = nxt[..., 2] - tri[..., 2]
        cross = inside ^ in_n
        t = (-near - tri[..., 2]) / torch.where(cross, dz, torch.ones_like(dz))
        inter = tri + torch.where(cross, t, torch.zeros_like(t))[..., None] * (nxt - tri)
        # on the plane exactly: interpolated, z is off by ~ulp(|z|), which a tiny near plane (1e-7
        # in float32) cannot absorb: the corner would project through z ~ 0 (or from behind)
        inter = torch.cat([inter[..., :2], torch.where(cross, -near, inter[..., 2])[..., None]], -1)
        cand = torch.stack([tri, inter], 3).reshape(B, F, 6, 3)
        cvalid = torch.stack([inside, cross], 3).reshape(B, F, 6)
        count = cvalid.sum(-1)
        pos = cvalid.cumsum(-1) - 1
        slots = []
        for s in range(4):
            target = torch.clamp(count - 1, max=s)
            sel = cvalid & (pos == target[..., None])
            slots.append(sel.to(torch.int8).argmax(-1))
        idx = torch.stack(slots, -1)  # [B, F, 4]
        poly = torch.gather(cand, 2, idx[..., None].expand(B, F, 4, 3))
        valid, K = count > 0, 4
        # keep invalid faces' corners finite (they are never enumerated)
        poly = torch.where(valid[..., None, None], poly, torch.full_like(poly, -1.0))
    X, Y = _screen(camera, P, H, W, *poly.unbind(-1))  # [B, F, K]
    X, Y = X.reshape(B * F, K), Y.reshape(B * F, K)
    with torch.no_grad():
        box = torch.stack([X.amin(-1), X.amax(-1), Y.amin(-1), Y.amax(-1)], 0)
        if box.numel():
            check_screen_reach(float(box.abs().max()), str(X.dtype).replace("torch.", ""))
        area2 = (X * Y.roll(-1, 1) - X.roll(-1, 1) * Y).sum(-1)  # twice the signed area
    shade = tex = None
    if settings.blend is not None or normals:
        shade = _shading_data(settings, camera, P, H, W, verts, faces, tri, colors, per_face, B, texture, normals)
    if texture is not None:
        tex = texture[0] if texture[0].ndim == 4 else texture[0][None]
    return Faces(B, F, K, X, Y, box, valid.reshape(-1), area2 > 0, shade, camera.near, camera.far, tex,
                 UV_ROW + (6 if texture is not None else 0))


def anchor_swapped(X, Y):
    """[N, K] bool: edge k (corner k -> k + 1) is measured from corner k + 1 (its "anchor").

    A pixel's distance to edge k is computed as (p − P)·n, from the anchor P; its rounding error is
    ~ulp(|P|). Corners of faces clipped by a small near plane lie at ~x/near screen units (1e5 at
    near = 1e-5), which would cost float32 ~0.01 screen units: so in near-clipped renders an edge
    whose corner k is far (> FAR_CORNER) and farther than corner k + 1 is measured from corner
    k + 1 instead. Other edges (all of an unclipped render) keep corner k: the same arithmetic as
    without the rule. The Dr.Jit backend decides alike (raster._face_edges)."""
    if X.shape[1] != 4:
        return None
    m = torch.maximum(X.abs(), Y.abs()).detach()
    m_next = m.roll(-1, 1)
    return (m > FAR_CORNER) & (m > m_next)


def edge_table(X, Y):
    """Per-edge data of polygons with corners (X, Y) [N, K]: [8K, N], rows (edge k, field) with
    fields Px, Py, Ex, Ey, 1/|E|², nx, ny, c (inward unit normal n, offset c, see signed_distance).
    Field-major, so that a block's gather (index_select along dim 1) gives contiguous [1, R] rows.
    (Px, Py) is the edge's anchor and (Ex, Ey) points from it to the other end: corner k and
    P_{k+1} − P_k, or where :func:`anchor_swapped`, corner k + 1 and P_k − P_{k+1} (then the
    backward's corner parts of the edge are exchanged, see swap_corner_parts)."""
    N, K = X.shape
    Ex, Ey = X.roll(-1, 1) - X, Y.roll(-1, 1) - Y
    len2 = Ex * Ex + Ey * Ey
    nonzero = len2 > 0
    len2_safe = torch.where(nonzero, len2, torch.ones_like(len2))
    inv_len2 = torch.where(nonzero, 1.0 / len2_safe, torch.zeros_like(len2))
    orient = torch.sign((X * Y.roll(-1, 1) - X.roll(-1, 1) * Y).sum(-1)).detach()
    inv_len = torch.where(nonzero, torch.rsqrt(len2_safe), torch.zeros_like(len2)) * orient[:, None]
    nx, ny = -Ey * inv_len, Ex * inv_len  # inward unit normals (0 for zero-length edges)
    # offset: +big for zero-length edges (never the nearest line, never fails the inside test),
    # -1 for zero-area faces (nothing is inside them)
    big = torch.finfo(X.dtype).max / 4
    c = torch.where(nonzero, torch.zeros_like(len2), torch.full_like(len2, big))
    c = torch.where((orient == 0)[:, None], torch.full_like(c, -1.0), c)
    Px, Py = X, Y
    swap = anchor_swapped(X, Y)
    if swap is not None:  # (n is the line's: the same from either end)
        Px, Py = torch.where(swap, X.roll(-1, 1), X), torch.where(swap, Y.roll(-1, 1), Y)
        Ex, Ey = torch.where(swap, -Ex, Ex), torch.where(swap, -Ey, Ey)
    return torch.stack([t.t() for t in (Px, Py, Ex, Ey, inv_len2, nx, ny, c)], 1).reshape(8 * K, N)


def swap_corner_parts(gP, X, Y):
    """The backward's per (face, edge) parts [N, K, 4] (anchor x, y, other end x, y: see
    signed_distance's t) with each swapped edge's two corners exchanged back to (corner k, k + 1)."""
    swap = anchor_swapped(X, Y)
    if swap is None:
        return gP
    return torch.where(swap[..., None], gP[..., [2, 3, 0, 1]], gP)


def _zero_area(cross, e1, e2):
    """[..., 1] True where |e1 × e2| is rounding noise (ZERO_AREA_ULPS, gendr.renderer)."""
    tol = (ZERO_AREA_ULPS * torch.finfo(cross.dtype).eps) ** 2
    return (cross * cross).sum(-1, keepdim=True) <= tol * (e1 * e1).sum(-1, keepdim=True) * (e2 * e2).sum(-1, keepdim=True)


def _shading_data(settings, camera, P, H, W, verts, faces, tri, colors, per_face, B, texture=None, normals_out=False):
    """Barycentric coefficients (affine in screen X, Y), view depths and lit corner colours (with a
    texture: the lighting factor alone, then the corners' uvs); with ``normals_out`` the corners'
    unit normals (rows: see Faces.shade)."""
    sx, sy, ox, oy = camera.ndc_affine(ops, P, H, W)
    sx, sy, ox, oy = (torch.as_tensor(v, dtype=tri.dtype, device=tri.device) for v in (sx, sy, ox, oy))
    sx, sy, ox, oy = (v.reshape(-1, 1, 1) for v in (sx, sy, ox, oy))  # [Bc|1, 1, 1]
    v = tri  # [B, F, 3, 3]
    vj, vk = v.roll(-1, 2), v.roll(-2, 2)  # corners j = i+1, k = i+2
    ar = H / W  # x_ndc = X * ar
    if camera.orthographic:
        # u_i = (vj - o) x (vk - o) in the view xy-plane, o = ((x_ndc - ox)/sx, (y_ndc - oy)/sy)
        cz = vj[..., 0] * vk[..., 1] - vj[..., 1] * vk[..., 0]
        Dx, Dy = vj[..., 0] - vk[..., 0], vj[..., 1] - vk[..., 1]
        a = Dy * ar / sx
        b = -Dx / sy
        c0 = cz - Dy * ox / sx + Dx * oy / sy
    else:
        # u_i = r · (vj × vk), r = ((x_ndc - ox)/sx, (y_ndc - oy)/sy, -1)
        C = torch.linalg.cross(vj, vk, dim=-1)
        a = C[..., 0] * ar / sx
        b = C[..., 1] / sy
        c0 = -C[..., 0] * ox / sx - C[..., 1] * oy / sy - C[..., 2]
    # a face collapsed to a point or a line has no plane: its barycentrics would be rounding noise
    # (u_i / Σu with Σu ~ 1e-17), so give it constant barycentrics 1/3
    e1, e2 = v[:, :, 1] - v[:, :, 0], v[:, :, 2] - v[:, :, 0]
    with torch.no_grad():
        n2 = (torch.linalg.cross(e1, e2, dim=-1) ** 2).sum(-1)
        degenerate = (n2 <= 1e-24 * (e1 * e1).sum(-1) * (e2 * e2).sum(-1))[..., None]
    a, b = torch.where(degenerate, 0.0, a), torch.where(degenerate, 0.0, b)
    c0 = torch.where(degenerate, 1.0 / 3.0, c0)
    depth = -v[..., 2]  # positive view depth per corner [B, F, 3]

    # --- colours: albedo per corner, Lambert-lit with vertex (smooth) or face (flat) normals ---
    if verts.shape[0] != B:
        verts = verts.expand(B, -1, -1)
    wtri = verts[:, faces]  # world corners [B, F, 3, 3]
    e1, e2 = wtri[:, :, 1] - wtri[:, :, 0], wtri[:, :, 2] - wtri[:, :, 0]
    fn = torch.linalg.cross(e1, e2, dim=-1)  # area-weighted
    fn = torch.where(_zero_area(fn.detach(), e1.detach(), e2.detach()), 0.0, fn)
    if colors is None:
        albedo = torch.ones_like(wtri)
        per_face = False
    else:
        albedo = colors if colors.ndim == 3 else colors[None]
        albedo = albedo.expand(B, -1, -1)
        albedo = albedo[:, :, None, :].expand(B, -1, 3, 3) if per_face else albedo[:, faces]
    if per_face:
        normals = fn[:, :, None, :].expand(B, -1, 3, 3)
    else:
        vn = torch.zeros_like(verts).index_add(1, faces.reshape(-1), fn[:, :, None, :].expand(B, -1, 3, 3).reshape(B, -1, 3))
        normals = vn[:, faces]
    normals = normals / torch.clamp(torch.linalg.vector_norm(normals, dim=-1, keepdim=True), min=1e-30)
    light = torch.as_tensor(settings.light_direction, dtype=verts.dtype, device=verts.device)
    light = light / torch.linalg.vector_norm(light)
    ndl = (normals * -light).sum(-1, keepdim=True)
    # n·(−l) within rounding of 0 is Lambert's kink itself (e.g. a mesh's vertices on a plane of
    # symmetry perpendicular to the light): its sign there is summation-order noise, so snap it to exactly
    # 0, where the clamp passes the gradient (torch.clamp semantics), as the Dr.Jit backend does
    ndl = torch.where(ndl.detach().abs() <= LAMBERT_KINK_ULPS * torch.finfo(ndl.dtype).eps, ndl - ndl.detach(), ndl)
    lambert = torch.clamp(ndl, min=0.0)
    color = albedo * (settings.ambient + settings.diffuse * lambert)  # [B, F, 3 corners, 3 rgb]
    parts = [a, b, c0, depth, color.reshape(B, -1, 9)]  # [B, F, 21]
    if texture is not None:
        uv, uv_faces = texture[1], texture[2]
        uv = (uv if uv.ndim == 3 else uv[None]).expand(B, -1, -1)[:, uv_faces]  # [B, F, 3 corners, 2]
        parts += [uv[..., 0], uv[..., 1]]
    if normals_out:
        parts.append(normals.reshape(B, -1, 9))
    shade = torch.cat(parts, -1)
    return shade.reshape(B * tri.shape[1], shade.shape[-1]).t()


# ---------------------------------------------------------------------------------------------
# pair enumeration
# ---------------------------------------------------------------------------------------------
def pixel_ranges(fc: Faces, H: int, W: int, radius: float):
    """Inclusive pixel row/column ranges of each face's grown box, clipped to the image ([B·F] int64).
    Empty ranges (or invalid faces) have i1 < i0."""
    X0, X1, Y0, Y1 = fc.box
    r = radius * (1 + 1e-6) + 1e-6  # inf (no culling radius): ±inf bounds clamp to the whole image
    # pixel j has X = (2j + 1 - W)/H ; pixel i has Y = 1 - (2i + 1)/H
    j0 = torch.ceil((X0 - r) * (H / 2) + (W - 1) / 2)
    j1 = torch.floor((X1 + r) * (H / 2) + (W - 1) / 2)
    i0 = torch.ceil((H * (1 - (Y1 + r)) - 1) / 2)
    i1 = torch.floor((H * (1 - (Y0 - r)) - 1) / 2)
    # int32 indices: index_select / index_add are ~3x faster with them than with int64 on CPU
    j0, i0 = (torch.clamp(t, 0, n).int() for t, n in ((j0, W), (i0, H)))
    j1, i1 = (torch.clamp(t, -1, n - 1).int() for t, n in ((j1, W), (i1, H)))
    i1 = torch.where(fc.valid, i1, i0 - 1)
    return i0, i1, j0, torch.maximum(j1, j0 - 1)


def face_rows(i0, i1):
    """(face, image row) of every row of every face box, face-major ([R] int64 each)."""
    h = (i1 - i0 + 1).clamp(min=0).long()
    face = torch.repeat_interleave(torch.arange(h.numel(), device=h.device), h)
    start = torch.repeat_interleave(h.cumsum(0) - h, h)
    return face, i0.long()[face] + torch.arange(face.numel(), device=h.device) - start


def _chunks(widths, max_pairs: int):
    """Cut rows sorted by width (ascending) into consecutive chunks of at most max_pairs padded
    pairs (rows × the chunk's largest width; one row at least): [(start, end)]."""
    w = widths.tolist()
    out, a, R = [], 0, len(w)
    while a < R:
        lo, hi = a + 1, R  # the largest end with (end - a) * w[end - 1] <= max_pairs
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if (mid - a) * w[mid - 1] <= max_pairs:
                lo = mid
            else:
                hi = mid - 1
        out.append((a, lo))
        a = lo
    return out


#: blocks narrower than this many columns are evaluated transposed (see Block)
TRANSPOSE_BELOW = 24


@dataclass
class Block:
    """Face rows evaluated together: row r covers columns j0 ... j0 + width − 1 (j0: its face box's
    first column) of image row row[r] of the face's image. Columns beyond the box are farther than
    the culling distance (exact zeros, like the box's own corners); those beyond the image land in
    the padding columns of a wider output (see Plan.Wc).

    Arrays are [R, width] with per-row data [R, 1], or, for blocks narrower than TRANSPOSE_BELOW
    (``transposed``), [width, R] with per-row data [1, R]: torch's CPU loops broadcast a per-row
    value along a short inner dimension several times slower than along a long one (a multiply of
    262k pairs: 124 µs at width 8 against 39 µs transposed; equal from width ~32 on)."""

    face: torch.Tensor  # [R] int64, index into B·F
    pix0: torch.Tensor  # per row (shaped as py), int32: output index of the row's first pixel
    xnum: torch.Tensor  # per row, H × screen X of the row's first pixel (an integer)
    py: torch.Tensor  # per row ([R, 1], or [1, R] transposed): screen Y of the row
    cnum: torch.Tensor  # per column ([1, width], or [width, 1]): H × screen X offsets (even integers)
    H: int
    transposed: bool = False

    @property
    def width(self):
        return self.cnum.numel()

    def px(self):
        """Screen X of the block's pixels, rounded exactly as (2j + 1 − W)/H."""
        return self.screen_x(self.xnum, self.cnum, self.H)

    @staticmethod
    def screen_x(xnum, cnum, H):
        return (xnum + cnum) / H

    def pix(self):
        """Output pixel indices of the block's pixels (int32)."""
        return self.pix0 + torch.arange(self.width, dtype=torch.int32, device=self.pix0.device).view(self.cnum.shape)

    def by_rows(self, a):
        """A block array flattened row by row, [R·width] (the order of :meth:`flat`)."""
        if not self.transposed or a.numel() == 0:
            return a.reshape(-1)
        return torch.stack(a.unbind(0), 1).view(-1)  # (~2x faster than a.t().reshape(-1) here)

    def pix_by_rows(self):
        """:meth:`pix` flattened row by row (computed directly, without a transposing copy)."""
        if not self.transposed:
            return self.pix().reshape(-1)
        return (self.pix0.view(-1, 1) + torch.arange(self.width, dtype=torch.int32, device=self.pix0.device)).view(-1)

    def flat(self):
        """Per-pair (face, pix, px, py), [R·width] each, row by row. Sums over pairs (index_add) run
        in this order, so that a pixel's sum adds its faces in the order of the rows, whatever the
        chunking (results do not depend on max_pairs)."""
        shape = (self.face.numel(), self.width)
        return (self.face[:, None].expand(shape).reshape(-1), self.pix_by_rows(),
                self.by_rows(self.px()), self.py.view(-1, 1).expand(shape).reshape(-1))


@dataclass
class Plan:
    """What a render enumerates: per-face pixel ranges (inclusive) and their rows."""

    settings: object
    fc: Faces
    i0: torch.Tensor
    i1: torch.Tensor
    j0: torch.Tensor
    j1: torch.Tensor
    fused: object = None  # fused.FusedChains (compile=True) or None: eager

    def __post_init__(self):
        self.face, self.row = face_rows(self.i0, self.i1)
        self.rwidth = (self.j1 - self.j0 + 1).long()[self.face]
        # outputs are computed W + padding columns wide, cropped to W at the end
        self.Wc = self.settings.image_size[1] + (int(self.rwidth.max()) if self.rwidth.numel() else 0)
        self._chunks = self._bands = None

    def block(self, sel, r0=0, nrows=None):
        """The Block of rows ``sel``; output pixels indexed in [B, nrows, Wc] from image row r0."""
        H, W = self.settings.image_size
        nrows = H if nrows is None else nrows
        face, row = self.face.index_select(0, sel), self.row.index_select(0, sel)  # (faster than [sel])
        width = int(self.rwidth.index_select(0, sel).max())
        col0 = self.j0.long().index_select(0, face)
        dtype, device = self.fc.X.dtype, face.device
        transposed = width < TRANSPOSE_BELOW
        per_row, per_col = ((1, -1), (-1, 1)) if transposed else ((-1, 1), (1, -1))
        pix0 = (((face // self.fc.F) * nrows + row - r0) * self.Wc + col0).int().view(per_row)
        xnum = (2 * col0 + 1 - W).to(dtype).view(per_row)
        py = (1 - (2 * row + 1).to(dtype) / H).view(per_row)
        cnum = torch.arange(0, 2 * width, 2, dtype=dtype, device=device).view(per_col)
        return Block(face, pix0, xnum, py, cnum, H, transposed)

    def chunks(self):
        """Blocks covering every row, in any order (for sums): rows of similar width together."""
        if self._chunks is None:
            order = torch.argsort(self.rwidth, stable=True)
            self._chunks = [self.block(order[a:b]) for a, b in _chunks(self.rwidth[order], self.settings.max_pairs)]
        return self._chunks

    def bands(self):
        """[(r0, r1, Block or None)]: bands of image rows covering [0, H), each Block holding all
        rows of its pixels (for per-pixel maxima and blends)."""
        if self._bands is None:
            H, max_pairs = self.settings.image_size[0], self.settings.max_pairs
            order = torch.argsort(self.row, stable=True)
            count = torch.bincount(self.row, minlength=H).tolist()
            wmax = torch.zeros(H, dtype=torch.int64, device=self.row.device).scatter_reduce_(0, self.row, self.rwidth, "amax").tolist()
            cuts, r0, a, n, w = [], 0, 0, 0, 0  # band [r0, r): rows a ... a + n − 1 (in order), widest w
            for r in range(H):
                if n and (n + count[r]) * max(w, wmax[r]) > max_pairs:
                    cuts.append((r0, r, a, n))
                    r0, a, n, w = r, a + n, 0, 0
                n, w = n + count[r], max(w, wmax[r])
            cuts.append((r0, H, a, n))
            self._bands = [(r0, r1, self.block(order[a:a + n], r0, r1 - r0) if n else None) for r0, r1, a, n in cuts]
        return self._bands


# ---------------------------------------------------------------------------------------------
# per-pair evaluation of one block
# ---------------------------------------------------------------------------------------------
def _below(a, b):
    """1.0 where a < b, else 0.0 (a, b not NaN), as a float tensor: a bool mask and torch.where
    are ~5x slower per element on CPU; selections are then torch.lerp with weights 0 or 1 (exact:
    lerp returns start at weight 0 and end at weight 1). b − a > 0 exactly when a < b (a float
    difference is 0 only for equal operands); an in-place comparison keeps the float dtype."""
    return (b - a).gt_(0.0)


def _at_least(a, b):
    """1.0 where a >= b, else 0.0 (see _below)."""
    return (a - b).ge_(0.0)


def signed_distance(g, K, px, py, track=False):
    """Signed distance (inside > 0, outside < 0) of a block's pixel centres to their face
    polygons, shaped as px (g: the block's faces' columns of edge_table, [8K, R]; px: screen X
    of the pixels, py: screen Y per row, [R, 1] or [1, R]: see Block).

    With ``track``, also returns what the analytic backward needs: the nearest edge k (as a float),
    the position t in [0, 1] of the nearest boundary point on it, and the unit vector (ux, uy) with
    ∂d/∂P_k = (1 − t)·u and ∂d/∂P_{k+1} = t·u.
    """
    d2 = emin = None
    for k in range(K):
        Px, Py, Ex, Ey, il, nx, ny, c = g[8 * k: 8 * k + 8].view(8, *py.shape).unbind(0)  # per row, as py
        # rounded as the textbook formulas (and Dr.Jit) do: no fused multiply-adds (addcmul is
        # one), since ties between edges at kinks must break alike; the terms in py are per row
        dx, dy = px - Px, py - Py
        t = (dx * Ex).add_(dy * Ey).mul_(il).clamp_(0.0, 1.0)
        qx, qy = dx - t * Ex, dy - t * Ey
        dk = (qx * qx).add_(qy * qy)
        ek = (dx * nx).add_(dy * ny + c)  # c is 0, or decides alone
        if d2 is None:
            d2, emin = dk, ek
            if track:  # (out of place: torch.compile fuses it into one loop)
                kd = ke = torch.zeros_like(dk)
                td = te = t
                qxb, qyb, nxb, nyb = qx, qy, nx, ny
        else:
            if track:  # the first edge attaining the minimum, as torch.minimum's ties resolve
                bd, be = _below(dk, d2), _below(ek, emin)
                kk = dk.new_full((), k)
                kd, td, qxb, qyb = (torch.lerp(a, b, bd) for a, b in ((kd, kk), (td, t), (qxb, qx), (qyb, qy)))
                ke, te, nxb, nyb = (torch.lerp(a, b, be) for a, b in ((ke, kk), (te, t), (nxb, nx), (nyb, ny)))
            d2, emin = torch.minimum(d2, dk), torch.minimum(emin, ek)
    inside = _at_least(emin, 0.0)
    # inside a convex polygon the distance to the boundary is the distance to the nearest edge line
    r = d2.clamp_(min=torch.finfo(d2.dtype).tiny).sqrt_()
    d = torch.lerp(-r, emin, inside)
    if not track:
        return d
    # inside: d = n·(p − P_k) => ∂d/∂P_k = −(1 − t)n ; outside: d = −|p − q| => ∂d/∂P_k = (1 − t)(p − q)/|p − q|,
    # which is −n where q lies within the edge (0 < t < 1): taken as such, since for a pixel centre
    # on the edge (|p − q| ~ 1e-16, rounded outside) the quotient's direction is noise (gradients
    # were 2–20 % off). That edge's n is at hand where it is also the nearest line (ke = kd), as it is
    # near the edge; farther out the quotient is exact. Not for zero-area faces (n = 0)
    normal = (td > 0.0) & (td < 1.0) & (ke == kd) & ((nxb != 0.0) | (nyb != 0.0))
    uox, uoy = torch.where(normal, -nxb, qxb / r), torch.where(normal, -nyb, qyb / r)
    ux, uy = torch.lerp(uox, -nxb, inside), torch.lerp(uoy, -nyb, inside)
    return d, torch.lerp(kd, ke, inside), torch.lerp(td, te, inside), ux, uy


def culling_argument(dist, eps):
    """F⁻¹(eps): pairs with x below it have coverage < eps and are dropped (None: eps = 0)."""
    return dist.argument_threshold(eps) if eps > 0 else None


def pair_terms(dist, tcn, x):
    """(g, p, log(1 − p)) per pair, nothing culled or masked: the generator g that a streaming
    aggregation sums (for the mean p itself; then p and log1m are None)."""
    if tcn.kind == MEAN:
        return tcn.pair_term(ops, dist.cdf(ops, x)), None, None
    p, log1m = dist.cdf_and_log_sf(ops, x)
    return tcn.generator(ops, p, log1m), p, log1m


def _generator_parts(dist, tcn, x, x_min, x_cut):
    """(g, keep, p, log(1 − p)) per pair, nothing masked (p, log1m: None for the mean)."""
    g, p, log1m = pair_terms(dist, tcn, x)
    return g, keep_mask(ops.detach(x), x_min, x_cut), p, log1m


def generator_unsaturated(dist, tcn, x, x_min, x_cut=None):
    """Per-pair generator values g(p), culled pairs 0 (coverage < eps, tested as x < x_min =
    F⁻¹(eps), see culling_argument, like the Dr.Jit backend; and with ``x_cut``, x <= x_cut, the
    reference cut-off of RenderSettings.cutoff_argument), assuming no pair saturates, and a check:
    a 0-d tensor that is finite exactly when none did (p < 1 and g finite everywhere). No
    data-dependent branch (this is what ``compile=True`` fuses). The mean (``average``) sums p
    itself (TConorm.pair_term), culled alike, and never saturates: a face with p = 1 just adds 1."""
    g, keep, _, log1m = _generator_parts(dist, tcn, x, x_min, x_cut)
    return (g * keep if keep is not None else g), _saturation_check(g, log1m)


def _saturation_check(g, log1m):
    """Finite exactly when no pair saturated (0-d; the mean, log1m None, never saturates)."""
    return g.new_zeros(()) if log1m is None else ops.detach(log1m).sum() + ops.detach(g).sum()


def _generator_terms(dist, tcn, x, eps, x_cut=None):
    """Per-pair generator values (see generator_unsaturated) and the mask of saturated pairs
    (p = 1, or g overflowed), which set their pixel's alpha to 1 (None: none)."""
    g, keep, p, log1m = _generator_parts(dist, tcn, x, culling_argument(dist, eps), x_cut)
    if bool(torch.isfinite(_saturation_check(g, log1m))):  # the usual case: nothing saturated
        return (g * keep if keep is not None else g), None
    sat = ~torch.isfinite(log1m)
    g = tcn.generator(ops, torch.where(sat, 0.5, p), torch.where(sat, math.log(0.5), log1m))
    over = ~torch.isfinite(g)
    if bool(over.any()):
        sat = sat | over
        g = tcn.generator(ops, torch.where(sat, 0.5, p), torch.where(sat, math.log(0.5), log1m))
    if keep is not None:
        keep = keep > 0.0
        sat = sat & keep
        return torch.where(keep & ~sat, g, 0.0), sat
    return torch.where(sat, 0.0, g), sat


def edge_sums(gd, k, t, ux, uy, K, row_shape):
    """∂L/∂d per pair (a Block's array) -> per edge e and row the sums over the row's pairs whose
    nearest edge is e of the corner parts (corner e: x, y; corner e + 1: x, y), [K, 4, R]; with
    ∂d/∂P_e = (1 − t)·u and ∂d/∂P_{e+1} = t·u (see signed_distance). ``row_shape``: the shape of
    the block's per-row data ([R, 1], or [1, R] transposed)."""
    gb = gd * t
    ga = gd - gb
    parts = (ga * ux, ga * uy, gb * ux, gb * uy)
    out = []
    for e in range(K):
        m = (k - e).eq_(0.0)  # 1.0 where k == e (float, see _below)
        out.append(torch.stack([(v * m).sum_to_size(row_shape).view(-1) for v in parts]))
    return torch.stack(out)


def keep_mask(x, x_min, x_cut):
    """1.0 for the pairs that count, x >= x_min (coverage >= eps) and x > x_cut, else 0.0
    (arithmetic, see _below); None: all count."""
    keep = _at_least(x, x_min) if x_min is not None else None
    if x_cut is not None:
        above = _below(x_cut, x)
        keep = above if keep is None else keep * above
    return keep


def _from_sum(tcn, S, nsat, n_faces):
    """Alpha from the per-pixel sums: saturated pixels 1; the mean S/F has no singular point."""
    if tcn.kind == MEAN:
        return tcn.from_sum(ops, S, n_faces)
    # a subnormal S counts as 0, as in Dr.Jit (whose kernels flush it): dA/dS = S^(1/p − 1)/p of
    # yager, aczel_alsina, dombi with p ≳ 11 overflowed there into NaN vertex gradients (float32)
    pos = S >= torch.finfo(S.dtype).tiny
    A = torch.where(pos, tcn.from_generator_sum(ops, torch.where(pos, S, 1.0)), 0.0)
    return torch.where(nsat > 0, 1.0, A)


def _coverage_max(dist, x, eps, x_cut=None):
    p = dist.cdf(ops, x)
    p = torch.where(p >= eps, p, 0.0) if eps > 0 else p
    return p if x_cut is None else torch.where(x > x_cut, p, 0.0)


class SoftAlpha(torch.autograd.Function):
    """Alpha [B, H, W] from polygon corners: forward streams over blocks of pairs, backward
    recomputes each block and applies the analytic geometric derivative (nothing per pair is stored)."""

    @staticmethod
    def forward(ctx, X, Y, tau, plan, *tparams):
        """``tparams``: the learnable parameters (0-d tensors, in the order of
        :func:`learnable_tensors`: the T-conorm's, then the distribution's); ∂A/∂θ comes back for each."""
        s = plan.settings
        eps = s.eps
        dist, tcn = _bind(s, tparams, detach=True)
        x_cut = s.cutoff_argument(ops, tau.detach())
        H, W = s.image_size
        B, K, Wc = plan.fc.B, plan.fc.K, plan.Wc
        geom = edge_table(X, Y)
        S = X.new_zeros(B * H * Wc)
        if tcn.streams:  # archimedean T-conorms and the mean: a scatter-added sum per pixel
            nsat = torch.zeros(B * H * Wc, dtype=torch.int32, device=X.device)
            for blk in plan.chunks():
                # detached as in the backward: τ's requires_grad would be another compiled variant
                g = plan.fused.forward(geom, blk, tau.detach(), x_cut) if plan.fused else None
                if g is not None:
                    sat = None
                else:
                    d = signed_distance(geom.index_select(1, blk.face), K, blk.px(), blk.py)
                    g, sat = _generator_terms(dist, tcn, dist.argument(ops, d, tau), eps, x_cut)
                pix = blk.pix_by_rows()  # row by row (see Block.flat)
                S.index_add_(0, pix, blk.by_rows(g))
                if sat is not None:
                    nsat.index_add_(0, pix, blk.by_rows(sat).to(torch.int32))
            acc = torch.stack([S, nsat.to(S.dtype)], 0).reshape(2, B, H, Wc)[..., :W]
            A = _from_sum(tcn, acc[0], acc[1], plan.fc.F)
        else:
            for r0, r1, blk in plan.bands():
                if blk is None:
                    continue
                d = signed_distance(geom.index_select(1, blk.face), K, blk.px(), blk.py)
                p = _coverage_max(dist, dist.argument(ops, d, tau), eps, x_cut)
                pix = blk.pix().reshape(-1).long()
                Sb = X.new_zeros(B * (r1 - r0) * Wc).scatter_reduce_(0, pix, p.reshape(-1), "amax", include_self=True)
                S.view(B, H, Wc)[:, r0:r1] = Sb.view(B, r1 - r0, Wc)
            acc = S.reshape(1, B, H, Wc)[..., :W]
            A = acc[0]
            if tcn.kind != MAX:  # the hard logical "or": covered where some face has p >= 1/2
                A = (A >= 0.5).to(X.dtype)
        ctx.plan = plan
        ctx.save_for_backward(X, Y, tau, acc, A, *tparams)
        return A

    @staticmethod
    @first_order_only  # (its analytic backward has no graph)
    def backward(ctx, gA):
        X, Y, tau, acc, A, *tparams = ctx.saved_tensors
        plan = ctx.plan
        s = plan.settings
        eps = s.eps
        # the learnable parameters as fresh leaves: per-pair ∂g/∂θ and the direct ∂g⁻¹/∂p by autograd
        want_p = [ctx.needs_input_grad[4 + i] for i in range(len(tparams))]
        leaves = [t.detach().requires_grad_(w) for t, w in zip(tparams, want_p)]
        dist, tcn = _bind(s, leaves)
        p_in = [t for t, w in zip(leaves, want_p) if w]
        gp = [torch.zeros((), dtype=X.dtype, device=X.device) for _ in p_in]
        x_cut = s.cutoff_argument(ops, tau.detach())
        W = s.image_size[1]
        B, K, Wc = plan.fc.B, plan.fc.K, plan.Wc
        if not (tcn.streams or tcn.kind == MAX):  # the hard "or": piecewise constant, zero gradients
            return tuple(torch.zeros_like(t) if need else None
                         for t, need in zip((X, Y, tau, acc, *tparams), ctx.needs_input_grad))
        want_tau = ctx.needs_input_grad[2]
        geom = edge_table(X, Y)
        gP = X.new_zeros(X.numel() * 4)  # per (face, edge k): the parts for corner k (x, y), corner k + 1 (x, y)
        slots = torch.arange(4 * K, device=X.device)
        gtau = torch.zeros((), dtype=X.dtype, device=X.device)

        def local_grad(blk, d, w, formula):
            """∂L/∂d per pair (and accumulate ∂L/∂τ) by autograd on the spec formulas."""
            nonlocal gtau
            with torch.enable_grad():
                d_ = d.detach().requires_grad_(True)
                tau_ = tau.detach().requires_grad_(want_tau)
                out = formula(dist.argument(ops, d_, tau_))
                if not out.requires_grad:  # e.g. heaviside: coverage is piecewise constant
                    return None
                inputs = ((d_, tau_) if want_tau else (d_,)) + tuple(p_in)
                grads = torch.autograd.grad(out, inputs, w, allow_unused=True)
            if want_tau and grads[1] is not None:
                gtau = gtau + grads[1]
            for i, g in enumerate(grads[len(inputs) - len(p_in):]):
                if g is not None:
                    gp[i] = gp[i] + g
            return grads[0]

        def scatter(blk, sums):
            # sums over each row's pixels per nearest edge (edge_sums), then one index_add per
            # block into the (face, edge, part) slots: per pair it is slow where neighbouring
            # pairs hit the same slot; here neighbours are the 4K distinct slots of one row
            idx = (blk.face[:, None] * (4 * K) + slots).reshape(-1)
            gP.index_add_(0, idx, sums.permute(2, 0, 1).reshape(-1))

        if tcn.streams:
            with torch.enable_grad():  # dL/dS = dL/dA · dA/dS, per pixel (and the direct ∂g⁻¹/∂p)
                S = acc[0].detach().requires_grad_(True)
                gS, *gdirect = torch.autograd.grad(_from_sum(tcn, S, acc[1], plan.fc.F), (S, *p_in), gA,
                                                   allow_unused=True)
            for i, g in enumerate(gdirect):
                if g is not None:
                    gp[i] = gp[i] + g
            gS = torch.nn.functional.pad(gS, (0, Wc - W)).reshape(-1)
            tau_value = tau.detach()
            for blk in plan.chunks():
                pix = blk.pix()
                w = gS.index_select(0, pix.reshape(-1)).view(pix.shape)
                out = plan.fused.backward(geom, blk, tau_value, x_cut, w) if plan.fused else None
                if out is not None:
                    scatter(blk, out[0])
                    if want_tau:
                        gtau = gtau + out[1]
                    continue
                d, k, t, ux, uy = signed_distance(geom.index_select(1, blk.face), K, blk.px(), blk.py, track=True)
                gd = local_grad(blk, d, w, lambda x: _generator_terms(dist, tcn, x, eps, x_cut)[0])
                if gd is not None:
                    scatter(blk, edge_sums(gd, k, t, ux, uy, K, blk.py.shape))
        else:  # max: the gradient goes to one face attaining the maximum
            A, gA = (torch.nn.functional.pad(t, (0, Wc - W)) for t in (A, gA))
            for r0, r1, blk in plan.bands():
                if blk is None:
                    continue
                pix = blk.pix()
                shape, pix = pix.shape, pix.reshape(-1).long()
                Ap = A[:, r0:r1].reshape(-1)[pix].view(shape)
                w = gA[:, r0:r1].reshape(-1)[pix].view(shape)
                d, k, t, ux, uy = signed_distance(geom.index_select(1, blk.face), K, blk.px(), blk.py, track=True)
                with torch.no_grad():
                    pm = _coverage_max(dist, dist.argument(ops, d, tau), eps, x_cut)
                win = ((pm == Ap) & (pm > 0)).reshape(-1)
                face = blk.face.view(blk.py.shape).expand(shape).reshape(-1)
                win = _lowest_face(win, face, pix, B * (r1 - r0) * Wc)
                w = torch.where(win.view(shape), w, 0.0)
                gd = local_grad(blk, d, w, lambda x: _coverage_max(dist, x, eps, x_cut))
                if gd is not None:
                    scatter(blk, edge_sums(gd, k, t, ux, uy, K, blk.py.shape))
        gP = swap_corner_parts(gP.view(*X.shape, 4), X, Y)
        gX = gP[..., 0] + gP[..., 2].roll(1, 1)  # edge k − 1 ends at corner k
        gY = gP[..., 1] + gP[..., 3].roll(1, 1)
        it = iter(gp)
        gparams = [next(it).reshape(t.shape) if w else None for t, w in zip(tparams, want_p)]
        return (gX, gY, gtau.reshape(tau.shape), None, *gparams)


def _bind(settings, tparams, detach=False):
    """(distribution, T-conorm) of ``settings`` with their learnable parameters' arrays replaced by
    ``tparams`` (in the order of :func:`learnable_tensors`), optionally detached."""
    tparams = [t.detach() if detach else t for t in tparams]
    tcn, dist = settings.tconorm, settings.distribution
    n = len(tcn.learnable)
    return (dist.with_arrays(dict(zip(dist.learnable, tparams[n:]))),
            tcn.with_arrays(dict(zip(tcn.learnable, tparams[:n]))))


def learnable_tensors(settings, dtype, device):
    """The learnable parameters of the T-conorm, then of the distribution, as 0-d tensors of the
    render dtype/device (differentiable casts)."""
    out = []
    for v in (*settings.tconorm.learnable.values(), *settings.distribution.learnable.values()):
        t = v if isinstance(v, torch.Tensor) else torch.as_tensor(float(v))
        out.append(t.to(dtype=dtype, device=device).reshape(()))
    return out


def rgb_band(plan, X, Y, shade, tau, band, tex=None):
    """RGB of the image rows of plan.bands()[band] by plain autograd: [B, r1 − r0, W, 3]. (``tex``:
    fc.tex, an argument so that checkpointing sees it as an input.)"""
    s, fc = plan.settings, plan.fc
    W = s.image_size[1]
    r0, r1, blk = plan.bands()[band]
    npix = fc.B * (r1 - r0) * plan.Wc
    if blk is None:
        bg = torch.as_tensor(s.background, dtype=X.dtype, device=X.device)
        return bg.expand(fc.B, r1 - r0, W, 3)
    d = blk.by_rows(signed_distance(edge_table(X, Y).index_select(1, blk.face), fc.K, blk.px(), blk.py))
    inside = d >= 0  # outside, d <= −sqrt(tiny)
    x = s.distribution.argument(ops, d, tau)
    p = _coverage_max(s.distribution, x, s.eps, s.cutoff_argument(ops, tau.detach()))  # 0 where culled
    face, pix, px, py = blk.flat()
    rgb = _blend(s, fc, shade.index_select(1, face), pix, npix, px, py, p, inside, face)
    return rgb.reshape(fc.B, r1 - r0, plan.Wc, 3)[:, :, :W]


def _lowest_face(win, face, pix, npix):
    """``win`` kept only for the lowest face index among each pixel's winners: exact ties (of depth,
    or of coverage for max) go to the lowest face, as in the Dr.Jit backend and the naive reference."""
    big = torch.iinfo(torch.int64).max
    key = torch.where(win, face.long(), big)
    low = torch.full((npix,), big, dtype=torch.long, device=face.device).scatter_reduce(0, pix.long(), key, "amin")
    return win & (key == low[pix.long()])


def _bary_depth(sh, px, py, near):
    """Perspective-correct barycentrics (clamped to the triangle, a list of 3) and view depth of the
    pairs' faces (shading rows ``sh``) at screen points (px, py)."""
    u = [sh[i] * px + sh[3 + i] * py + sh[6 + i] for i in range(3)]
    s = u[0] + u[1] + u[2]
    s = torch.where(s.abs() > torch.finfo(px.dtype).tiny, s, torch.ones_like(s))
    b = [torch.clamp(ui / s, min=0.0) for ui in u]
    bs = b[0] + b[1] + b[2]
    b = [bi / bs for bi in b]
    # a near-clipped face extrapolates towards its corner behind the camera: clamp to the near plane
    depth = torch.clamp(b[0] * sh[9] + b[1] * sh[10] + b[2] * sh[11], min=near)
    return b, depth


def _blend(settings, fc, sh, pix, npix, px, py, p, inside, face):
    dtype, device = px.dtype, px.device
    pix = pix.long()  # scatter_reduce needs int64 indices
    b, depth = _bary_depth(sh, px, py, fc.near)
    col = torch.stack([b[0] * sh[12 + c] + b[1] * sh[15 + c] + b[2] * sh[18 + c] for c in range(3)], 1)
    bg = torch.as_tensor(settings.background, dtype=dtype, device=device)
    if fc.tex is not None:
        if settings.blend == "hard":  # sample only where a face wins (below)
            col = _TexturedColour(settings, fc, sh, b, face, col)
        else:
            col = col * _texel(settings, fc, sh, b, face)
    if settings.blend == "hard":  # purely geometric: the nearest face containing the pixel centre
        use = inside & fc.front[face] if settings.cull_backfaces else inside
        key = torch.where(use, depth.detach(), torch.full_like(depth, math.inf))
        dmin = torch.full((npix,), math.inf, dtype=dtype, device=device).scatter_reduce(0, pix, key, "amin")
        win = _lowest_face(use & (key == dmin[pix]), face, pix, npix)
        out = torch.zeros(npix, 3, dtype=dtype, device=device).index_add(0, pix[win], col[win])
        covered = torch.zeros(npix, dtype=torch.bool, device=device)
        covered[pix[win]] = True
        return torch.where(covered[:, None], out, bg)
    # softmax over depth (SoftRas): weights p·exp(z̃/γ), background exp(ε/γ)
    zt = (fc.far - depth) / (fc.far - fc.near)
    gamma, beps = settings.gamma, settings.background_eps
    # (p is 0 where culled; a tinier p counts as 0, as in Dr.Jit, where kernels may flush it)
    live = p >= softmax_min_coverage(str(dtype).replace("torch.", ""))
    if settings.cull_backfaces:
        live = live & fc.front[face]
    key = torch.where(live, zt.detach(), torch.full_like(zt, -math.inf))
    m = torch.full((npix,), beps, dtype=dtype, device=device).scatter_reduce(0, pix, key, "amax")
    # exponent <= 0 where live; 0 elsewhere so that exp cannot overflow into a 0·inf = NaN gradient
    w = torch.where(live, p * torch.exp(torch.where(live, zt - m[pix], 0.0) / gamma), 0.0)
    num = torch.zeros(npix, 3, dtype=dtype, device=device).index_add(0, pix, w[:, None] * col)
    wb = torch.exp((beps - m) / gamma)
    den = torch.zeros(npix, dtype=dtype, device=device).index_add(0, pix, w) + wb
    return (num + wb[:, None] * bg) / den[:, None]


class _TexturedColour:
    """The textured colours of a block's pairs, sampled only for the selected ones (``col[sel]``)."""

    def __init__(self, settings, fc, sh, b, face, lit):
        self.args, self.lit = (settings, fc, sh, b, face), lit

    def __getitem__(self, sel):
        settings, fc, sh, b, face = self.args
        return self.lit[sel] * _texel(settings, fc, sh[:, sel], [bi[sel] for bi in b], face[sel])


def _texel(settings, fc, sh, b, face):
    """The texture sampled at the pairs' interpolated uvs: [N, 3] (gendr.textures conventions)."""
    tex = fc.tex
    Bt, Ht, Wt, C = tex.shape
    u = b[0] * sh[UV_ROW] + b[1] * sh[UV_ROW + 1] + b[2] * sh[UV_ROW + 2]
    v = b[0] * sh[UV_ROW + 3] + b[1] * sh[UV_ROW + 4] + b[2] * sh[UV_ROW + 5]
    flat = tex[..., :3].reshape(-1, 3)
    base = (face // fc.F) * (Ht * Wt) if Bt > 1 else torch.zeros_like(face)
    repeat = settings.texture_wrap == "repeat"
    # one period first (gendr.textures.one_period): texel indices then lie in [−1, n], exactly
    u, v = (u - torch.floor(u.detach()), v - torch.floor(v.detach())) if repeat else (u.clamp(-1, 2), v.clamp(-1, 2))

    def wrap(i, n):  # integer-valued floats in [−1, n] -> int64 in [0, n)
        i = torch.where(i < 0, i + n, torch.where(i >= n, i - n, i)) if repeat else torch.clamp(i, 0, n - 1)
        return i.long()

    def at(r, c):
        return flat.index_select(0, base + r * Wt + c)

    if settings.texture_filter == "nearest":
        with torch.no_grad():
            r, c = wrap(torch.floor((1.0 - v) * Ht), Ht), wrap(torch.floor(u * Wt), Wt)
        return at(r, c)
    x, y = u * Wt - 0.5, (1.0 - v) * Ht - 0.5
    x0, y0 = torch.floor(x.detach()), torch.floor(y.detach())
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    with torch.no_grad():
        c0, c1, r0, r1 = wrap(x0, Wt), wrap(x0 + 1, Wt), wrap(y0, Ht), wrap(y0 + 1, Ht)
    top = torch.lerp(at(r0, c0), at(r0, c1), fx)
    bot = torch.lerp(at(r1, c0), at(r1, c1), fx)
    return torch.lerp(top, bot, fy)


def render(settings, camera, verts, faces, colors, per_face, texture=None, compile=False):
    """RGBA [B, H, W, 4]; ``compile``: alpha's per-pair chains fused by torch.compile (see fused)."""
    H, W = settings.image_size
    fc = prepare_faces(settings, camera, verts, faces, colors, per_face, texture)
    tau = settings.tau
    tau = tau.to(verts.dtype) if isinstance(tau, torch.Tensor) else torch.tensor(float(tau), dtype=verts.dtype, device=verts.device)
    radius = settings.culling_distance(settings.tau_value)
    with torch.no_grad():
        plan = Plan(settings, fc, *pixel_ranges(fc, H, W, radius))
    if compile:
        plan.fused = FusedChains(settings.distribution, settings.tconorm, settings.eps, fc.K, verts.device.type)
    alpha = SoftAlpha.apply(fc.X, fc.Y, tau, plan, *learnable_tensors(settings, verts.dtype, verts.device))
    if fc.shade is None:
        return torch.cat([alpha.new_zeros(*alpha.shape, 3), alpha[..., None]], -1)
    needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in (fc.X, fc.shade, tau)) or (
        torch.is_grad_enabled() and fc.tex is not None and fc.tex.requires_grad)
    nb = len(plan.bands())
    parts = []
    for band in range(nb):
        if needs_grad and nb > 1:
            parts.append(checkpoint(rgb_band, plan, fc.X, fc.Y, fc.shade, tau, band, fc.tex,
                                    use_reentrant=False, preserve_rng_state=False))
        else:
            parts.append(rgb_band(plan, fc.X, fc.Y, fc.shade, tau, band))
    rgb = torch.cat(parts, 1) if len(parts) > 1 else parts[0]
    return torch.cat([rgb, alpha[..., None]], -1)


# ---------------------------------------------------------------------------------------------
# G-buffer
# ---------------------------------------------------------------------------------------------
def rasterize(settings, camera, verts, faces):
    """(face_id [B, H, W] int64, bary [B, H, W, 3], depth [B, H, W], normal [B, H, W, 3]): the
    nearest face containing each pixel centre (the hard blend's z-buffer), see gendr.GBuffer."""
    H, W = settings.image_size
    fc = prepare_faces(settings, camera, verts, faces, None, False, normals=True)
    B, F, dtype, device = fc.B, fc.F, verts.dtype, verts.device
    with torch.no_grad():
        plan = Plan(settings, fc, *pixel_ranges(fc, H, W, 0.0))
    geom = edge_table(fc.X, fc.Y)
    parts = []
    for r0, r1, blk in plan.bands():
        npix = B * (r1 - r0) * plan.Wc
        fid = torch.full((npix,), -1, dtype=torch.long, device=device)
        vals = torch.zeros(npix, 8, dtype=dtype, device=device)  # bary (3), depth, normal (3), unused
        if blk is not None:
            d = blk.by_rows(signed_distance(geom.index_select(1, blk.face), fc.K, blk.px(), blk.py))
            face, pix, px, py = blk.flat()
            pix = pix.long()
            sh = fc.shade.index_select(1, face)
            b, depth = _bary_depth(sh, px, py, fc.near)
            use = (d >= 0).reshape(-1)
            if settings.cull_backfaces:
                use = use & fc.front[face]
            key = torch.where(use, depth.detach(), torch.full_like(depth, math.inf))
            dmin = torch.full((npix,), math.inf, dtype=dtype, device=device).scatter_reduce(0, pix, key, "amin")
            win = _lowest_face(use & (key == dmin[pix]), face, pix, npix)
            nr = fc.normal_row
            n = [b[0] * sh[nr + c] + b[1] * sh[nr + 3 + c] + b[2] * sh[nr + 6 + c] for c in range(3)]
            norm = torch.clamp(torch.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), min=1e-30)
            row = torch.stack(b + [depth] + [nc / norm for nc in n] + [torch.zeros_like(depth)], 1)
            vals = vals.index_add(0, pix[win], row[win])
            fid[pix[win]] = face[win] % F
        parts.append((fid.view(B, r1 - r0, plan.Wc)[:, :, :W], vals.view(B, r1 - r0, plan.Wc, 8)[:, :, :W]))
    fid = torch.cat([p[0] for p in parts], 1)
    vals = torch.cat([p[1] for p in parts], 1)
    return fid, vals[..., 0:3], vals[..., 3], vals[..., 4:7]
