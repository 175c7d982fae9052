"""The Dr.Jit rasterizer: one fused per-pixel loop over the faces of the pixel's screen tile.

Pipeline of one render (DESIGN.md §5; semantics identical to ``gendr_torch.raster``):

1. vertices -> camera frame -> per-face polygons clipped at the near plane (3 corners, or 4 when
   some face crosses it) -> screen units; Lambert-lit corner colours and barycentric coefficients
   for the RGB blends. Ordinary Dr.Jit AD arrays, O(B·F) work.
2. binning (host, NumPy, on detached data): each face's screen box grown by the distribution's
   culling radius is split into TILE×TILE pixel tiles; per tile, the list of faces (ascending).
3. a symbolic ``dr.while_loop`` per pixel over its tile's faces: signed distance to the polygon,
   coverage p = F(x), generator g(p), summed (archimedean T-conorms). Reverse-mode AD through this
   "sum loop" (``max_iterations=-1``) re-runs the loop body and scatters gradients into the face
   arrays; nothing is stored per (pixel, face) pair.
4. ``max`` / hard ``or`` / the hard z-buffer / the softmax maximum are not sums: a first loop
   without AD finds the arg-max (or the maximum) per pixel; the differentiable value is then
   re-evaluated for that one face (max, hard), or the maximum enters a second, summing loop as a
   constant (softmax: weights p·exp((z̃ − m)/γ)).

τ, the camera parameters and the culling constants are opaque (not literals) so changing them does
not recompile a kernel; the loop kernels depend only on the instance, image size, dtype and K.
"""
from __future__ import annotations

import math

import numpy as np
import drjit as dr

from gendr.tconorms import ARCHIMEDEAN, MAX

TILE = 8
#: above this many (tile, face) entries, when the tile lists are at least a quarter of "every tile
#: lists every face" (heavy tails, huge τ), every pixel loops over all valid faces of its batch
#: instead: memory O(F) rather than O(tiles·F), same result (the extra pairs are culled)
MAX_TILE_ENTRIES = 1 << 22
FALLBACK_RATIO = 4
GRAD_MODE = dr.ReduceMode.Auto
_NONE = 0xFFFFFFFF


class Types:
    """The Dr.Jit types of one (device, dtype): Float, UInt32, Int32, Bool, Tensor."""

    def __init__(self, module, double):
        self.module = module
        self.Float = module.Float64 if double else module.Float
        self.Tensor = module.TensorXf64 if double else module.TensorXf
        self.UInt32, self.Int32, self.Bool = module.UInt32, module.Int32, module.Bool
        self.double = double
        self.tiny = float(np.finfo(np.float64 if double else np.float32).tiny)
        self.big = float(np.finfo(np.float64 if double else np.float32).max) / 4


def _expand_params(P, bidx, Bc, T):
    """Camera arrays (width Bc or 1) gathered to lanes whose batch index is ``bidx``."""
    out = {}
    for k, v in P.items():
        if isinstance(v, tuple):
            out[k] = tuple(c if Bc == 1 else dr.gather(T.Float, c, bidx) for c in v)
        else:
            out[k] = v if Bc == 1 else dr.gather(T.Float, v, bidx)
    return out


# ---------------------------------------------------------------------------------------------
# per-face preparation
# ---------------------------------------------------------------------------------------------
class Faces:
    """Per-face data of one render (attributes set by :func:`prepare_faces`): B, F, K; corners X, Y
    (lists of K AD arrays over B·F faces), their detached copies Xd, Yd and (when they carry
    gradients, ``ad``) the flat (face, corner) arrays Xall, Yall; valid, orient (±1, 0 for zero
    area), front (counter-clockwise), near, far, shade (21 arrays or None), cull_lo."""


