"""The Dr.Jit rasterizer: one fused per-pixel loop over the faces of the pixel's screen tile.

Pipeline of one render (DESIGN.md §5; semantics identical to ``gendr_torch.raster``):

1. vertices -> camera frame -> per-face polygons clipped at the near plane (3 corners, or 4 when
   some face crosses it) -> screen units; Lambert-lit corner colours and barycentric coefficients
   for the RGB blends. Ordinary Dr.Jit AD arrays, O(B·F) work.
2. binning (device, detached; :class:`Bins`): per square tile a bit mask over the faces whose
   screen box grown by the culling radius meets the tile (and whose signed distance at the tile
   centre is within the radius plus the tile's half diagonal). Sizes depend only on (B, H, W, F):
   nothing is read back, so a render can be frozen (``gendr_drjit.frozen``).
3. a symbolic ``dr.while_loop`` per pixel (lanes in tile-major order, :class:`Pixels`) over its
   tile's faces in ascending order: signed distance to the polygon, coverage p = F(x), generator
   g(p), summed (archimedean T-conorms; the mean ``average`` sums p itself). Gradients: :class:`AlphaSum`, a custom op whose backward
   is a second explicit loop (analytic distance derivative, local forward-mode derivative of the
   spec formulas, scatter-adds into the face corners); nothing is stored per (pixel, face) pair.
4. ``max`` / hard ``or`` / the hard z-buffer / the softmax maximum are not sums: a first loop
   without AD finds the arg-max (or the maximum) per pixel; the differentiable value is then
   re-evaluated for that one face (max, hard), or the maximum enters a second, summing loop as a
   constant (softmax: weights p·exp((z̃ − m)/γ)). These keep Dr.Jit's generic reverse-mode "sum
   loop" (``max_iterations=-1``) on a linearised signed distance.

τ, the camera parameters and the culling constants are opaque (not literals) so changing them does
not recompile a kernel; the loop kernels depend only on the instance, image size, dtype and K.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import drjit as dr

from gendr.renderer import (FAR_CORNER, LAMBERT_KINK_ULPS, ZERO_AREA_ULPS, check_screen_reach,
                            softmax_min_coverage)
from gendr.tconorms import HARD_OR, MAX, MEAN

#: tile edges tried in order (see tile_size); TILE != 0 forces one
TILES = (4, 8, 16, 32)
TILE = 0
#: pixel rows per lane of the archimedean alpha loops (Pixels): a lane shares one face's reads and
#: edge set-up between the pixels of its strip (at most the tile edge: 4 lanes per 4×4 tile)
STRIP = 4
#: a culling radius of WIDE_RADIUS screen units or more (half the image height: heavy tails, wide τ)
#: puts nearly every face in every tile's list, so tiles of at least WIDE_TILE pixels and strips of
#: WIDE_STRIP rows share each face's reads and set-up among more pixels (cauchy on the paper's
#: shape step at τ = 0.01: fwd+bwd −15 %; at a radius of 0.55 the larger tiles lost 5 %)
WIDE_RADIUS, WIDE_TILE, WIDE_STRIP = 1.0, 16, 8
#: memory budget of the per-tile face bit masks (tiles · ceil(F/32) · 4 bytes)
MASK_BYTES = 64 << 20
#: extra margin of the binning boxes, in pixels (float32 rounding of the box; culled pairs add 0)
BIN_MARGIN = 1e-3
GRAD_MODE = dr.ReduceMode.Auto
#: the hand-written backward of the archimedean alpha sum (AlphaSum); False: Dr.Jit's generic
#: reverse-mode sum loop
CUSTOM_BACKWARD = True
#: how AlphaSum's backward scatter-adds into the face corners (Expand: per-thread copies, no atomics)
BWD_MODE = dr.ReduceMode.Expand
#: AlphaSum's backward walks each face's pixels (face-major, no scatter per pair) when the culling
#: radius is at most FACE_MAJOR_RADIUS_PX pixels; wider radii (heavy tails, large images) keep the
#: pixel-major loop, whose dense tile lists beat the face loop's per-pair gathers of δ_S (measured:
#: paper shape step τ = 0.01, 4.4 px: backward −50 %; 13 px: −20 %; 256² at 12 px: even; 1024² at
#: 47 px and cauchy at 32 px: +25–40 %)
FACE_MAJOR_RADIUS_PX = 16.0
#: the face-major loop splits a face's box rows into chunks until it has at least this many lanes
FACE_LANES = 16384
#: the face-major backward reads δ_S for this many adjacent pixels of a row at once (one packet gather)
FACE_GROUP = 2
_NONE = 0xFFFFFFFF


class Types:
    """The Dr.Jit types of one (device, dtype): Float, UInt32, Int32, Bool, Tensor."""

    def __init__(self, module, double):
        self.module = module
        self.device = "cuda" if module.__name__.startswith("drjit.cuda") else "llvm"
        self.Float = module.Float64 if double else module.Float
        self.Tensor = module.TensorXf64 if double else module.TensorXf
        self.ArrayX = module.ArrayXf64 if double else module.ArrayXf
        self.UInt32, self.Int32, self.Bool = module.UInt32, module.Int32, module.Bool
        self.double = double
        self.tiny = float(np.finfo(np.float64 if double else np.float32).tiny)
        self.big = float(np.finfo(np.float64 if double else np.float32).max) / 4


def _expand_params(P, bidx, Bc, T):
    """Camera arrays (width Bc or 1) gathered to lanes whose batch index is ``bidx``. Width-1 arrays
    that carry gradients are repeated to the lanes' width by one :class:`_Broadcast` (the camera
    math then runs per lane): Dr.Jit's implicit broadcast would sum the gradient of every derived
    width-1 value (basis, eye: twelve) in a kernel and a reduction of its own."""
    out = {}
    for k, v in P.items():
        if isinstance(v, tuple):
            out[k] = tuple(c if Bc == 1 else dr.gather(T.Float, c, bidx) for c in v)
        else:
            out[k] = v if Bc == 1 else dr.gather(T.Float, v, bidx)
    if Bc == 1:
        leaves = [(k, i, c) for k, v in out.items() for i, c in enumerate(v if isinstance(v, tuple) else (v,))
                  if dr.grad_enabled(c)]
        if leaves:
            wide = dr.custom(_Broadcast, tuple(c for _, _, c in leaves), dr.width(bidx))
            for (k, i, _), w in zip(leaves, wide):
                out[k] = tuple(w if j == i else c for j, c in enumerate(out[k])) if isinstance(out[k], tuple) else w
    return out


class _Broadcast(dr.CustomOp):
    """Width-1 arrays repeated to width ``n``; the adjoint sums all their gradients in one reduction."""

    def eval(self, values, n):
        self.n = n
        return tuple(v + dr.zeros(type(v), n) for v in values)

    def forward(self):
        raise NotImplementedError("forward-mode AD of the Dr.Jit camera broadcast is not implemented")

    def backward(self):
        n, grads = self.n, self.grad_out()
        Float = type(grads[0])
        grads = [g if dr.width(g) == n else dr.zeros(Float, n) + g for g in grads]
        dr.schedule(*grads)
        lane = dr.arange(dr.uint32_array_t(Float), n * len(grads))
        row, col = lane // n, lane % n
        stacked = dr.zeros(Float, dr.width(lane))
        for j, g in enumerate(grads):
            stacked = dr.select(row == j, dr.gather(Float, g, col), stacked)
        sums = dr.block_sum(stacked, n)
        self.set_grad_in("values", tuple(dr.gather(Float, sums, j) for j in range(len(grads))))

    def name(self):
        return "gendr camera broadcast"


# ---------------------------------------------------------------------------------------------
# per-face preparation
# ---------------------------------------------------------------------------------------------
class Faces:
    """Per-face data of one render (attributes set by :func:`prepare_faces`): B, F, K; corners X, Y
    (lists of K AD arrays over B·F faces), their detached copies Xd, Yd and (when they carry
    gradients, ``ad``) the flat (face, corner) arrays Xall, Yall; valid, orient (±1, 0 for zero
    area), front (counter-clockwise), near, far, shade (21 arrays or None), cull_lo; packed
    (:func:`_pack_corners`: Xd, Yd, orient interleaved per face, what the loops read)."""


def prepare_faces(settings, camera, ops, T, P, Bc, verts, Bv, V, faces_np, colors, per_face, clip=None, faces_u=None,
                  tex=None, normals=False):
    """``tex``: (flat texture, Bt, Ht, Wt, C, flat uvs, Bu, T, flat UInt32 uv_faces) or None;
    ``normals``: append the corners' unit normals to ``shade`` (G-buffer; computed without a blend too).
    ``clip``: None decides from the data whether near-plane clipping (K = 4) is needed (a host
    read); True / False force it (frozen replays, where nothing may be read back: ``fc.all_inside``
    then holds the device-side answer and ``fc.reach`` the farthest corner, for the caller to check
    afterwards, as ``check_screen_reach`` does here when ``clip`` is None). ``faces_u``: the faces
    as a flat UInt32 array (default: converted from ``faces_np``)."""
    H, W = settings.image_size
    B, F = max(Bv, Bc), faces_np.shape[0]
    Float, UInt32 = T.Float, T.UInt32
    # --- vertices in the camera frame, lanes (b, v) ---
    n = B * V
    lane = dr.arange(UInt32, n)
    b_v = lane // V
    src = (b_v if Bv > 1 else dr.zeros(UInt32, n)) * V + lane % V
    x, y, z = (dr.gather(Float, verts, src * 3 + c) for c in range(3))
    Pv = _expand_params(P, b_v, Bc, T)
    xv, yv, zv = camera.view_coords(ops, Pv, x, y, z)
    # --- face corners, lanes (b, f) ---
    m = B * F
    fl = dr.arange(UInt32, m)
    b_f, f_f = fl // F, fl % F
    if faces_u is None:
        faces_u = UInt32(faces_np.reshape(-1).astype(np.uint32))
    vid = [dr.gather(UInt32, faces_u, f_f * 3 + c) for c in range(3)]
    dr.schedule(xv, yv, zv)  # gathered below: evaluated together, in one kernel (not one each)
    corner = [tuple(dr.gather(Float, a, b_f * V + vid[c]) for a in (xv, yv, zv)) for c in range(3)]
    near = camera.near
    inside = [c[2] <= -near for c in corner]
    in_front = inside[0] & inside[1] & inside[2]
    # a UInt32 max, not dr.all: Dr.Jit 1.5 replays a frozen Bool reduction from every 4th lane only,
    # so a face crossing the near plane at another index went unnoticed (unclipped image)
    all_in = (dr.max(dr.select(in_front, UInt32(0), UInt32(1)), axis=None) == 0) if m else dr.full(T.Bool, True, 1)
    all_inside = (bool(all_in) if m else True) if clip is None else not clip
    if all_inside:
        poly, valid, K = corner, dr.full(T.Bool, True, m), 3
    else:
        cands, flags = [], []
        for c in range(3):
            a, bq = corner[c], corner[(c + 1) % 3]
            cross = inside[c] ^ inside[(c + 1) % 3]
            dz = bq[2] - a[2]
            t = dr.select(cross, (-near - a[2]) / dr.select(cross, dz, 1.0), 0.0)
            # z on the plane exactly (interpolated it is off by ~ulp(|z|): a tiny near plane would
            # project the corner through z ~ 0)
            cands += [a, (a[0] + t * (bq[0] - a[0]), a[1] + t * (bq[1] - a[1]), dr.select(cross, -near, a[2]))]
            flags += [inside[c], cross]
        Int32 = T.Int32
        pos, cnt = [], dr.zeros(Int32, m)
        for fl_ in flags:
            pos.append(cnt)
            cnt = cnt + dr.select(fl_, 1, 0)
        poly = []
        for s in range(4):
            target = dr.minimum(cnt - 1, s)
            acc = [dr.zeros(Float, m) for _ in range(3)]
            for cd, fl_, p in zip(cands, flags, pos):
                sel = fl_ & (p == target)
                acc = [dr.select(sel, cd[i], acc[i]) for i in range(3)]
            poly.append(tuple(acc))
        valid, K = cnt > 0, 4
        poly = [tuple(dr.select(valid, c[i], -1.0) for i in range(3)) for c in poly]
    Pf = _expand_params(P, b_f, Bc, T)
    sx, sy, ox, oy = camera.ndc_affine(ops, Pf, H, W)
    X, Y = [], []
    for (px_, py_, pz_) in poly:
        if camera.orthographic:
            nx, ny = sx * px_ + ox, sy * py_ + oy
        else:
            nx, ny = sx * px_ / -pz_ + ox, sy * py_ / -pz_ + oy
        X.append(nx * (W / H))
        Y.append(ny)
    reach = dr.zeros(Float, 1)  # the farthest corner from the image centre (screen units, max norm)
    if m:
        far = dr.maximum(dr.abs(dr.detach(X[0])), dr.abs(dr.detach(Y[0])))
        for k in range(1, K):
            far = dr.maximum(far, dr.maximum(dr.abs(dr.detach(X[k])), dr.abs(dr.detach(Y[k]))))
        reach = dr.max(far, axis=None)
        if clip is None:  # (a frozen render checks fc.reach after its replay: nothing is read back here)
            check_screen_reach(float(reach[0]), "float64" if T.double else "float32")
    fc = Faces()
    fc.B, fc.F, fc.K, fc.X, fc.Y, fc.valid = B, F, K, X, Y, valid
    fc.all_inside, fc.reach = all_in, reach
    fc.Xd, fc.Yd = [dr.detach(x) for x in X], [dr.detach(y) for y in Y]
    fc.ad = any(dr.grad_enabled(a) for a in X + Y)
    area2 = sum(dr.detach(X[k]) * dr.detach(Y[(k + 1) % K]) - dr.detach(X[(k + 1) % K]) * dr.detach(Y[k]) for k in range(K))
    fc.orient = Float(dr.select(area2 > 0, 1.0, dr.select(area2 < 0, -1.0, 0.0)))
    fc.front = area2 > 0
    # the loops and the binning gather these: evaluated together, in one kernel (not one each)
    dr.schedule(*X, *Y, fc.orient, fc.front)
    fc.packed = _pack_corners(T, fc.Xd, fc.Yd, fc.orient)
    dr.schedule(fc.packed)
    if fc.ad:  # corners flattened (face, corner) for the linearised distance (see signed_distance)
        fc.Xall, fc.Yall = _row_major(T, X, K), _row_major(T, Y, K)
    fc.near, fc.far = camera.near, camera.far
    fc.shade = None
    fc.tex = None if tex is None else tex[:5]
    if settings.blend is not None or normals:
        fc.shade = _shading_data(settings, camera, ops, T, Pf, H, W, verts, Bv, V, B, F, b_f, f_f, faces_u,
                                 vid, corner, colors, per_face, tex, normals)
    fc.normal_row = UV_ROW + (6 if tex is not None else 0)
    return fc


UV_ROW = 21  # first of the corners' u (3), v (3) in Faces.shade when textured


def _clamp_min(x, lo):
    """max(x, lo) whose gradient passes at x == lo (torch.clamp semantics, for parity at ties)."""
    return dr.select(x < lo, lo, x)


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _vertex_sums(T, values, slots, n):
    """Σ of each per-face array of ``values`` into n vertex slots (one index array per corner), the
    same bits with any thread count and summation order: each term becomes a 64-bit integer in
    units of 2^−k (k from the largest |term| and the most terms per slot, so that no sum
    overflows), the integers add exactly, and each sum is rounded to Float once (terms round to the
    grid: absolute error <= 2^−(k+1) each, ~2^−62 of the largest possible sum). A float
    scatter-add's order varies across threads, which moved smooth-shaded colours by an ulp from run
    to run. Derivatives follow the float scatter-add (dr.replace_grad)."""
    Float, Int64, F64 = T.Float, T.module.Int64, T.module.Float64
    count = dr.zeros(T.UInt32, n)
    for idx in slots:
        dr.scatter_reduce(dr.ReduceOp.Add, count, T.UInt32(1), idx)
    most = F64(dr.max(count))
    out = []
    for value in values:
        vd = F64(dr.detach(value))
        bound = dr.maximum(dr.max(dr.abs(vd)) * most, 1e-300)
        scale = dr.exp2(61.0 - dr.ceil(dr.log2(bound)))  # |Σ| <= bound <= 2^61 / scale
        q = Int64(dr.round(vd * scale))
        total = dr.zeros(Int64, n)
        for idx in slots:
            dr.scatter_reduce(dr.ReduceOp.Add, total, q, idx)
        exact = Float(F64(total) / scale)
        if dr.grad_enabled(value):
            acc = dr.zeros(Float, n)
            for idx in slots:
                dr.scatter_reduce(dr.ReduceOp.Add, acc, value, idx)
            exact = dr.replace_grad(exact, acc)
        out.append(exact)
    return out


def _shading_data(settings, camera, ops, T, Pf, H, W, verts, Bv, V, B, F, b_f, f_f, faces_u, vid, v, colors, per_face,
                  tex=None, normals_out=False):
    """21 per-face arrays: barycentric affine coefficients a(3), b(3), c0(3), view depths (3), lit
    corner colours (3 corners × rgb) — the same quantities as gendr_torch.raster._shading_data; with
    ``tex`` (colours then white: the lighting factor) the corners' u (3), v (3); with
    ``normals_out`` the corners' unit normals (3 corners × xyz)."""
    Float, UInt32 = T.Float, T.UInt32
    m = B * F
    sx, sy, ox, oy = camera.ndc_affine(ops, Pf, H, W)
    ar = H / W
    A, Bb, C0 = [], [], []
    for i in range(3):
        vj, vk = v[(i + 1) % 3], v[(i + 2) % 3]
        if camera.orthographic:
            cz = vj[0] * vk[1] - vj[1] * vk[0]
            Dx, Dy = vj[0] - vk[0], vj[1] - vk[1]
            A.append(Dy * ar / sx)
            Bb.append(-Dx / sy)
            C0.append(cz - Dy * ox / sx + Dx * oy / sy)
        else:
            C = _cross(vj, vk)
            A.append(C[0] * ar / sx)
            Bb.append(C[1] / sy)
            C0.append(-C[0] * ox / sx - C[1] * oy / sy - C[2])
    e1 = tuple(v[1][i] - v[0][i] for i in range(3))
    e2 = tuple(v[2][i] - v[0][i] for i in range(3))
    cr = _cross(e1, e2)
    n2 = dr.detach(_dot(cr, cr))
    degenerate = n2 <= 1e-24 * dr.detach(_dot(e1, e1)) * dr.detach(_dot(e2, e2))
    A = [dr.select(degenerate, 0.0, a) for a in A]
    Bb = [dr.select(degenerate, 0.0, b) for b in Bb]
    C0 = [dr.select(degenerate, 1.0 / 3.0, c) for c in C0]
    depth = [-v[i][2] for i in range(3)]
    # --- colours: albedo per corner, Lambert with vertex (smooth) or face (flat) normals (world) ---
    n = B * V
    lane = dr.arange(UInt32, n)
    src = ((lane // V) if Bv > 1 else dr.zeros(UInt32, n)) * V + lane % V
    wv = [dr.gather(Float, verts, src * 3 + c) for c in range(3)]  # world vertices, lanes (b, v)
    wc = [tuple(dr.gather(Float, wv[c], b_f * V + vid[i]) for c in range(3)) for i in range(3)]
    we1 = tuple(wc[1][c] - wc[0][c] for c in range(3))
    we2 = tuple(wc[2][c] - wc[0][c] for c in range(3))
    fn = _cross(we1, we2)
    # corners collinear within rounding: no normal (ZERO_AREA_ULPS, gendr.renderer), as in gendr_torch
    tol = (ZERO_AREA_ULPS * float(np.finfo(np.float64 if T.double else np.float32).eps)) ** 2
    zero_area = dr.detach(_dot(fn, fn)) <= tol * dr.detach(_dot(we1, we1)) * dr.detach(_dot(we2, we2))
    fn = tuple(dr.select(zero_area, 0.0, c) for c in fn)
    if colors is None:
        albedo = [(1.0, 1.0, 1.0)] * 3
        per_face = False
    else:
        cflat, cb = colors  # flat [Bc?, N, 3] values and its batch size (1 or B)
        N = F if per_face else V
        if per_face:
            idx = (b_f if cb > 1 else dr.zeros(UInt32, m)) * N + f_f
            alb = tuple(dr.gather(Float, cflat, idx * 3 + c) for c in range(3))
            albedo = [alb] * 3
        else:
            base = (b_f if cb > 1 else dr.zeros(UInt32, m)) * N
            albedo = [tuple(dr.gather(Float, cflat, (base + vid[i]) * 3 + c) for c in range(3)) for i in range(3)]
    if per_face:
        normals = [fn] * 3
    else:
        slots = [b_f * V + vid[i] for i in range(3)]
        vn = _vertex_sums(T, fn, slots, n)
        normals = [tuple(dr.gather(Float, vn[c], b_f * V + vid[i]) for c in range(3)) for i in range(3)]
    L = settings.light_direction
    ln = math.sqrt(sum(c * c for c in L))
    ml = tuple(-c / ln for c in L)
    kink_tol = LAMBERT_KINK_ULPS * float(np.finfo(np.float64 if T.double else np.float32).eps)
    colour = []
    for i in range(3):
        nrm = normals[i]
        norm = _clamp_min(dr.sqrt(_dot(nrm, nrm)), 1e-30)
        ndl = _dot(nrm, ml) / norm
        # Lambert's kink: n·(−l) within rounding of 0 snaps to exactly 0 (gradient passes), as in
        # gendr_torch.raster._shading_data — its sign there is summation-order noise
        ndl = dr.select(dr.abs(dr.detach(ndl)) <= kink_tol, ndl - dr.detach(ndl), ndl)
        lam = _clamp_min(ndl, 0.0)
        shade = settings.ambient + settings.diffuse * lam
        colour.append(tuple(albedo[i][c] * shade for c in range(3)))
    out = A + Bb + C0 + depth + [colour[i][c] for i in range(3) for c in range(3)]
    if tex is not None:
        uvflat, Bu, Tn, uvf = tex[5:]
        ubase = (b_f if Bu > 1 else dr.zeros(UInt32, m)) * Tn
        uid = [ubase + dr.gather(UInt32, uvf, f_f * 3 + i) for i in range(3)]
        out += [dr.gather(Float, uvflat, uid[i] * 2 + c) for c in range(2) for i in range(3)]
    if normals_out:
        for i in range(3):
            nrm = normals[i]
            norm = _clamp_min(dr.sqrt(_dot(nrm, nrm)), 1e-30)
            out += [nrm[c] / norm for c in range(3)]
    return [o if dr.width(o) == m else dr.zeros(Float, m) + o for o in out]


# ---------------------------------------------------------------------------------------------
# binning (device side, detached): one bit mask over the faces per tile
# ---------------------------------------------------------------------------------------------
def tile_size(B, H, W, F, radius=0.0):
    """The tile edge in pixels: the smallest of TILES whose bit masks fit MASK_BYTES, and at least
    WIDE_TILE when the culling ``radius`` (screen units) is WIDE_RADIUS or more (see WIDE_TILE)."""
    nw = -(-F // 32)
    least = WIDE_TILE if wide_layout(radius) else 0
    for t in TILES:
        if t >= least and B * (-(-H // t)) * (-(-W // t)) * nw * 4 <= MASK_BYTES:
            return t
    return TILES[-1]


def pixel_x(Float, j, H, W):
    """Screen x of the centres of pixel columns ``j`` (1 unit = H/2 pixels). Every loop computes
    pixel centres with these two functions, so the layouts evaluate the same pairs bit for bit."""
    return (2.0 * Float(j) + (1.0 - W)) / H


def pixel_y(Float, i, H):
    """Screen y (up) of the centres of pixel rows ``i`` (row 0 at the top)."""
    return 1.0 - (2.0 * Float(i) + 1.0) / H


def pixel_box(fc, H, W, r):
    """Per face (B·F lanes): the pixel index ranges [j0, j1] × [i0, i1] (floats, clipped to the
    image) of its screen box grown by ``r`` screen units (pixel centre j at (2j + 1 − W)/H), and
    ``ok``: valid and not empty. Every pixel within distance r of the face lies in it."""
    X0 = X1 = fc.Xd[0]
    Y0 = Y1 = fc.Yd[0]
    for k in range(1, fc.K):
        X0, X1 = dr.minimum(X0, fc.Xd[k]), dr.maximum(X1, fc.Xd[k])
        Y0, Y1 = dr.minimum(Y0, fc.Yd[k]), dr.maximum(Y1, fc.Yd[k])
    half, cx = 0.5 * H, 0.5 * (W - 1)
    j0 = dr.ceil((X0 - r) * half + cx)
    j1 = dr.floor((X1 + r) * half + cx)
    i0 = dr.ceil((H * (1.0 - (Y1 + r)) - 1.0) * 0.5)
    i1 = dr.floor((H * (1.0 - (Y0 - r)) - 1.0) * 0.5)
    j0, i0 = dr.clip(j0, 0.0, float(W)), dr.clip(i0, 0.0, float(H))
    j1, i1 = dr.clip(j1, -1.0, float(W - 1)), dr.clip(i1, -1.0, float(H - 1))
    return j0, j1, i0, i1, fc.valid & (j1 >= j0) & (i1 >= i0)  # (NaN boxes compare False)


class Bins:
    """Per tile (b, ty, tx) a bit mask over the faces of batch element b (``nw`` 32-bit words):
    bit f of the mask is set when face f's screen box grown by the culling radius meets the tile and
    f's signed distance at the tile centre is at least −(radius + the tile's half diagonal), a
    conservative test (the distance is 1-Lipschitz in the pixel position). Built on the device (a symbolic loop per face over its tiles, atomic OR), so its size depends
    only on (B, H, W, F): no data-dependent host work, nothing read back. Iterating a mask visits
    the faces in ascending order (as the former host lists did), so sums are deterministic."""

    def __init__(self, fc, H, W, cull_r, T, radius=0.0, mask=None):
        F, B = fc.F, fc.B
        self.tile = TILE if TILE else tile_size(B, H, W, F, radius)  # radius: a Python float (layout only)
        t = self.tile
        self.ntx, self.nty = -(-W // t), -(-H // t)
        self.nw = nw = -(-F // 32)
        self.F = F
        self.mask_tiles = B * self.ntx * self.nty
        if mask is not None:  # the masks of an earlier pass over the same faces (frozen backward replays)
            self.mask = mask
            return
        Float, Int32, UInt32 = T.Float, T.Int32, T.UInt32
        m = B * F
        r = cull_r + 2.0 * BIN_MARGIN / H  # cull_r: the same (opaque) radius the pair loop culls with
        j0, j1, i0, i1, ok = pixel_box(fc, H, W, r)
        tx0 = Int32(dr.select(ok, j0, 0.0)) // t
        tx1 = Int32(dr.select(ok, j1, 0.0)) // t
        ty0 = Int32(dr.select(ok, i0, 0.0)) // t
        ty1 = Int32(dr.select(ok, i1, 0.0)) // t
        wt = tx1 - tx0 + 1
        count = UInt32(dr.select(ok, wt * (ty1 - ty0 + 1), 0))
        fl = dr.arange(UInt32, m)
        b, f = fl // F, fl % F
        bit = UInt32(1) << (f % 32)
        word = f // 32
        base = b * (self.ntx * self.nty)
        wtu, tx0u, ty0u = UInt32(wt), UInt32(tx0), UInt32(ty0)
        mask = dr.zeros(UInt32, B * self.ntx * self.nty * nw)

        # a tile of the box is kept when the face's signed distance at the tile centre is within
        # the radius plus the tile's half diagonal (the signed distance is 1-Lipschitz): about a
        # third fewer pairs than whole boxes for the benchmark scene
        reach = -(r + t * math.sqrt(2.0) / H)
        fidx = fl

        def body(k):
            ty, tx = ty0u + k // wtu, tx0u + k % wtu
            cx_ = (2.0 * Float(tx * t) + (t - W)) / H  # centre of the tile's pixel centres
            cy_ = 1.0 - (2.0 * Float(ty * t) + t) / H
            d, _, _ = distance_parts(fc, T, fidx, cx_, cy_, False)
            tile = base + ty * self.ntx + tx
            dr.scatter_reduce(dr.ReduceOp.Or, mask, bit, tile * nw + word, d >= reach, mode=dr.ReduceMode.Direct)
            return (k + 1,)

        with dr.suspend_grad():
            dr.while_loop((dr.zeros(UInt32, m),), lambda k: k < count, body, labels=("k",))
        self.mask = mask


def tile_order(T, bins, group=1, interleave=False):
    """``(order, slot)``: the tiles in descending order of their face counts (log-spaced classes,
    four per octave; stable within a class), ``order[slot] = tile`` and its inverse ``slot[tile]``.
    A SIMD packet of strip lanes spans several tiles and loops as long as its longest list; at a
    silhouette most tiles are empty or short (24 × 64² paper views, τ = 0.003: 55 % empty, lanes
    busy 59 % of the packet iterations), so neighbours in this order share a length (99.9 %
    busy). A counting sort by one prefix sum on the device: no read-back, fixed sizes (freezable).
    ``interleave``: the packets' groups of ``group`` tiles are then dealt out (:func:`_interleave`),
    so that the contiguous blocks of lanes that CPU threads take get equal shares of the work."""
    UInt32, n = T.UInt32, bins.mask_tiles
    v = dr.block_sum(dr.popcnt(bins.mask), bins.nw) + 1  # face count + 1 per tile
    e = 31 - dr.lzcnt(v)  # octave: floor(log2 v)
    cls = 4 * e + ((v << 2) >> e) % 4  # and the two bits below the leading one
    nc = 4 * (bins.F + 1).bit_length()
    key = (nc - 1 - cls) * n + dr.arange(UInt32, n)  # descending classes, tile index within
    flag = dr.zeros(UInt32, nc * n)
    dr.scatter(flag, UInt32(1), key)
    slot = dr.gather(UInt32, dr.prefix_sum(flag), key)
    if interleave:
        slot = _interleave(T, slot, n, group)
    order = dr.zeros(UInt32, n)
    dr.scatter(order, dr.arange(UInt32, n), slot)
    return order, slot


def deal_blocks(T):
    """Whether the loops' lanes are dealt out to balance threads (:func:`_interleave`): on the CPU
    with several threads, each of which takes contiguous blocks of lanes. One thread (the lane order
    then fixes the order of the backward's sums, as before) or a GPU's many small blocks: no."""
    return dr.backend_v(T.Float) == dr.JitBackend.LLVM and dr.thread_count() > 1


def _interleave(T, rank, n, group):
    """New positions of ranks 0..n−1: groups of ``group`` consecutive ranks (one SIMD packet's
    tiles, kept together) in the bit-reversed (van der Corput) order of their group index, a
    partial last group last. Any stretch of positions then holds heavy and light groups alike:
    Dr.Jit's CPU backend gives each thread contiguous blocks of lanes (four for two threads at
    the shape step's size), and in descending order the first block held most of the work
    (forward loop at 2 threads only 1.27× faster than at 1, τ = 0.003)."""
    UInt32, full = T.UInt32, n // group
    if full < 2:
        return rank
    bits = (full - 1).bit_length()
    g = rank // group
    key = dr.select(g < full, dr.brev(g) >> (32 - bits), 1 << bits) * group + rank % group
    flag = dr.zeros(UInt32, ((1 << bits) + 1) * group)
    dr.scatter(flag, UInt32(1), key)
    return dr.gather(UInt32, dr.prefix_sum(flag), key)


class Pixels:
    """Lanes of the pixel loops in tile-major order (b, ty, tx, lane in tile), so that a SIMD packet
    stays in one tile (coherent face lists). A lane covers ``rows`` pixels of one column of its tile
    (a strip; ``rows`` = 1: one pixel): the per-face reads and edge set-up of an iteration are shared
    by its pixels. ``py`` is the list of the strip's pixel-centre ordinates (``py[r]`` for row r);
    ``image_index`` maps row-major pixels (b, i, j) to ``r·n + lane`` (lanes of partial border tiles
    outside the image are computed and dropped). ``order``: :func:`tile_order`'s ``(order, slot)``,
    the order in which the lanes take the tiles (None: row-major tiles)."""

    def __init__(self, T, B, H, W, bins, rows=1, order=None):
        t, ntx, nty = bins.tile, bins.ntx, bins.nty
        per_tile = t * t // rows
        n = B * nty * ntx * per_tile
        lane = dr.arange(T.UInt32, n)
        slot = lane // per_tile
        tile = slot if order is None else dr.gather(T.UInt32, order[0], slot)
        loc = lane % per_tile
        b = tile // (ntx * nty)
        tyx = tile % (ntx * nty)
        i = (tyx // ntx) * t + (loc // t) * rows
        j = (tyx % ntx) * t + loc % t
        self.px = pixel_x(T.Float, j, H, W)
        self.py = [pixel_y(T.Float, i + r, H) for r in range(rows)]
        self.rows = rows
        self.word0 = tile * bins.nw  # the tile's first mask word
        self.face0 = b * bins.F      # faces of batch element b
        self.n = n
        self.H, self.W = H, W
        self.bins, self.T = bins, T
        q = dr.arange(T.UInt32, B * H * W)
        jj, ii, bb = q % W, (q // W) % H, q // (H * W)
        tile_of = (bb * nty + ii // t) * ntx + jj // t
        if order is not None:
            tile_of = dr.gather(T.UInt32, order[1], tile_of)
        lane_of = tile_of * per_tile + ((ii % t) // rows) * t + jj % t
        self.image_index = ((ii % t) % rows) * n + lane_of

    def start(self):
        """Initial face-iterator state (w, bits): positioned on the tile's first face, if any."""
        w = dr.zeros(self.T.UInt32, self.n)
        bits = dr.gather(self.T.UInt32, self.bins.mask, self.word0)
        return self.advance(w, bits)

    def advance(self, w, bits):
        """Skip empty mask words: afterwards bits != 0, or the tile's list is exhausted (bits == 0)."""
        nw, mask, word0 = self.bins.nw, self.bins.mask, self.word0
        if nw == 1:
            return w, bits

        def body(w, bits):
            w = w + 1
            return w, dr.gather(self.T.UInt32, mask, word0 + w)

        return dr.while_loop((w, bits), lambda w, bits: (bits == 0) & (w + 1 < nw), body, labels=("w", "bits"))

    def next_face(self, w, bits):
        """(face index, w, bits) of the current face, the iterator moved on by one face."""
        f = self.face0 + w * 32 + dr.tzcnt(bits)
        w, bits = self.advance(w, bits & (bits - 1))
        return f, w, bits

    def to_image(self, a):
        """Row-major image [B·H·W] of per-lane values: one array (rows = 1) or a list of ``rows``."""
        if not isinstance(a, (list, tuple)):
            a = [a]
        dr.schedule(*a)  # the gathers evaluate their sources: together, in one kernel
        if len(a) == 1:
            return dr.gather(type(a[0]), a[0], self.image_index)
        slot, lane = self.image_index // self.n, self.image_index % self.n
        out = dr.gather(type(a[0]), a[0], lane)
        for r in range(1, len(a)):
            out = dr.select(slot == r, dr.gather(type(a[r]), a[r], lane), out)
        return out


class FaceLanes:
    """Lanes of the face-major loops: one per (face, chunk) of the B·F faces (``m``). A lane walks the
    pixels of its face's screen box grown by the culling radius (every pixel within the radius lies
    in it), chunk c of C taking the box rows c, c + C, ... (C: enough lanes for every thread when
    the faces are few or large). Its start (i, j0), row end j1, last row i1 (−1: nothing to walk)
    and ``base``, the face's first pixel in the row-major image [B·H·W]. ``schedule``: arrays to
    evaluate in the kernel that computes the boxes (the gathers here evaluate their sources)."""

    def __init__(self, fc, T, H, W, schedule=(), group=1):
        Int32 = T.Int32
        self.m = m = dr.width(fc.Xd[0])
        self.C = C = max(1, min(H, -(-FACE_LANES // m)))
        r = (2.0 * BIN_MARGIN / H - fc.cull_lo) if fc.cull_lo is not None else math.inf
        box = pixel_box(fc, H, W, r)
        dr.schedule(*schedule, *(box if C > 1 else ()))
        lane = dr.arange(T.UInt32, m * C)
        self.f = f = lane // C if C > 1 else lane
        j0, j1, i0, i1, ok = (dr.gather(type(a), a, f) for a in box) if C > 1 else box
        self.j0, self.j1 = Int32(dr.select(ok, j0, 0.0)), Int32(dr.select(ok, j1, -1.0))
        self.i1 = Int32(dr.select(ok, i1, -1.0))
        self.i = Int32(dr.select(ok, i0, 0.0)) + Int32(lane % C)
        self.base = (f // fc.F) * (H * W)
        # a row is walked in groups of ``group`` pixels starting at multiples of it (W % group == 0)
        self.group = group
        self.j_start = self.j0 if group == 1 else self.j0 - self.j0 % group

    def next_pixel(self, i, j):
        """The lane's next pixel (group) (i, j) after (i, j): along the row, then C rows down."""
        j = j + self.group
        wrap = j > self.j1
        return dr.select(wrap, i + self.C, i), dr.select(wrap, self.j_start, j)


# ---------------------------------------------------------------------------------------------
# per-pair evaluation (inside the loops)
# ---------------------------------------------------------------------------------------------
def signed_distance(fc, T, f, px, py):
    d, inside, parts = distance_parts(fc, T, f, px, py, fc.ad)
    if parts is None:
        return d, inside
    i0, i1, tt, ux, uy, act = parts
    Float, mode = T.Float, GRAD_MODE  # mode: how the reverse-mode scatter-adds of these reads are compiled
    Xa, Ya = dr.gather(Float, fc.Xall, i0, act, mode=mode), dr.gather(Float, fc.Yall, i0, act, mode=mode)
    Xb, Yb = dr.gather(Float, fc.Xall, i1, act, mode=mode), dr.gather(Float, fc.Yall, i1, act, mode=mode)
    lin = ((1.0 - tt) * (ux * (Xa - dr.detach(Xa)) + uy * (Ya - dr.detach(Ya)))
           + tt * (ux * (Xb - dr.detach(Xb)) + uy * (Yb - dr.detach(Yb))))
    return d + lin, inside


def distance_parts(fc, T, f, px, py, track):
    """Signed distance (inside > 0) of pixel centres (px, py) to polygon ``f``; and ``inside``.

    Evaluated on detached corners. When the corners carry gradients, the result is linearised
    around that value: d + (1 − t)·u·(P_k − P̄_k) + t·u·(P_{k+1} − P̄_{k+1}) for the nearest edge k
    (nearest boundary point at parameter t, u = ∂d/∂(boundary point)) — the exact first-order
    dependence, as in the torch backend's analytic backward, with 4 differentiable reads per pair
    instead of AD through every edge.
    """
    d, parts = _strip_pixel(T, _edge_setup(fc, T, f, px), py, track)
    inside = d >= 0.0  # (outside, d = −max(r, sqrt(tiny)) < 0)
    if not track:
        return d, inside, None
    kk, tt, ux, uy = parts
    K = fc.K
    i0 = f * K + kk
    i1 = f * K + dr.select(kk + 1 == K, 0, kk + 1)
    # pairs beyond the culling radius have coverage < eps (zero gradient): masked reads, so the
    # reverse pass issues no scatter-add for them (value unchanged: the linear term is 0 anyway)
    act = (d >= fc.cull_lo) if fc.cull_lo is not None else T.Bool(True)
    return d, inside, (i0, i1, tt, ux, uy, act)


def live_pairs(x, x_eps, x_cut):
    """The pairs whose generator term is not culled (x >= x_eps, x > x_cut), or None: all are."""
    keep = x >= x_eps if x_eps > -math.inf else None
    if x_cut is not None:
        keep = (x > x_cut) if keep is None else keep & (x > x_cut)
    return keep


def generator_terms(dist, tcn, ops, x, x_eps, x_cut=None):
    """(g, sat): generator value (0 where saturated or culled) and saturation flag of argument x.
    Pairs with x < x_eps = F⁻¹(eps) (coverage < eps) are culled: a test on x, so that F itself is
    never evaluated where the generator reads only log(1 − F) (dead code to Dr.Jit); so are those
    with x <= x_cut (the reference cut-off, RenderSettings.cutoff_argument). The mean (``average``)
    sums p itself (TConorm.pair_term), culled alike, and never saturates. A generator of the odds
    alone (Dombi's) with a distribution of closed-form odds is evaluated from the log-odds (the
    logistic's: x, so Dombi's term is one exp)."""
    if tcn.kind == MEAN:
        g = tcn.pair_term(ops, dist.cdf(ops, x))
        keep = live_pairs(x, x_eps, x_cut)
        if keep is not None:
            g = dr.select(keep, g, 0.0)
        return g, dr.zeros(dr.mask_t(x), dr.width(x))
    if dist.has_odds and tcn.family.odds_generator is not None:
        g = tcn.odds_generator(ops, dist.log_odds(ops, x))
        sat = ~(g < math.inf)  # 1 − F underflowing or g overflowing: saturated
    else:
        p, l = dist.cdf_and_log_sf(ops, x)
        sat = ~(l > -math.inf)
        g = tcn.generator(ops, dr.select(sat, 0.5, p), dr.select(sat, math.log(0.5), l))
        sat = sat | ~(g < math.inf)  # overflow: saturated too (the generator's gradient there is finite)
    keep = live_pairs(x, x_eps, x_cut)
    if keep is not None:
        sat = sat & keep
        g = dr.select(keep & ~sat, g, 0.0)
    else:
        g = dr.select(sat, 0.0, g)
    return g, sat


def odds_product_slope(dist, c, ops, x, x_eps, x_cut):
    """∂g/∂x of a generator log(1 + c·odds(x)) (see alpha_sums): c·odds′/(1 + c·odds), one exp and
    one division for the logistic where forward-mode AD through softplus takes three divisions; 0
    for culled pairs. NaN where the odds overflow: those pixels saturate, and their δ_S is 0."""
    o, do = _local_derivative(lambda xx: dist.odds(ops, xx), x)
    gx = c * do / (1.0 + c * o)
    keep = live_pairs(x, x_eps, x_cut)
    return gx if keep is None else dr.select(keep, gx, 0.0)


def coverage(s, ops, d, tau, x_cut):
    """p = F(x), 0 where p < eps or x <= x_cut (the reference cut-off; None: none)."""
    x = s.distribution.argument(ops, d, tau)
    p = s.distribution.cdf(ops, x)
    p = dr.select(p >= s.eps, p, 0.0) if s.eps > 0 else p
    return p if x_cut is None else dr.select(x > x_cut, p, 0.0)


def shade_pair(fc, T, f, px, py, settings=None):
    """(depth, (r, g, b)) of face ``f`` at the pixel (clamped perspective-correct barycentrics);
    textured faces (``fc.tex``) multiply the lighting by the texture, sampled as ``settings`` say."""
    sh = [dr.gather(T.Float, a, f) for a in fc.shade]
    b, depth = _bary_depth(fc, T, sh, px, py)
    col = tuple(b[0] * sh[12 + c] + b[1] * sh[15 + c] + b[2] * sh[18 + c] for c in range(3))
    if fc.tex is not None:
        u = b[0] * sh[UV_ROW] + b[1] * sh[UV_ROW + 1] + b[2] * sh[UV_ROW + 2]
        v = b[0] * sh[UV_ROW + 3] + b[1] * sh[UV_ROW + 4] + b[2] * sh[UV_ROW + 5]
        texel = _texel(fc, T, f, u, v, settings.texture_filter, settings.texture_wrap)
        col = tuple(col[c] * texel[c] for c in range(3))
    return depth, col


def _texel(fc, T, f, u, v, filt, wrap):
    """RGB of the texture at (u, v) for faces ``f`` (gendr.textures conventions; same arithmetic as
    gendr_torch.raster._texel)."""
    flat, Bt, Ht, Wt, C = fc.tex
    Float, UInt32 = T.Float, T.UInt32
    base = (f // fc.F) * (Ht * Wt) if Bt > 1 else UInt32(0)

    repeat = wrap == "repeat"
    # one period first (gendr.textures.one_period): texel indices then lie in [−1, n], exactly. (Not
    # i − n·floor(i/n): Dr.Jit divides by a constant n as a product with its rounded reciprocal, so
    # 47/47 < 1 in float32 and i = n read and wrote out of bounds.)
    u, v = (u - dr.floor(dr.detach(u)), v - dr.floor(dr.detach(v))) if repeat else (dr.clip(u, -1.0, 2.0),
                                                                                     dr.clip(v, -1.0, 2.0))

    def wrapi(i, n):  # integer-valued floats in [−1, n] -> UInt32 in [0, n)
        i = dr.select(i < 0.0, i + n, dr.select(i >= n, i - n, i)) if repeat else dr.clip(i, 0.0, float(n - 1))
        return dr.minimum(UInt32(i), n - 1)  # (NaN uvs: still no out-of-bounds gather or scatter)

    def at(r, c):
        idx = (base + r * Wt + c) * C
        return [dr.gather(Float, flat, idx + ch) for ch in range(3)]

    if filt == "nearest":
        r = wrapi(dr.floor(dr.detach((1.0 - v) * Ht)), Ht)
        c = wrapi(dr.floor(dr.detach(u * Wt)), Wt)
        return at(r, c)
    x, y = u * Wt - 0.5, (1.0 - v) * Ht - 0.5
    x0, y0 = dr.floor(dr.detach(x)), dr.floor(dr.detach(y))
    fx, fy = x - x0, y - y0
    c0, c1, r0, r1 = wrapi(x0, Wt), wrapi(x0 + 1.0, Wt), wrapi(y0, Ht), wrapi(y0 + 1.0, Ht)
    t00, t01, t10, t11 = at(r0, c0), at(r0, c1), at(r1, c0), at(r1, c1)
    out = []
    for ch in range(3):  # torch.lerp's arithmetic: a + w·(b − a)
        top = t00[ch] + fx * (t01[ch] - t00[ch])
        bot = t10[ch] + fx * (t11[ch] - t10[ch])
        out.append(top + fy * (bot - top))
    return out


def _bary_depth(fc, T, sh, px, py):
    """Clamped perspective-correct barycentrics (list of 3) and view depth from gathered shade rows."""
    u = [sh[i] * px + sh[3 + i] * py + sh[6 + i] for i in range(3)]
    s = u[0] + u[1] + u[2]
    s = dr.select(dr.abs(s) > T.tiny, s, 1.0)
    b = [_clamp_min(ui / s, 0.0) for ui in u]
    bs = b[0] + b[1] + b[2]
    b = [bi / bs for bi in b]
    depth = _clamp_min(b[0] * sh[9] + b[1] * sh[10] + b[2] * sh[11], fc.near)
    return b, depth


# ---------------------------------------------------------------------------------------------
# the loops
# ---------------------------------------------------------------------------------------------
def _local_derivative(fn, x):
    """(fn(x), d fn/dx) per lane by forward-mode AD on a fresh leaf (valid inside symbolic loops):
    the spec formulas are differentiated exactly as Dr.Jit's reverse mode would."""
    with dr.isolate_grad():
        xg = type(x)(dr.detach(x))
        dr.enable_grad(xg)
        y = fn(xg)
        if not dr.grad_enabled(y):  # piecewise constant (e.g. heaviside)
            return dr.detach(y), dr.zeros(type(x), dr.width(x))
        dr.forward(xg, dr.ADFlag.ClearEdges)
        return dr.detach(y), dr.grad(y)


def _row_major(T, cols, width):
    """One flat array holding ``cols[k][f]`` at ``f·width + k`` (zeros for k >= len(cols)), built by
    gathers: scatters into one array would each evaluate the one before (a kernel apiece). Each
    element is read by one lane, so the adjoint is a plain scatter (``ReduceMode.Permute``)."""
    lane = dr.arange(T.UInt32, width * dr.width(cols[0]))
    row, col = lane // width, lane % width
    out = dr.zeros(T.Float, dr.width(lane))
    for k, c in enumerate(cols):
        sel = col == k
        out = dr.select(sel, dr.gather(T.Float, c, row, sel, mode=dr.ReduceMode.Permute), out)
    return out


def _pack_corners(T, Xd, Yd, orient):
    """One flat array of the detached corners and the orientation, face after face (X_0..X_{K−1},
    Y_0..Y_{K−1}, orient, padding to 8 or 16 entries), so that a loop reads a face with one packet
    gather (a vector load per lane and a transpose) instead of 2K + 1 gathers: forward loop of the
    paper shape step −10 to −12 % at τ = 0.01 and 0.003 (toggled in one process, 1 thread)."""
    return _row_major(T, [*Xd, *Yd, orient], _packed_width(len(Xd)))


def _packed_width(K):
    """Entries per face of :func:`_pack_corners`' array (2K + 1 used, padded to a packet width)."""
    return 8 if 2 * K + 1 <= 8 else 16


def _face_edges(fc, T, f):
    """Per (lane, face ``f``): the face's edges, (Px, Py, Ex, Ey, nx, ny, c, il, kc) each. Edge k runs
    from corner P_k to corner k + 1 (E); its unit normal (nx, ny) points into the face (orient);
    il = 1/|E|²; c offsets degenerate edges (see distance_parts). In near-clipped renders (K = 4)
    an edge from a far corner k to a nearer corner k + 1 is anchored at corner k + 1 instead, with
    E reversed (the torch backend's ``anchor_swapped``: the distance's rounding error is
    ~ulp(|anchor|)); kc is then the edge's code k + 4 (else k; None in unclipped renders), which
    :func:`_strip_pixel` turns back into (k, t from corner k)."""
    K = fc.K
    v = dr.gather(T.ArrayX, fc.packed, f, shape=(_packed_width(K), dr.width(f)))
    Xs, Ys, orient = [v[k] for k in range(K)], [v[K + k] for k in range(K)], v[2 * K]
    far = [dr.maximum(dr.abs(Xs[k]), dr.abs(Ys[k])) for k in range(K)] if K == 4 else None
    edges = []
    for k in range(K):
        Px, Py = Xs[k], Ys[k]
        Ex, Ey = Xs[(k + 1) % K] - Px, Ys[(k + 1) % K] - Py
        len2 = Ex * Ex + Ey * Ey
        nonzero = len2 > 0.0
        len2s = dr.select(nonzero, len2, 1.0)
        il = dr.select(nonzero, 1.0 / len2s, 0.0)
        inv_len = dr.select(nonzero, dr.rsqrt(len2s), 0.0) * orient
        nx, ny = -Ey * inv_len, Ex * inv_len  # (the line's normal: the same from either end)
        c = dr.select(orient == 0.0, -1.0, dr.select(nonzero, 0.0, T.big))
        kc = None
        if far is not None:
            swap = (far[k] > FAR_CORNER) & (far[k] > far[(k + 1) % K])
            Px, Py = dr.select(swap, Xs[(k + 1) % K], Px), dr.select(swap, Ys[(k + 1) % K], Py)
            Ex, Ey = dr.select(swap, -Ex, Ex), dr.select(swap, -Ey, Ey)
            kc = dr.select(swap, T.UInt32(k + 4), T.UInt32(k))
        edges.append((Px, Py, Ex, Ey, nx, ny, c, il, kc))
    return edges


def _column_edges(edges, px):
    """The edges of :func:`_face_edges` relative to the pixel column ``px`` (what _strip_pixel reads)."""
    out = []
    for Px, Py, Ex, Ey, nx, ny, c, il, kc in edges:
        dx = px - Px
        out.append((Py, Ex, Ey, nx, ny, c, il, dx, dx * nx, dx * Ex, kc))
    return out


def _edge_setup(fc, T, f, px):
    """Per (lane, face): the face's edges relative to the lane's column ``px``, shared by the pixels
    of the lane's strip."""
    return _column_edges(_face_edges(fc, T, f), px)


def _min(a, b):
    """a < b ? a : b, one x86 ``minps``. ``dr.minimum`` is the IEEE 754-2019 minimum (NaN
    propagating, −0 < +0): six AVX-512 instructions, and the pair distance takes twelve minima or
    maxima per pixel (loops −4 to −14 %). Same values here: the corners of binned faces are finite,
    and a ±0 tie yields a zero either way."""
    return dr.select(a < b, a, b)


def _max(a, b):
    """a > b ? a : b, one x86 ``maxps`` (see :func:`_min`)."""
    return dr.select(a > b, a, b)


def _strip_pixel(T, edges, py, track):
    """Signed distance (inside > 0) of one pixel of the strip to the face of ``edges`` (the distance
    to the nearest edge line inside, to the nearest boundary point outside), and with ``track`` the
    nearest edge's (k, t, ux, uy): the signed distance moves by (1 − t)·u·δP_k + t·u·δP_{k+1}."""
    d2 = emin = None
    for k, (Py, Ex, Ey, nx, ny, c, il, dx, dxnx, dxEx, kc) in enumerate(edges):
        kc = k if kc is None else kc  # (the edge's code: k, or k + 4 where anchored at corner k + 1)
        # evaluated in the torch backend's order: the same rounding decides ties between edges
        # (zero-area faces), whose corners get different gradients
        dy = py - Py
        t = _min(_max((dxEx + dy * Ey) * il, 0.0), 1.0)
        qx, qy = dx - t * Ex, dy - t * Ey
        dk = qx * qx + qy * qy
        ek = dxnx + dy * ny + c
        if d2 is None:
            d2, emin = dk, ek
            if track:
                kd = ke = T.UInt32(kc)
                td = te = t
                qxb, qyb, nxb, nyb = qx, qy, nx, ny
        else:
            if track:
                bd, be = dk < d2, ek < emin
                kd, td = dr.select(bd, kc, kd), dr.select(bd, t, td)
                qxb, qyb = dr.select(bd, qx, qxb), dr.select(bd, qy, qyb)
                ke, te = dr.select(be, kc, ke), dr.select(be, t, te)
                nxb, nyb = dr.select(be, nx, nxb), dr.select(be, ny, nyb)
            d2, emin = _min(d2, dk), _min(emin, ek)
    inside = emin >= 0.0
    r = dr.sqrt(dr.select(inside, 1.0, _max(d2, T.tiny)))
    d = dr.select(inside, emin, -r)
    if not track:
        return d, None
    # outside, (p − q)/|p − q| is −n where q lies within the edge: taken as such where that edge is
    # also the nearest line (as the torch backend's signed_distance), since on the edge the
    # quotient's direction is rounding noise
    normal = (td > 0.0) & (td < 1.0) & (ke == kd) & ((nxb != 0.0) | (nyb != 0.0))
    uox, uoy = dr.select(normal, -nxb, qxb / r), dr.select(normal, -nyb, qyb / r)
    kk, tt = dr.select(inside, ke, kd), dr.select(inside, te, td)
    if edges[0][-1] is not None:  # t was measured from the anchor: from corner k it is 1 − t
        swapped = kk >= 4
        kk, tt = dr.select(swapped, kk - 4, kk), dr.select(swapped, 1.0 - tt, tt)
    return d, (kk, tt, dr.select(inside, -nxb, uox), dr.select(inside, -nyb, uoy))


#: the odds product's cap: a pixel that reaches it (Q = Π(1 + c·odds) − 1 ≥ 2^100, or an overflowing
#: e^x) saturates: alpha 1, gradient 0. Exact to float64 while c ≤ ODDS_FACTOR_MAX: alpha is
#: Q/(Q + c) (1 − e^(−S) for c = 1), whose 1 − alpha ≤ c/Q ≤ 2^−60 is below float64's ulp
ODDS_PRODUCT_MAX = 2.0 ** 100
#: the largest c summed as an odds product; a larger one (Hamacher p > 2^40) takes the generator's
#: own loop (capped, p = 1e28 rendered alpha 1 where the coverage was 0.9953, and 1e31: 0.16)
ODDS_FACTOR_MAX = 2.0 ** 40


def odds_factor(dist, tcn):
    """c where the loops sum the generator as an odds product log Π(1 + c·odds) (alpha_sums), else None."""
    c = tcn.odds_product_factor() if dist.has_odds else None
    return c if c is None or c <= ODDS_FACTOR_MAX else None


def alpha_sums(s, fc, T, ops, pix, tau):
    """Per strip row r: S[r] = Σ_faces g(F(x(d, τ))) and the saturation count nsat[r] (no AD).

    Where the T-conorm's generator is log(1 + c·odds) (probabilistic, Einstein, Hamacher) and the
    distribution has closed-form odds (the logistic's e^x), the loop accumulates Q = Π(1 + c·odds) − 1
    instead, by Q ← Q + c·odds·(1 + Q) (relative accuracy where Q is small), capped at
    ODDS_PRODUCT_MAX, and S = log1p(Q) once per pixel: no logarithm per pair; nsat is 1 where Q
    reached the cap."""
    dist, tcn, R = s.distribution, s.tconorm, pix.rows
    x_eps, x_cut = dist.argument_threshold(s.eps), s.cutoff_argument(ops, dr.detach(tau))
    c = odds_factor(dist, tcn)
    odds_product = c is not None

    def body(w, bits, *acc):
        f, w, bits = pix.next_face(w, bits)
        edges = _edge_setup(fc, T, f, pix.px)
        S, nsat = list(acc[:R]), list(acc[R:])
        for r in range(R):
            d, _ = _strip_pixel(T, edges, pix.py[r], False)
            x = dist.argument(ops, d, tau)
            if odds_product:
                o = dist.odds(ops, x) if c == 1.0 else c * dist.odds(ops, x)
                keep = live_pairs(x, x_eps, x_cut)
                o = o if keep is None else dr.select(keep, o, 0.0)
                S[r] = _min(dr.fma(o, 1.0 + S[r], S[r]), ODDS_PRODUCT_MAX)  # inf (1 − F = 0) too
                continue
            g, sat = generator_terms(dist, tcn, ops, x, x_eps, x_cut)
            S[r], nsat[r] = S[r] + g, nsat[r] + dr.select(sat, 1, 0)
        return (w, bits, *S, *nsat)

    init = [dr.zeros(T.Float, pix.n) for _ in range(R)] + [dr.zeros(T.UInt32, pix.n) for _ in range(R)]
    out = dr.while_loop((*pix.start(), *init), lambda w, bits, *a: bits != 0, body)
    S, nsat = out[2:2 + R], out[2 + R:]
    if odds_product:
        nsat = [n + dr.select(Q >= ODDS_PRODUCT_MAX, 1, 0) for Q, n in zip(S, nsat)]
        S = [ops.log1p(Q) for Q in S]
    return tuple(S), tuple(nsat)


class _Ctx:
    """What AlphaSum needs besides its inputs. It must hold no AD-attached array: the AD graph keeps
    the op (and so this) alive, and an attached array here (the faces' corners, or the sums S that
    the op outputs) would close a reference cycle through C++ that Python's collector cannot see —
    every render leaked its graph (~4 MB per shape step) until the process ended."""

    def __init__(self, s, fc, T, ops, pix, tau_grad, resid, p_grad=False, shape_grad=False):
        # settings with the learnable parameters detached (AlphaSum gets them as inputs "tp", "dp")
        s = replace(s, tconorm=s.tconorm.with_arrays({k: dr.detach(v) for k, v in s.tconorm.learnable.items()}),
                    distribution=s.distribution.with_arrays(
                        {k: dr.detach(v) for k, v in s.distribution.learnable.items()}))
        self.p_grad, self.shape_grad = p_grad, shape_grad
        edges = Faces()  # the detached per-face data the loops read
        edges.K, edges.Xd, edges.Yd, edges.orient, edges.cull_lo = fc.K, fc.Xd, fc.Yd, fc.orient, fc.cull_lo
        edges.packed = fc.packed
        edges.F, edges.valid, edges.face_major = fc.F, fc.valid, fc.face_major
        edges.grad_xy = bool(fc.ad) and (dr.grad_enabled(fc.Xall) or dr.grad_enabled(fc.Yall))
        edges.n_corners = dr.width(fc.Xall) if fc.ad else 1
        self.parts, self.tau_grad, self.nsat, self.resid = (s, edges, T, ops, pix), tau_grad, None, resid


class AlphaSum(dr.CustomOp):
    """S = Σ_faces g(F(x(d, τ))) per pixel (archimedean T-conorms, one array per strip row; for the
    mean g(p) = p), with a hand-written backward.

    Forward: :func:`alpha_sums`, without any AD bookkeeping. Backward: a second loop over the same
    faces that recomputes each pair, takes the local derivative of the spec formulas (forward-mode
    AD on the scalar argument x, see _local_derivative), accumulates δ_S · ∂g/∂x · ∂x/∂d ·
    ∂d/∂(corner) over the lane's strip for the corners of the face (the signed distance's exact
    first-order dependence: the two corners of the nearest edge) and scatter-adds that once per
    (lane, face) (BWD_MODE); δ_S · ∂g/∂x · ∂x/∂τ
    goes into a per-lane τ accumulator summed once after the loop. Same derivatives as Dr.Jit's
    generic reverse-mode sum loop (tests/test_drjit_freeze.py)."""

    def eval(self, Xall, Yall, tau, tp, dp, ctx):
        self.ctx, self.tau, self.tp, self.dp = ctx, tau, tp, dp
        s, fc, T, ops, pix = ctx.parts
        if ctx.resid is not None:  # S and nsat of an earlier forward pass of the same inputs
            S, ctx.nsat = ctx.resid
            return tuple(T.Float(a) for a in S)
        S, nsat = alpha_sums(s, fc, T, ops, pix, tau)
        # stored when the pass runs (not re-traced into the consumers of S, e.g. the backward pass)
        dr.schedule(S, nsat)
        ctx.nsat = nsat
        return S

    def forward(self):
        raise NotImplementedError("forward-mode AD of the Dr.Jit alpha sum is not implemented")

    def backward(self):
        s, fc, T, ops, pix = self.ctx.parts
        dist, tcn, K = s.distribution, s.tconorm, fc.K
        Float = T.Float
        tau = dr.detach(self.tau)
        x_eps, x_cut = dist.argument_threshold(s.eps), s.cutoff_argument(ops, tau)
        want_xy = fc.grad_xy
        want_tau = self.ctx.tau_grad
        # learnable p (one parameter: every parametric family has just p): ∂g/∂p per pair by
        # forward-mode AD on a fresh leaf, as for τ; the direct ∂g⁻¹/∂p is ordinary AD after the op
        want_p = self.ctx.p_grad
        pname = next(iter(tcn.learnable), None)
        p_val = dr.detach(self.tp)
        # a learnable distribution parameter (the gamma shape: the only family with one), likewise
        want_k = self.ctx.shape_grad
        kname = next(iter(dist.learnable), None)
        k_val = dr.detach(self.dp)
        delta = [Float(g) for g in self.grad_out()]
        delta = [g if dr.width(g) == pix.n else dr.zeros(Float, pix.n) + g for g in delta]
        gX = dr.zeros(Float, fc.n_corners) if want_xy else None
        gY = dr.zeros(Float, fc.n_corners) if want_xy else None
        c_odds = odds_factor(dist, tcn)

        def pair(d, x, kk, tt, ux, uy, dl, gt, gp, gk, *acc):
            """One pixel's contribution: the strip's corner accumulators and the τ, p, shape sums."""
            acc = list(acc)
            if c_odds is not None:  # the forward summed an odds product (alpha_sums)
                gx = odds_product_slope(dist, c_odds, ops, x, x_eps, x_cut)
            else:
                _, gx = _local_derivative(lambda xx: generator_terms(dist, tcn, ops, xx, x_eps, x_cut)[0], x)
            # a zero incoming gradient contributes nothing, even where ∂g/∂x overflowed (0·inf):
            # as in Dr.Jit's reverse mode (e.g. a pixel whose sum S saturated: ∂A/∂S = 0)
            coef = dr.select(dl != 0.0, dl * gx, 0.0)
            if want_xy:
                _, xd = _local_derivative(lambda dd: dist.argument(ops, dd, tau), d)
                cd = coef * xd
                c0, c1 = cd * (1.0 - tt), cd * tt
                for k in range(K):
                    wk = dr.select(kk == k, c0, dr.select(kk == (k - 1) % K, c1, 0.0))
                    acc[2 * k] = acc[2 * k] + wk * ux
                    acc[2 * k + 1] = acc[2 * k + 1] + wk * uy
            if want_tau:
                _, xt = _local_derivative(lambda tt_: dist.argument(ops, d, tt_), Float(tau))
                gt = gt + coef * xt
            if want_p:
                _, gpp = _local_derivative(lambda pp: generator_terms(
                    dist, tcn.with_arrays({pname: pp}), ops, x, x_eps, x_cut)[0], Float(p_val))
                gp = gp + dr.select(dl != 0.0, dl * gpp, 0.0)
            if want_k:
                _, gkk = _local_derivative(lambda kk_: generator_terms(
                    dist.with_arrays({kname: kk_}), tcn, ops, x, x_eps, x_cut)[0], Float(k_val))
                gk = gk + dr.select(dl != 0.0, dl * gkk, 0.0)
            return (gt, gp, gk, *acc)

        loop = self._face_loop if fc.face_major else self._pixel_loop
        gt, gp, gk, gX, gY = loop(pair, delta, want_xy, x_eps, x_cut, tau, gX, gY)
        if want_xy:
            self.set_grad_in("Xall", gX)
            self.set_grad_in("Yall", gY)
        if want_tau:
            self.set_grad_in("tau", dr.sum(gt))
        if want_p:
            self.set_grad_in("tp", dr.sum(gp))
        if want_k:
            self.set_grad_in("dp", dr.sum(gk))

    def _face_loop(self, pair, delta, want_xy, x_eps, x_cut, tau, gX, gY):
        """Face-major backward (narrow culling radius, :func:`face_major_backward`): one lane per
        (face, chunk) walks the pixels of the face's box grown by the culling radius (chunk c of C
        takes the box rows c, c + C, ...), gathers each pixel's δ_S and accumulates the face's corner
        gradients in registers; the chunks are summed in chunk order afterwards and written to
        gX, gY once per face. No scatter per pair. Visits the same live pairs as the pixel-major
        loop (a pixel outside the box is beyond the radius); only the order of the sums differs."""
        s, fc, T, ops, pix = self.ctx.parts
        dist, K, Float = s.distribution, fc.K, T.Float
        H, W = pix.H, pix.W
        G = FACE_GROUP if W % FACE_GROUP == 0 else 1
        fl = FaceLanes(fc, T, H, W, delta, group=G)
        m, C = fl.m, fl.C
        delta_img = pix.to_image(list(delta))
        face_edges = _face_edges(fc, T, fl.f)

        def body(i, j, gt, gp, gk, *acc):
            py = pixel_y(Float, i, H)
            # an unmasked read, then the select (the box lies in the image): LLVM turns a masked gather
            # into a branch per lane where the CPU has no fast gathers (AVX2 Zen 3: backward −9 %);
            # G aligned pixels of the row with one packet gather (a vector load per lane)
            at = fl.base + T.UInt32(i * W + j)
            dls = [dr.gather(Float, delta_img, at)] if G == 1 else \
                dr.gather(T.ArrayX, delta_img, at // G, shape=(G, dr.width(at)))
            for k in range(G):
                jk = j + k
                d, (kk, tt, ux, uy) = _strip_pixel(T, _column_edges(face_edges, pixel_x(Float, jk, H, W)), py, True)
                x = dist.argument(ops, d, tau)
                live = live_pairs(x, x_eps, x_cut)
                # a group's columns left of the box (alignment) lie beyond the culling radius and its
                # margin, so live_pairs drops them (masking them too cost 6 % of this loop); a face-major
                # layout always has a finite radius, hence a culling test
                if live is None:
                    live = (jk >= fl.j0) & (jk <= fl.j1)
                dl = dr.select(live, dls[k], 0.0)
                gt, gp, gk, *acc = dr.if_stmt((d, x, kk, tt, ux, uy, dl, gt, gp, gk, *acc), dl != 0.0, pair,
                                              lambda *a: a[7:])
            return (*fl.next_pixel(i, j), gt, gp, gk, *acc)

        zeros = [dr.zeros(Float, m * C) for _ in range(3 + (2 * K if want_xy else 0))]
        out = dr.while_loop((fl.i, fl.j_start, *zeros), lambda i, j, *a: i <= fl.i1, body,
                            labels=("i", "j", "gt", "gp", "gk") + tuple(f"c{k}" for k in range(len(zeros) - 3)))
        gt, gp, gk, acc = out[2], out[3], out[4], list(out[5:])
        dr.eval(gt, gp, gk, acc)  # one loop kernel for all outputs (each use below would launch its own)
        if C > 1:  # chunk sums in chunk order, all corners in one kernel
            lanes = dr.arange(T.UInt32, m) * C

            def add_chunk(c, *total):
                return (c + 1, *(t + dr.gather(Float, a, lanes + c) for t, a in zip(total, acc)))

            acc = list(dr.while_loop((dr.zeros(T.UInt32, m), *(dr.zeros(Float, m) for _ in acc)),
                                     lambda c, *t: c < C, add_chunk)[1:])
        if want_xy:
            dr.schedule(*acc)
            gX, gY = _row_major(T, acc[0::2], K), _row_major(T, acc[1::2], K)
        return gt, gp, gk, gX, gY

    def _pixel_loop(self, pair, delta, want_xy, x_eps, x_cut, tau, gX, gY):
        """Pixel-major backward: the strip lanes of the forward loop over their tiles' faces,
        scatter-adding each (lane, face)'s corner gradients."""
        s, fc, T, ops, pix = self.ctx.parts
        dist, R, K, Float = s.distribution, pix.rows, fc.K, T.Float

        def body(w, bits, gt, gp, gk):
            f, w, bits = pix.next_face(w, bits)
            edges = _edge_setup(fc, T, f, pix.px)
            acc = [Float(0.0) for _ in range(2 * K)]  # (x, y) per corner, over the strip
            for r in range(R):
                d, (kk, tt, ux, uy) = _strip_pixel(T, edges, pix.py[r], True)
                x = dist.argument(ops, d, tau)
                live = live_pairs(x, x_eps, x_cut)
                args = (d, x, kk, tt, ux, uy, delta[r], gt, gp, gk, *acc)
                if live is None:
                    gt, gp, gk, *acc = pair(*args)
                else:
                    # a branch, skipped by packets without a live pair: pairs beyond the radius, or of
                    # pixels without incoming gradient, would add exact zeros
                    gt, gp, gk, *acc = dr.if_stmt(args, live & (delta[r] != 0.0), pair, lambda *a: a[7:])
            if want_xy:
                for k in range(K):
                    for g, v in ((gX, acc[2 * k]), (gY, acc[2 * k + 1])):
                        dr.scatter_reduce(dr.ReduceOp.Add, g, v, f * K + k, v != 0.0, mode=BWD_MODE)
            return w, bits, gt, gp, gk

        zeros = [dr.zeros(Float, pix.n) for _ in range(3)]
        _, _, gt, gp, gk = dr.while_loop((*pix.start(), *zeros), lambda w, bits, *acc: bits != 0, body,
                                         labels=("w", "bits", "gt", "gp", "gk"))
        return gt, gp, gk, gX, gY

    def name(self):
        return "gendr alpha sum"


def alpha_archimedean(s, fc, T, ops, pix, pix1, tau, resid=None):
    """Alpha of an archimedean T-conorm, or of the mean (``average``: S/F, F the number of faces of
    the mesh), as a row-major image [B·H·W]; sets fc.resid = (S, nsat) (the loop's sums; the
    frozen forward returns them). ``pix``: the strip lanes of :func:`alpha_sums`; ``pix1`` one pixel
    per lane (the generic reverse-mode loop). ``resid``: (S, nsat) of an earlier forward pass of the
    same inputs (frozen backward replays reuse them)."""
    tcn = s.tconorm
    learn = list(tcn.learnable.values())
    p_ad = bool(learn) and dr.grad_enabled(learn[0])
    shape = list(s.distribution.learnable.values())
    k_ad = bool(shape) and dr.grad_enabled(shape[0])
    ad = fc.ad or dr.grad_enabled(tau) or p_ad or k_ad
    if ad and not CUSTOM_BACKWARD:
        S, nsat = alpha_sum_generic(s, fc, T, ops, pix1, tau)
        S, nsat, pix = (S,), (nsat,), pix1
    elif ad:
        Xall = fc.Xall if fc.ad else dr.zeros(T.Float, 1)
        Yall = fc.Yall if fc.ad else dr.zeros(T.Float, 1)
        ctx = _Ctx(s, fc, T, ops, pix, dr.grad_enabled(tau), resid, p_ad, k_ad)  # (not a PyTree: passed as is)
        tp = learn[0] if learn else dr.zeros(T.Float, 1)
        dp = shape[0] if shape else dr.zeros(T.Float, 1)
        S = dr.custom(AlphaSum, Xall, Yall, tau, tp, dp, ctx)
        nsat = ctx.nsat
    elif resid is not None:
        S, nsat = resid
    else:
        S, nsat = alpha_sums(s, fc, T, ops, pix, tau)
        dr.schedule(S, nsat)  # one loop kernel for all rows (each gather below would evaluate its own)
    fc.resid = (S, nsat)
    A = []
    if tcn.kind == MEAN:  # no saturation, no singular point: A = S/F
        return pix.to_image([tcn.from_sum(ops, Sr, fc.F) for Sr in S])
    for Sr, nr in zip(S, nsat):
        pos = Sr >= T.tiny  # (a subnormal S counts as 0, flushed or not: as the torch backend)
        Ar = dr.select(pos, tcn.from_generator_sum(ops, dr.select(pos, Sr, 1.0)), 0.0)
        A.append(dr.select(nr > 0, 1.0, Ar))
    return pix.to_image(A)


def alpha_sum_generic(s, fc, T, ops, pix, tau):
    """S and the saturation count by Dr.Jit's generic reverse-mode sum loop (the reference the
    hand-written backward of AlphaSum is tested against)."""
    dist, tcn = s.distribution, s.tconorm
    x_eps, x_cut = dist.argument_threshold(s.eps), s.cutoff_argument(ops, dr.detach(tau))
    px, py = pix.px, pix.py[0]

    def body(w, bits, S, nsat):
        f, w, bits = pix.next_face(w, bits)
        d, _ = signed_distance(fc, T, f, px, py)
        g, sat = generator_terms(dist, tcn, ops, dist.argument(ops, d, tau), x_eps, x_cut)
        return w, bits, S + g, nsat + dr.select(sat, 1, 0)

    _, _, S, nsat = dr.while_loop((*pix.start(), dr.zeros(T.Float, pix.n), dr.zeros(T.UInt32, pix.n)),
                                  lambda w, bits, S, nsat: bits != 0, body, max_iterations=-1,
                                  labels=("w", "bits", "S", "nsat"))
    return S, nsat


def alpha_max(s, fc, T, ops, pix, tau, resid=None):
    """Alpha of max (the covering probability of the arg-max face, differentiable through that face)
    or of the hard "or" (0/1), one pixel per lane. For max, sets fc.resid = (arg,), the arg-max
    faces; ``resid``: those of an earlier forward pass of the same inputs (frozen backward replays
    skip the arg-max loop)."""
    tcn = s.tconorm
    px, py = pix.px, pix.py[0]
    tau_d = dr.detach(tau)
    x_cut = s.cutoff_argument(ops, tau_d)  # (once, outside the loop)

    def body(w, bits, best, arg):
        f, w, bits = pix.next_face(w, bits)
        d, _, _ = distance_parts(fc, T, f, px, py, False)  # (no AD here: untracked)
        p = coverage(s, ops, d, tau_d, x_cut)
        better = p > best
        return w, bits, dr.select(better, p, best), dr.select(better, f, arg)

    hard_or = tcn.kind != MAX  # the logical "or": decided once some face covers with p >= 1/2
    if resid is not None and not hard_or:
        (arg,) = resid
    else:
        with dr.suspend_grad():
            _, _, best, arg = dr.while_loop(
                (*pix.start(), dr.zeros(T.Float, pix.n), dr.full(T.UInt32, _NONE, pix.n)),
                lambda w, bits, b, a: (bits != 0) & (b < 0.5) if hard_or else bits != 0,
                body, labels=("w", "bits", "best", "arg"))
        if not hard_or:
            dr.eval(arg)  # stored once: read by the winning face's gathers and returned as residual
    if hard_or:
        return dr.select(best >= 0.5, T.Float(1.0), T.Float(0.0))  # typed: plain floats give float32
    fc.resid = (arg,)
    has = arg != _NONE
    f = dr.select(has, arg, 0)
    d, _ = signed_distance(fc, T, f, px, py)
    return dr.select(has, coverage(s, ops, d, tau, x_cut), 0.0)


def alpha_or_faces(s, fc, T, ops, H, W, tau):
    """The hard "or" (0/1: some face covers with p >= 1/2), face-major (:class:`FaceLanes`): each
    lane walks its face's box and writes 1 where the face covers, as a row-major image [B·H·W]. The
    same pairs and the same test as :func:`alpha_max`'s "or" (every pixel with p >= eps lies in the
    box), without binning; for narrow culling radii (:func:`face_major_backward`), where a box is a
    few pixels and the pixel-major loop would walk every face its tile lists."""
    Float = T.Float
    tau_d = dr.detach(tau)
    x_cut = s.cutoff_argument(ops, tau_d)
    fl = FaceLanes(fc, T, H, W)
    face_edges = _face_edges(fc, T, fl.f)
    A = dr.zeros(Float, fc.B * H * W)

    def body(i, j):
        px, py = pixel_x(Float, j, H, W), pixel_y(Float, i, H)
        d, _ = _strip_pixel(T, _column_edges(face_edges, px), py, False)
        covers = coverage(s, ops, d, tau_d, x_cut) >= 0.5
        dr.scatter(A, Float(1.0), fl.base + T.UInt32(i * W + j), covers)  # (equal values: any order)
        return fl.next_pixel(i, j)

    with dr.suspend_grad():
        dr.while_loop((fl.i, fl.j0), lambda i, j: i <= fl.i1, body, labels=("i", "j"))
    return A


def nearest_face(fc, T, pix, cull):
    """Per lane (one pixel each): the nearest face whose interior holds the pixel centre (front
    faces only with ``cull``) and whether there is one: ``(face, has)``, face 0 where none. No AD:
    the choice is piecewise constant (its values are differentiated where the caller uses them)."""
    px, py = pix.px, pix.py[0]

    def body(w, bits, best, arg):
        f, w, bits = pix.next_face(w, bits)
        _, inside, _ = distance_parts(fc, T, f, px, py, False)
        if cull:
            inside = inside & dr.gather(T.Bool, fc.front, f)
        _, depth = _bary_depth(fc, T, [dr.gather(T.Float, a, f) for a in fc.shade[:12]], px, py)
        better = inside & (depth < best)
        return w, bits, dr.select(better, depth, best), dr.select(better, f, arg)

    with dr.suspend_grad():
        _, _, _, arg = dr.while_loop((*pix.start(), dr.full(T.Float, math.inf, pix.n), dr.full(T.UInt32, _NONE, pix.n)),
                                     lambda w, bits, b, a: bits != 0, body, labels=("w", "bits", "best", "arg"))
    has = arg != _NONE
    return dr.select(has, arg, 0), has


def rgb_hard(s, fc, T, ops, pix):
    px, py = pix.px, pix.py[0]
    f, has = nearest_face(fc, T, pix, s.cull_backfaces)
    _, col = shade_pair(fc, T, f, px, py, s)
    return [dr.select(has, col[c], s.background[c]) for c in range(3)]


def rgb_softmax(s, fc, T, ops, pix, tau):
    px, py = pix.px, pix.py[0]
    gamma, beps, cull = s.gamma, s.background_eps, s.cull_backfaces
    zscale = 1.0 / (fc.far - fc.near)
    tau_d = dr.detach(tau)
    x_cut = s.cutoff_argument(ops, tau_d)  # (once, outside the loops)
    p_min = softmax_min_coverage("float64" if T.double else "float32")

    def live_zt(f, tau_, track=True):
        d = signed_distance(fc, T, f, px, py)[0] if track else distance_parts(fc, T, f, px, py, False)[0]
        p = coverage(s, ops, d, tau_, x_cut)
        live = p >= p_min  # (a tinier p counts as 0: kernels may flush its products)
        if cull:
            live = live & dr.gather(T.Bool, fc.front, f)
        depth, col = shade_pair(fc, T, f, px, py, s)
        return live, p, (fc.far - depth) * zscale, col

    def body_max(w, bits, m):
        f, w, bits = pix.next_face(w, bits)
        live, _, zt, _ = live_zt(f, tau_d, False)
        return w, bits, dr.select(live, dr.maximum(m, zt), m)

    with dr.suspend_grad():
        _, _, m = dr.while_loop((*pix.start(), dr.full(T.Float, beps, pix.n)), lambda w, bits, m: bits != 0, body_max,
                                labels=("w", "bits", "m"))
    m = dr.detach(m)

    def body_sum(wi, bits, r, g, b, den):
        f, wi, bits = pix.next_face(wi, bits)
        live, p, zt, col = live_zt(f, tau)
        w = dr.select(live, p * dr.exp(dr.select(live, zt - m, 0.0) / gamma), 0.0)
        return wi, bits, r + w * col[0], g + w * col[1], b + w * col[2], den + w

    z = dr.zeros(T.Float, pix.n)
    _, _, r, g, b, den = dr.while_loop((*pix.start(), z, T.Float(z), T.Float(z), T.Float(z)),
                                       lambda wi, bits, *a: bits != 0, body_sum, max_iterations=-1,
                                       labels=("w", "bits", "r", "g", "b", "den"))
    wb = dr.exp((beps - m) / gamma)
    den = den + wb  # >= p_min: the nearest live face's weight is its p

    def ratio(a):
        # a/den with the derivatives 1/den and −(a/den)/den: Dr.Jit's own −a/den² underflows where
        # every coverage is tiny (eps = 0: den ~1e-170 gave NaN and 40 % wrong gradients)
        q = dr.detach(a) / dr.detach(den)
        if not (dr.grad_enabled(a) or dr.grad_enabled(den)):
            return q
        return q + ((a - dr.detach(a)) - q * (den - dr.detach(den))) / dr.detach(den)
    return [ratio(num + wb * s.background[c]) for c, num in enumerate((r, g, b))]


def render(settings, camera, ops, T, P, Bc, verts, Bv, V, faces_np, colors, per_face, tau, tex=None):
    """The image as a flat array [B·H·W·4] (RGBA interleaved) and B."""
    return render_parts(settings, camera, ops, T, P, Bc, verts, Bv, V, faces_np, colors, per_face, tau, tex=tex)[:2]


def culling_radius(settings, tau_value):
    """The binning / culling radius (spec culling distance plus a relative margin), a Python float."""
    return settings.culling_distance(tau_value) * (1 + 1e-6) + 1e-6


def wide_layout(radius):
    """Whether a culling radius (screen units) selects the wide tiles and strips (WIDE_RADIUS)."""
    return radius >= WIDE_RADIUS


def face_major_backward(radius, H):
    """Whether a culling radius (screen units) at image height H selects the face-major backward of
    the alpha sums (FACE_MAJOR_RADIUS_PX)."""
    return radius * H / 2 <= FACE_MAJOR_RADIUS_PX


def render_parts(settings, camera, ops, T, P, Bc, verts, Bv, V, faces_np, colors, per_face, tau, *, cull_r=None,
                 clip=None, faces_u=None, resid=None, tex=None):
    """(image [B·H·W·4], B, fc): as :func:`render`; ``cull_r`` (an opaque Dr.Jit scalar, or None
    to derive it from the settings' τ), ``clip`` and ``faces_u`` let a frozen function pass
    everything data-dependent in as Dr.Jit inputs (see backend.FrozenRenderer)."""
    H, W = settings.image_size
    if faces_np.shape[0] == 0:  # no faces: alpha 0, RGB the background (0 without a blend)
        B = max(Bv, Bc)
        ch = dr.arange(T.UInt32, 4 * B * H * W) % 4
        out = dr.zeros(T.Float, 4 * B * H * W)
        if settings.blend is not None:
            for c in range(3):
                out = dr.select(ch == c, settings.background[c], out)
        return out, B, None
    fc = prepare_faces(settings, camera, ops, T, P, Bc, verts, Bv, V, faces_np, colors, per_face, clip, faces_u, tex)
    radius = culling_radius(settings, settings.tau_value)  # (frozen renders key on wide_layout)
    if cull_r is None:
        # opaque: the radius follows τ, and a literal would recompile the loop kernels
        cull_r = dr.opaque(T.Float, radius, 1) if math.isfinite(radius) else None
    fc.cull_lo = -cull_r if cull_r is not None else None
    fc.face_major = face_major_backward(radius, H)
    fc.resid = None
    or_faces = settings.tconorm.kind == HARD_OR and fc.face_major  # the hard "or", face-major
    if or_faces and settings.blend is None:  # no pixel lanes needed: no binning
        A = alpha_or_faces(settings, fc, T, ops, H, W, tau)
        return _rgba(T, fc.B, H, W, A, None, None), fc.B, fc
    # resid = (the loop's residuals, (mask, tile order...)) of a forward pass of the same inputs
    loop_resid, bin_resid = (None, None) if resid is None else resid
    bins = Bins(fc, H, W, cull_r if cull_r is not None else math.inf, T, radius,
                mask=None if bin_resid is None else bin_resid[0])
    strip = min(WIDE_STRIP if wide_layout(radius) else STRIP, bins.tile)
    # a packet of strip lanes that spans tiles loops for its longest list: order the tiles (a packet
    # is 8 or 16 lanes on the CPU, a CUDA warp 32; one pixel per lane fills it from one 4×4 tile)
    order = None
    per_tile = bins.tile ** 2 // strip
    if settings.tconorm.streams and per_tile < 32:
        order = (tile_order(T, bins, max(1, 16 // per_tile), deal_blocks(T)) if bin_resid is None
                 else bin_resid[1:])
    pix1 = Pixels(T, fc.B, H, W, bins, order=order)  # one pixel per lane: max, "or", the RGB blends
    if settings.tconorm.streams:  # archimedean T-conorms and the mean
        strips = Pixels(T, fc.B, H, W, bins, rows=strip, order=order)
        A = alpha_archimedean(settings, fc, T, ops, strips, pix1, tau, loop_resid)
    elif or_faces:
        A = alpha_or_faces(settings, fc, T, ops, H, W, tau)
    else:
        A = pix1.to_image(alpha_max(settings, fc, T, ops, pix1, tau, loop_resid))
    # the frozen forward returns these, and its backward replay skips the binning
    fc.resid = (fc.resid, (bins.mask, *(order or ())))
    if settings.blend is None:
        rgb = None
    elif settings.blend == "hard":
        rgb = rgb_hard(settings, fc, T, ops, pix1)
    else:
        rgb = rgb_softmax(settings, fc, T, ops, pix1, tau)
    return _rgba(T, fc.B, H, W, A, rgb, pix1), fc.B, fc


def _rgba(T, B, H, W, A, rgb, pix1):
    """The flat RGBA image [B·H·W·4] of alpha A (row-major) and the per-lane colours ``rgb`` of
    ``pix1`` (None: RGB 0)."""
    if rgb is None:  # alpha into channel 3 of zeros: a pass over the pixels, not over the channels
        out = dr.zeros(T.Float, 4 * B * H * W)
        dr.scatter(out, A, dr.arange(T.UInt32, B * H * W) * 4 + 3)
        return out
    lane = dr.arange(T.UInt32, 4 * B * H * W)
    p, ch = lane // 4, lane % 4
    out = dr.select(ch == 3, dr.gather(T.Float, A, p), 0.0)
    for c in range(3):
        out = dr.select(ch == c, dr.gather(T.Float, pix1.to_image(rgb[c]), p), out)
    return out


# ---------------------------------------------------------------------------------------------
# G-buffer
# ---------------------------------------------------------------------------------------------
GBUFFER_CHANNELS = 8  # bary (3), depth, normal (3), face id (as a float; -1: background)


def rasterize(settings, camera, ops, T, P, Bc, verts, Bv, V, faces_np):
    """The G-buffer as a flat array [B·H·W·8] (channels: GBUFFER_CHANNELS) and B: per pixel the
    nearest face containing the centre (rgb_hard's z-buffer), see gendr.GBuffer."""
    H, W = settings.image_size
    nch = GBUFFER_CHANNELS
    if faces_np.shape[0] == 0:
        B = max(Bv, Bc)
        ch = dr.arange(T.UInt32, nch * B * H * W) % nch
        return dr.select(ch == nch - 1, T.Float(-1.0), T.Float(0.0)), B
    fc = prepare_faces(settings, camera, ops, T, P, Bc, verts, Bv, V, faces_np, None, False, normals=True)
    fc.cull_lo = None
    bins = Bins(fc, H, W, 0.0, T)
    pix = Pixels(T, fc.B, H, W, bins)
    px, py = pix.px, pix.py[0]
    f, has = nearest_face(fc, T, pix, settings.cull_backfaces)
    sh = [dr.gather(T.Float, a, f) for a in fc.shade]
    b, depth = _bary_depth(fc, T, sh, px, py)
    nr = fc.normal_row
    n = [b[0] * sh[nr + c] + b[1] * sh[nr + 3 + c] + b[2] * sh[nr + 6 + c] for c in range(3)]
    norm = _clamp_min(dr.sqrt(_dot(n, n)), 1e-30)
    chans = b + [depth] + [nc / norm for nc in n]
    chans = [dr.select(has, c, 0.0) for c in chans] + [dr.select(has, T.Float(f % fc.F), -1.0)]
    lane = dr.arange(T.UInt32, nch * fc.B * H * W)
    p, ch = lane // nch, lane % nch
    out = dr.zeros(T.Float, nch * fc.B * H * W)
    for c in range(nch):
        out = dr.select(ch == c, dr.gather(T.Float, pix.to_image(chans[c]), p), out)
    return out, fc.B