def prepare_faces(settings, camera, ops, T, P, Bc, verts, Bv, V, faces_np, colors, per_face):
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
    faces_u = UInt32(faces_np.reshape(-1).astype(np.uint32))
    vid = [dr.gather(UInt32, faces_u, f_f * 3 + c) for c in range(3)]
    corner = [tuple(dr.gather(Float, a, b_f * V + vid[c]) for a in (xv, yv, zv)) for c in range(3)]
    near = camera.near
    inside = [c[2] <= -near for c in corner]
    all_inside = bool(dr.all(inside[0] & inside[1] & inside[2], axis=None)) if m else True
    if all_inside:
        poly, valid, K = corner, dr.full(T.Bool, True, m), 3
    else:
        cands, flags = [], []
        for c in range(3):
            a, bq = corner[c], corner[(c + 1) % 3]
            cross = inside[c] ^ inside[(c + 1) % 3]
            dz = bq[2] - a[2]
            t = dr.select(cross, (-near - a[2]) / dr.select(cross, dz, 1.0), 0.0)
            cands += [a, tuple(a[i] + t * (bq[i] - a[i]) for i in range(3))]
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
    fc = Faces()
    fc.B, fc.F, fc.K, fc.X, fc.Y, fc.valid = B, F, K, X, Y, valid
    fc.Xd, fc.Yd = [dr.detach(x) for x in X], [dr.detach(y) for y in Y]
    fc.ad = any(dr.grad_enabled(a) for a in X + Y)
    if fc.ad:  # corners flattened (face, corner) for the linearised distance (see signed_distance)
        lane = dr.arange(UInt32, m * K)
        kf, ff = lane % K, lane // K
        fc.Xall = dr.zeros(Float, m * K)
        fc.Yall = dr.zeros(Float, m * K)
        for k in range(K):
            fc.Xall = dr.select(kf == k, dr.gather(Float, X[k], ff), fc.Xall)
            fc.Yall = dr.select(kf == k, dr.gather(Float, Y[k], ff), fc.Yall)
    area2 = sum(dr.detach(X[k]) * dr.detach(Y[(k + 1) % K]) - dr.detach(X[(k + 1) % K]) * dr.detach(Y[k]) for k in range(K))
    fc.orient = Float(dr.select(area2 > 0, 1.0, dr.select(area2 < 0, -1.0, 0.0)))
    fc.front = area2 > 0
    fc.near, fc.far = camera.near, camera.far
    fc.shade = None
    if settings.blend is not None:
        fc.shade = _shading_data(settings, camera, ops, T, Pf, H, W, verts, Bv, V, B, F, b_f, f_f, faces_u,
                                 vid, corner, colors, per_face)
    return fc


def _clamp_min(x, lo):
    """max(x, lo) whose gradient passes at x == lo (torch.clamp semantics, for parity at ties)."""
    return dr.select(x < lo, lo, x)


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _shading_data(settings, camera, ops, T, Pf, H, W, verts, Bv, V, B, F, b_f, f_f, faces_u, vid, v, colors, per_face):
    """21 per-face arrays: barycentric affine coefficients a(3), b(3), c0(3), view depths (3), lit
    corner colours (3 corners × rgb) — the same quantities as gendr_torch.raster._shading_data."""
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
    fn = _cross(tuple(wc[1][c] - wc[0][c] for c in range(3)), tuple(wc[2][c] - wc[0][c] for c in range(3)))
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
        vn = []
        for c in range(3):
            acc = dr.zeros(Float, n)
            for i in range(3):
                dr.scatter_reduce(dr.ReduceOp.Add, acc, fn[c], b_f * V + vid[i])
            vn.append(acc)
        normals = [tuple(dr.gather(Float, vn[c], b_f * V + vid[i]) for c in range(3)) for i in range(3)]
    L = settings.light_direction
    ln = math.sqrt(sum(c * c for c in L))
    ml = tuple(-c / ln for c in L)
    colour = []
    for i in range(3):
        nrm = normals[i]
        norm = _clamp_min(dr.sqrt(_dot(nrm, nrm)), 1e-30)
        lam = _clamp_min(_dot(nrm, ml) / norm, 0.0)
        shade = settings.ambient + settings.diffuse * lam
        colour.append(tuple(albedo[i][c] * shade for c in range(3)))
    out = A + Bb + C0 + depth + [colour[i][c] for i in range(3) for c in range(3)]
    return [o if dr.width(o) == m else dr.zeros(Float, m) + o for o in out]


# ---------------------------------------------------------------------------------------------
# binning (host side, detached)
# ---------------------------------------------------------------------------------------------
def bin_faces(fc, H, W, radius, T):
    """Per tile (b, ty, tx): the ascending list of candidate faces. Returns (start, end, faces) as
    Dr.Jit UInt32 arrays (start/end per tile) and the tile grid (ntx, nty)."""
    K = fc.K
    Xs = np.stack([dr.detach(x).numpy() for x in fc.X]).astype(np.float64)
    Ys = np.stack([dr.detach(y).numpy() for y in fc.Y]).astype(np.float64)
    valid = fc.valid.numpy().astype(bool)
    ntx, nty = -(-W // TILE), -(-H // TILE)
    ntiles = fc.B * ntx * nty
    X0, X1, Y0, Y1 = Xs.min(0), Xs.max(0), Ys.min(0), Ys.max(0)
    r = radius * (1 + 1e-6) + 1e-6
    with np.errstate(invalid="ignore", over="ignore"):
        j0 = np.ceil((X0 - r) * (H / 2) + (W - 1) / 2)
        j1 = np.floor((X1 + r) * (H / 2) + (W - 1) / 2)
        i0 = np.ceil((H * (1 - (Y1 + r)) - 1) / 2)
        i1 = np.floor((H * (1 - (Y0 - r)) - 1) / 2)
    j0, i0 = np.clip(np.nan_to_num(j0, nan=0, posinf=W, neginf=0), 0, W), np.clip(np.nan_to_num(i0, nan=0, posinf=H, neginf=0), 0, H)
    j1, i1 = np.clip(np.nan_to_num(j1, nan=-1, posinf=W - 1, neginf=-1), -1, W - 1), np.clip(np.nan_to_num(i1, nan=-1, posinf=H - 1, neginf=-1), -1, H - 1)
    ok = valid & (j1 >= j0) & (i1 >= i0)
    idx = np.nonzero(ok)[0]
    tx0, tx1 = (j0[idx] // TILE).astype(np.int64), (j1[idx] // TILE).astype(np.int64)
    ty0, ty1 = (i0[idx] // TILE).astype(np.int64), (i1[idx] // TILE).astype(np.int64)
    wt = tx1 - tx0 + 1
    counts = wt * (ty1 - ty0 + 1)
    total = int(counts.sum())
    if total > MAX_TILE_ENTRIES and FALLBACK_RATIO * total >= ntx * nty * idx.size:
        # one list per batch element: its valid faces (ascending); every tile of b points to it
        b_of = idx // fc.F
        first = np.searchsorted(b_of, np.arange(fc.B), "left").astype(np.uint32)
        last = np.searchsorted(b_of, np.arange(fc.B), "right").astype(np.uint32)
        per = ntx * nty
        return (T.UInt32(np.repeat(first, per)), T.UInt32(np.repeat(last, per)),
                T.UInt32(idx.astype(np.uint32) if idx.size else np.zeros(1, np.uint32)), int(idx.size) * per * TILE * TILE)
    if total == 0:
        z = np.zeros(ntiles, np.uint32)
        return T.UInt32(z), T.UInt32(z), T.UInt32(np.zeros(1, np.uint32)), 0
    rep = np.repeat(np.arange(idx.size), counts)
    local = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    b = idx[rep] // fc.F
    tile = b * (ntx * nty) + (ty0[rep] + local // wt[rep]) * ntx + (tx0[rep] + local % wt[rep])
    # stable sort by tile keeps faces ascending within each tile (radix sort for 16-bit keys)
    order = np.argsort(tile.astype(np.uint16) if ntiles <= 1 << 16 else tile, kind="stable")
    faces = idx[rep][order].astype(np.uint32)
    end = np.cumsum(np.bincount(tile, minlength=ntiles)).astype(np.uint32)
    start = np.concatenate([np.zeros(1, np.uint32), end[:-1]])
    return T.UInt32(start), T.UInt32(end), T.UInt32(faces), total


# ---------------------------------------------------------------------------------------------
# per-pair evaluation (inside the loops)
# ---------------------------------------------------------------------------------------------
def signed_distance(fc, T, f, px, py):
    """Signed distance (inside > 0) of pixel centres (px, py) to polygon ``f``; and ``inside``.

    Evaluated on detached corners. When the corners carry gradients, the result is linearised
    around that value: d + (1 − t)·u·(P_k − P̄_k) + t·u·(P_{k+1} − P̄_{k+1}) for the nearest edge k
    (nearest boundary point at parameter t, u = ∂d/∂(boundary point)) — the exact first-order
    dependence, as in the torch backend's analytic backward, with 4 differentiable reads per pair
    instead of AD through every edge.
    """
    K, Float = fc.K, T.Float
    Xs = [dr.gather(Float, x, f) for x in fc.Xd]
    Ys = [dr.gather(Float, y, f) for y in fc.Yd]
    orient = dr.gather(Float, fc.orient, f)
    track = fc.ad
    d2 = emin = None
    for k in range(K):
        Px, Py = Xs[k], Ys[k]
        Ex, Ey = Xs[(k + 1) % K] - Px, Ys[(k + 1) % K] - Py
        len2 = Ex * Ex + Ey * Ey
        nonzero = len2 > 0.0
        len2s = dr.select(nonzero, len2, 1.0)
        il = dr.select(nonzero, 1.0 / len2s, 0.0)
        inv_len = dr.select(nonzero, dr.rsqrt(len2s), 0.0) * orient
        nx, ny = -Ey * inv_len, Ex * inv_len
        c = dr.select(orient == 0.0, -1.0, dr.select(nonzero, 0.0, T.big))
        dx, dy = px - Px, py - Py
        t = dr.clip((dx * Ex + dy * Ey) * il, 0.0, 1.0)
        qx, qy = dx - t * Ex, dy - t * Ey
        dk = qx * qx + qy * qy
        ek = dx * nx + dy * ny + c
        if d2 is None:
            d2, emin = dk, ek
            if track:
                kd = ke = dr.zeros(T.UInt32, 1)
                td = te = t
                qxb, qyb, nxb, nyb = qx, qy, nx, ny
        else:
            if track:
                bd, be = dk < d2, ek < emin
                kd, td = dr.select(bd, k, kd), dr.select(bd, t, td)
                qxb, qyb = dr.select(bd, qx, qxb), dr.select(bd, qy, qyb)
                ke, te = dr.select(be, k, ke), dr.select(be, t, te)
                nxb, nyb = dr.select(be, nx, nxb), dr.select(be, ny, nyb)
            d2, emin = dr.minimum(d2, dk), dr.minimum(emin, ek)
    inside = emin >= 0.0
    r = dr.sqrt(dr.select(inside, 1.0, dr.maximum(d2, T.tiny)))
    d = dr.select(inside, emin, -r)
    if not track:
        return d, inside
    kk = dr.select(inside, ke, kd)
    tt = dr.select(inside, te, td)
    ux = dr.select(inside, -nxb, qxb / r)
    uy = dr.select(inside, -nyb, qyb / r)
    i0 = f * K + kk
    i1 = f * K + dr.select(kk + 1 == K, 0, kk + 1)
    # pairs beyond the culling radius have coverage < eps (zero gradient): masked reads, so the
    # reverse pass issues no scatter-add for them (value unchanged: the linear term is 0 anyway)
    act = (d >= fc.cull_lo) if fc.cull_lo is not None else True
    mode = GRAD_MODE  # how the reverse-mode scatter-adds of these reads are compiled
    Xa, Ya = dr.gather(Float, fc.Xall, i0, act, mode=mode), dr.gather(Float, fc.Yall, i0, act, mode=mode)
    Xb, Yb = dr.gather(Float, fc.Xall, i1, act, mode=mode), dr.gather(Float, fc.Yall, i1, act, mode=mode)
    lin = ((1.0 - tt) * (ux * (Xa - dr.detach(Xa)) + uy * (Ya - dr.detach(Ya)))
           + tt * (ux * (Xb - dr.detach(Xb)) + uy * (Yb - dr.detach(Yb))))
    return d + lin, inside


def generator_terms(dist, tcn, ops, x, eps):
    """(g, sat, p): generator value (0 where saturated or culled), saturation flag, coverage."""
    p = dist.cdf(ops, x)
    l = dist.log_sf(ops, x)
    sat = ~(l > -math.inf)
    g = tcn.generator(ops, dr.select(sat, 0.5, p), dr.select(sat, math.log(0.5), l))
    sat = sat | ~(g < math.inf)  # overflow: saturated too (the generator's gradient there is finite)
    if eps > 0:
        keep = p >= eps
        sat = sat & keep
        g = dr.select(keep & ~sat, g, 0.0)
    else:
        g = dr.select(sat, 0.0, g)
    return g, sat, p


def coverage(dist, ops, d, tau, eps):
    p = dist.cdf(ops, dist.argument(ops, d, tau))
    return dr.select(p >= eps, p, 0.0) if eps > 0 else p


def shade_pair(fc, T, f, px, py):
    """(depth, (r, g, b)) of face ``f`` at the pixel (clamped perspective-correct barycentrics)."""
    sh = [dr.gather(T.Float, a, f) for a in fc.shade]
    u = [sh[i] * px + sh[3 + i] * py + sh[6 + i] for i in range(3)]
    s = u[0] + u[1] + u[2]
    s = dr.select(dr.abs(s) > T.tiny, s, 1.0)
    b = [_clamp_min(ui / s, 0.0) for ui in u]
    bs = b[0] + b[1] + b[2]
    b = [bi / bs for bi in b]
    depth = _clamp_min(b[0] * sh[9] + b[1] * sh[10] + b[2] * sh[11], fc.near)
    col = tuple(b[0] * sh[12 + c] + b[1] * sh[15 + c] + b[2] * sh[18 + c] for c in range(3))
    return depth, col


# ---------------------------------------------------------------------------------------------
# the loops
# ---------------------------------------------------------------------------------------------
class Pixels:
    """Lanes (b, i, j) of the image: pixel centres and their tile's face range."""

    def __init__(self, T, B, H, W, start, end):
        n = B * H * W
        lane = dr.arange(T.UInt32, n)
        j = lane % W
        i = (lane // W) % H
        b = lane // (H * W)
        self.px = (2.0 * T.Float(j) + (1.0 - W)) / H
        self.py = 1.0 - (2.0 * T.Float(i) + 1.0) / H
        ntx, nty = -(-W // TILE), -(-H // TILE)
        tile = b * (ntx * nty) + (i // TILE) * ntx + j // TILE
        self.start = dr.gather(T.UInt32, start, tile)
        self.end = dr.gather(T.UInt32, end, tile)
        self.n = n


def alpha_archimedean(s, fc, T, ops, pix, tiles, tau):
    dist, tcn, eps = s.distribution, s.tconorm, s.eps
    px, py, end = pix.px, pix.py, pix.end

    def body(k, S, nsat):
        f = dr.gather(T.UInt32, tiles, k)
        d, _ = signed_distance(fc, T, f, px, py)
        g, sat, _ = generator_terms(dist, tcn, ops, dist.argument(ops, d, tau), eps)
        return k + 1, S + g, nsat + dr.select(sat, 1, 0)

    _, S, nsat = dr.while_loop((T.UInt32(pix.start), dr.zeros(T.Float, pix.n), dr.zeros(T.UInt32, pix.n)),
                               lambda k, S, nsat: k < end, body, max_iterations=-1, labels=("k", "S", "nsat"))
    pos = S > 0.0
    A = dr.select(pos, tcn.from_generator_sum(ops, dr.select(pos, S, 1.0)), 0.0)
    return dr.select(nsat > 0, 1.0, A)


def alpha_max(s, fc, T, ops, pix, tiles, tau):
    dist, tcn, eps = s.distribution, s.tconorm, s.eps
    px, py, end = pix.px, pix.py, pix.end
    tau_d = dr.detach(tau)

    def body(k, best, arg):
        f = dr.gather(T.UInt32, tiles, k)
        d, _ = signed_distance(fc, T, f, px, py)
        p = coverage(dist, ops, d, tau_d, eps)
        better = p > best
        return k + 1, dr.select(better, p, best), dr.select(better, f, arg)

    with dr.suspend_grad():
        _, best, arg = dr.while_loop((T.UInt32(pix.start), dr.zeros(T.Float, pix.n), dr.full(T.UInt32, _NONE, pix.n)),
                                     lambda k, b, a: k < end, body, labels=("k", "best", "arg"))
    if tcn.kind != MAX:  # the hard logical "or"
        return dr.select(best >= 0.5, T.Float(1.0), T.Float(0.0))  # typed: plain floats give float32
    has = arg != _NONE
    f = dr.select(has, arg, 0)
    d, _ = signed_distance(fc, T, f, px, py)
    return dr.select(has, coverage(dist, ops, d, tau, eps), 0.0)


def rgb_hard(s, fc, T, ops, pix, tiles):
    px, py, end = pix.px, pix.py, pix.end
    cull = s.cull_backfaces

    def body(k, best, arg):
        f = dr.gather(T.UInt32, tiles, k)
        _, inside = signed_distance(fc, T, f, px, py)
        if cull:
            inside = inside & dr.gather(T.Bool, fc.front, f)
        depth, _ = shade_pair(fc, T, f, px, py)
        better = inside & (depth < best)
        return k + 1, dr.select(better, depth, best), dr.select(better, f, arg)

    with dr.suspend_grad():
        _, _, arg = dr.while_loop((T.UInt32(pix.start), dr.full(T.Float, math.inf, pix.n), dr.full(T.UInt32, _NONE, pix.n)),
                                  lambda k, b, a: k < end, body, labels=("k", "best", "arg"))
    has = arg != _NONE
    _, col = shade_pair(fc, T, dr.select(has, arg, 0), px, py)
    return [dr.select(has, col[c], s.background[c]) for c in range(3)]


def rgb_softmax(s, fc, T, ops, pix, tiles, tau):
    dist, eps = s.distribution, s.eps
    px, py, end = pix.px, pix.py, pix.end
    gamma, beps, cull = s.gamma, s.background_eps, s.cull_backfaces
    zscale = 1.0 / (fc.far - fc.near)
    tau_d = dr.detach(tau)

    def live_zt(f, tau_):
        d, _ = signed_distance(fc, T, f, px, py)
        p = coverage(dist, ops, d, tau_, eps)
        live = p > 0.0
        if cull:
            live = live & dr.gather(T.Bool, fc.front, f)
        depth, col = shade_pair(fc, T, f, px, py)
        return live, p, (fc.far - depth) * zscale, col

    def body_max(k, m):
        f = dr.gather(T.UInt32, tiles, k)
        live, _, zt, _ = live_zt(f, tau_d)
        return k + 1, dr.select(live, dr.maximum(m, zt), m)

    with dr.suspend_grad():
        _, m = dr.while_loop((T.UInt32(pix.start), dr.full(T.Float, beps, pix.n)), lambda k, m: k < end, body_max,
                             labels=("k", "m"))
    m = dr.detach(m)

    def body_sum(k, r, g, b, den):
        f = dr.gather(T.UInt32, tiles, k)
        live, p, zt, col = live_zt(f, tau)
        w = dr.select(live, p * dr.exp(dr.select(live, zt - m, 0.0) / gamma), 0.0)
        return k + 1, r + w * col[0], g + w * col[1], b + w * col[2], den + w

    z = dr.zeros(T.Float, pix.n)
    _, r, g, b, den = dr.while_loop((T.UInt32(pix.start), z, T.Float(z), T.Float(z), T.Float(z)),
                                    lambda k, *a: k < end, body_sum, max_iterations=-1,
                                    labels=("k", "r", "g", "b", "den"))
    wb = dr.exp((beps - m) / gamma)
    den = den + wb
    return [(num + wb * s.background[c]) / den for c, num in enumerate((r, g, b))]


def render(settings, camera, ops, T, P, Bc, verts, Bv, V, faces_np, colors, per_face, tau):
    """The image as a flat array [B·H·W·4] (RGBA interleaved) and B."""
    H, W = settings.image_size
    if faces_np.shape[0] == 0:  # no faces: alpha 0, RGB the background (0 without a blend)
        B = max(Bv, Bc)
        ch = dr.arange(T.UInt32, 4 * B * H * W) % 4
        out = dr.zeros(T.Float, 4 * B * H * W)
        if settings.blend is not None:
            for c in range(3):
                out = dr.select(ch == c, settings.background[c], out)
        return out, B
    fc = prepare_faces(settings, camera, ops, T, P, Bc, verts, Bv, V, faces_np, colors, per_face)
    radius = settings.distribution.culling_distance(settings.eps, settings.tau_value)
    cull_r = radius * (1 + 1e-6) + 1e-6  # the margin bin_faces uses too
    # opaque: the radius follows τ, and a literal would recompile the loop kernels
    fc.cull_lo = dr.opaque(T.Float, -cull_r, 1) if math.isfinite(cull_r) else None
    start, end, tiles, _ = bin_faces(fc, H, W, radius, T)
    pix = Pixels(T, fc.B, H, W, start, end)
    if settings.tconorm.kind == ARCHIMEDEAN:
        A = alpha_archimedean(settings, fc, T, ops, pix, tiles, tau)
    else:
        A = alpha_max(settings, fc, T, ops, pix, tiles, tau)
    if settings.blend is None:
        rgb = None
    elif settings.blend == "hard":
        rgb = rgb_hard(settings, fc, T, ops, pix, tiles)
    else:
        rgb = rgb_softmax(settings, fc, T, ops, pix, tiles, tau)
    n = pix.n
    lane = dr.arange(T.UInt32, 4 * n)
    p, ch = lane // 4, lane % 4
    out = dr.select(ch == 3, dr.gather(T.Float, A, p), 0.0)
    if rgb is not None:
        for c in range(3):
            out = dr.select(ch == c, dr.gather(T.Float, rgb[c], p), out)
    return out, fc.B
