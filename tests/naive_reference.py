"""A naive, dense reference renderer for tests (tiny scenes only).

Written independently of ``backends/gendr_torch/raster.py``: the only thing borrowed from the torch
backend is its *ops namespace* (so the spec layer's distribution, T-conorm and camera formulas can be
evaluated on torch tensors). Everything else is the plainest possible code:

* every (batch, face) in a Python loop, every pixel of the image (a dense [H, W] grid per face);
* near-plane clipping by Sutherland–Hodgman on a Python list of corners;
* signed distance = ± the smallest point-to-segment distance to the clipped polygon's edges, the
  sign from a winding-number test (any winding counts; a zero-area polygon contains nothing);
* coverage p = F(x), x = d/τ (or d|d|/τ when squared), then the eps mask (p < eps -> 0);
* aggregation by FOLDING the paper's binary T-conorm S(a, b) face by face (not the generator form
  the fast path uses), a max-reduction for ``max``, and 1 where max p >= 1/2 for the hard ``or``;
  ``average`` (not a T-conorm): the plain sum of the coverages divided by F, the number of faces of
  the mesh (faces behind the near plane, which have no coverage, still count in F);
* RGB: SoftRas' softmax blend or a z-buffer ("hard"), colours from barycentrics of the
  intersection of the pixel's viewing ray with the triangle's plane (textbook ray–plane
  intersection, then areas), Lambert shading with area-weighted vertex normals (Gouraud) or face
  normals (flat, for face colours).

Autograd through this code gives the reference gradients. Conventions (DESIGN.md §3, raster.py):

* pixel (i, j) centre: NDC x = 2(j + .5)/W − 1, y = 1 − 2(i + .5)/H; screen units X = x·W/H, Y = y;
* a face's corner is in front of the near plane when its view z <= −near; faces with no part in
  front contribute nothing anywhere (no coverage, no colour);
* ``cull_backfaces``: only faces whose clipped projection is counter-clockwise on screen (signed
  area > 0, Y up) take part in the RGB blend; the silhouette always counts every face;
* softmax weights p·exp((z̃ − m)/γ), z̃ = (far − depth)/(far − near), depth = the interpolated
  positive view depth −z (clamped to >= near), m = max(ε_bg, max of z̃ over taking-part faces with p >= softmax_min_coverage), background
  weight exp((ε_bg − m)/γ);
* hard: the colour of the nearest taking-part face whose polygon contains the pixel centre, else
  the background colour;
* alpha (channel 3) is the aggregate; with ``blend=None`` RGB is 0.

Degenerate triangles (a normal of zero length up to rounding): their barycentrics are undefined;
this reference uses (1/3, 1/3, 1/3), which is exact for a face collapsed to a point; their Lambert
normal is 0 (|e1 × e2| <= ZERO_AREA_ULPS·eps·|e1|·|e2|, the backends' rule), so they are shaded
with the ambient term only.
"""
from __future__ import annotations

import math

import torch

from gendr_torch.ops import torch_ops as ops  # the ops namespace only

from gendr.renderer import LAMBERT_KINK_ULPS, ZERO_AREA_ULPS, softmax_min_coverage
from gendr.tconorms import ARCHIMEDEAN, HARD_OR, MAX, MEAN

__all__ = ["render_naive", "render_naive_settings", "pixel_face_geometry"]


def _as_tensor(value, dtype):
    if isinstance(value, torch.Tensor):
        return value.to(dtype)
    return torch.as_tensor(value, dtype=dtype)


def _camera_params(camera, dtype):
    """Camera array parameters as tensors broadcastable against [B, V]; and the camera batch."""
    P, batch = {}, 1
    for name, (value, kind) in camera.array_params().items():
        t = _as_tensor(value, dtype)
        if kind == "vec3":
            t = t.reshape(-1, 3)
            P[name] = (t[:, 0:1], t[:, 1:2], t[:, 2:3])
        else:
            t = t.reshape(-1, 1)
            P[name] = t
        batch = max(batch, t.shape[0])
    return P, batch


def _pick(v, b):
    """Row b of a per-camera [Bc, 1] tensor (or the only row), or a Python float unchanged."""
    if isinstance(v, torch.Tensor):
        v = v.reshape(-1)
        return v[b] if v.shape[0] > 1 else v[0]
    return v


def _clip_near(corners, near):
    """Sutherland–Hodgman clipping of a polygon (list of [3] tensors) to z <= −near."""
    out = []
    n = len(corners)
    for k in range(n):
        a, b = corners[k], corners[(k + 1) % n]
        a_in, b_in = bool(a[2] <= -near), bool(b[2] <= -near)
        if a_in:
            out.append(a)
        if a_in != b_in:
            t = (-near - a[2]) / (b[2] - a[2])
            out.append(a + t * (b - a))
    return out


def _screen_polygon(camera, tri, near, affine, aspect):
    """Clip a view-space triangle at the near plane and project it: list of (X, Y) or None."""
    sx, sy, ox, oy = affine
    poly = _clip_near(tri, near)
    if not poly:
        return None
    screen = []
    for q in poly:
        if camera.orthographic:
            qx, qy = sx * q[0] + ox, sy * q[1] + oy
        else:
            qx, qy = sx * q[0] / -q[2] + ox, sy * q[1] / -q[2] + oy
        screen.append((qx * aspect, qy))
    return screen


def _signed_distance(poly, X, Y, edges=False):
    """Signed distance (+ inside) from the points (X, Y) [H, W] to a polygon (list of (x, y))."""
    n = len(poly)
    dist2 = []
    winding = torch.zeros(X.shape, dtype=torch.int64)
    for k in range(n):
        (ax, ay), (bx, by) = poly[k], poly[(k + 1) % n]
        ex, ey = bx - ax, by - ay
        dx, dy = X - ax, Y - ay
        len2 = ex * ex + ey * ey
        if float(len2.detach()) > 0:
            t = torch.clamp((dx * ex + dy * ey) / len2, 0.0, 1.0)
        else:
            t = torch.zeros_like(X)
        qx, qy = dx - t * ex, dy - t * ey
        dist2.append(qx * qx + qy * qy)
        # winding number (Sunday): upward edge with the point on its left, downward on its right
        left = (ex * dy - ey * dx).detach()
        up = (ay <= Y) & (by > Y) & (left > 0)
        down = (by <= Y) & (ay > Y) & (left < 0)
        winding = winding + up.long() - down.long()
    d2 = torch.stack(dist2).amin(0)
    d = torch.sqrt(torch.clamp(d2, min=1e-300))
    inside = winding != 0
    if edges:
        return torch.where(inside, d, -d), inside, torch.sqrt(torch.stack(dist2))
    return torch.where(inside, d, -d), inside


def _rays(camera, affine, xn, yn):
    """Viewing rays of the pixels in view space: origins and directions [H, W, 3]."""
    sx, sy, ox, oy = affine
    xr, yr = (xn - ox) / sx, (yn - oy) / sy
    zero, one = torch.zeros_like(xr), torch.ones_like(xr)
    if camera.orthographic:
        return torch.stack([xr, yr, zero], -1), torch.stack([zero, zero, -one], -1)
    return torch.stack([zero, zero, zero], -1), torch.stack([xr, yr, -one], -1)


def _barycentrics(tri, ray_o, ray_d):
    """Unclamped barycentrics [H, W, 3] of the intersection of each ray with the triangle's plane
    (textbook: intersect, then ratios of sub-triangle areas); 1/3 each for a degenerate triangle."""
    v0, v1, v2 = tri
    n = torch.linalg.cross(v1 - v0, v2 - v0)
    nn = (n * n).sum()
    scale = ((v1 - v0) ** 2).sum() * ((v2 - v0) ** 2).sum()
    if not float(nn.detach()) > 1e-24 * float(scale.detach()):
        return torch.full(ray_o.shape, 1.0 / 3.0, dtype=ray_o.dtype)
    denom = (ray_d * n).sum(-1)
    parallel = denom == 0  # ray parallel to the plane (edge-on face): no intersection
    t = torch.where(parallel, 0.0, ((v0 - ray_o) * n).sum(-1) / torch.where(parallel, 1.0, denom))
    hit = ray_o + t[..., None] * ray_d
    bary = [(torch.linalg.cross((vk - vj).expand_as(hit), hit - vj) * n).sum(-1) / nn
            for vj, vk in ((v1, v2), (v2, v0), (v0, v1))]
    return torch.stack(bary, -1)


def _fold(tcn, ps, n_faces):
    """The n-ary T-conorm as a left fold of the paper's binary formula (ps: list of [H, W]); for
    ``average`` the mean over all ``n_faces`` faces of the mesh (faces missing from ps count as 0)."""
    if tcn.kind == MEAN:
        total = ps[0]
        for p in ps[1:]:
            total = total + p
        return total / n_faces
    if tcn.kind in (MAX, HARD_OR):
        m = torch.stack(ps).amax(0)
        return m if tcn.kind == MAX else (m >= 0.5).to(m.dtype)
    assert tcn.kind == ARCHIMEDEAN
    A = ps[0]
    for p in ps[1:]:
        # S(a, 1) = 1 for every T-conorm; the binary formulas' gradients are meant for [0, 1)
        sat = (A >= 1.0) | (p >= 1.0)
        a = torch.where(sat, 0.5, A)
        b = torch.where(sat, 0.5, p)
        A = torch.where(sat, 1.0, tcn.binary(ops, a, b))
    return A


def _normalize(v):
    """v/|v|; a zero vector stays 0 (with a zero gradient: its direction is undefined)."""
    n2 = (v * v).sum(-1, keepdim=True)
    ok = n2 > 0
    return torch.where(ok, v / torch.sqrt(torch.where(ok, n2, 1.0)), 0.0)


def render_naive(vertices, faces, camera, *, distribution, tconorm, tau, image_size, eps=0.0,
                 blend=None, gamma=1e-4, background_eps=1e-3, background=(0.0, 0.0, 0.0),
                 ambient=0.5, diffuse=0.5, light_direction=(0.0, 0.0, -1.0),
                 cull_backfaces=False, vertex_colors=None, face_colors=None):
    """Render [B, H, W, 4] densely. ``distribution``/``tconorm``: gendr spec objects.

    vertices: [B, V, 3] or [V, 3] tensor (its dtype is used throughout); faces: [F, 3] integer
    tensor; tau: float or 0-d tensor; colours as for :meth:`gendr.Renderer.render`.
    """
    H, W = image_size
    verts = vertices if vertices.ndim == 3 else vertices[None]
    dtype = verts.dtype
    faces = torch.as_tensor(faces, dtype=torch.long)
    tau = _as_tensor(tau, dtype)
    P, Bc = _camera_params(camera, dtype)
    B = max(verts.shape[0], Bc)
    verts = verts.expand(B, -1, -1)
    F = faces.shape[0]

    # camera frame and projection (the spec's formulas)
    xv, yv, zv = camera.view_coords(ops, P, verts[..., 0], verts[..., 1], verts[..., 2])
    view = torch.stack(torch.broadcast_tensors(xv, yv, zv), -1).expand(B, -1, -1)  # [B, V, 3]
    sx, sy, ox, oy = camera.ndc_affine(ops, P, H, W)
    near, far = camera.near, camera.far

    # pixel centres
    j = torch.arange(W, dtype=dtype)
    i = torch.arange(H, dtype=dtype)
    xn, yn = torch.meshgrid(2 * (j + 0.5) / W - 1, 1 - 2 * (i + 0.5) / H, indexing="xy")  # [H, W]
    X, Y = xn * (W / H), yn

    # shading inputs
    if blend is not None:
        light = _normalize(_as_tensor(light_direction, dtype))
        wtri = verts[:, faces]  # [B, F, 3, 3] world corners
        e1, e2 = wtri[:, :, 1] - wtri[:, :, 0], wtri[:, :, 2] - wtri[:, :, 0]
        fnormal = torch.linalg.cross(e1, e2)
        # collinear within rounding (|e1 × e2| <= ZERO_AREA_ULPS·eps·|e1|·|e2|): no normal
        tol = ZERO_AREA_ULPS * torch.finfo(dtype).eps
        noise = torch.linalg.vector_norm(fnormal, dim=-1) <= tol * torch.linalg.vector_norm(e1, dim=-1) * torch.linalg.vector_norm(e2, dim=-1)
        fnormal = torch.where(noise.detach()[..., None], 0.0, fnormal)
        if face_colors is not None:
            fc = face_colors if face_colors.ndim == 3 else face_colors[None]
            albedo = fc.to(dtype).expand(B, -1, -1)[:, :, None, :].expand(B, F, 3, 3)
            normals = fnormal[:, :, None, :].expand(B, F, 3, 3)
        else:
            if vertex_colors is None:
                albedo = torch.ones(B, F, 3, 3, dtype=dtype)
            else:
                vc = vertex_colors if vertex_colors.ndim == 3 else vertex_colors[None]
                albedo = vc.to(dtype).expand(B, -1, -1)[:, faces]
            vnormal = torch.zeros_like(verts)
            for f in range(F):
                for c in range(3):
                    vnormal = vnormal.index_add(1, faces[f, c:c + 1], fnormal[:, f:f + 1])
            normals = vnormal[:, faces]
        ndl = (_normalize(normals) * -light).sum(-1, keepdim=True)
        # Lambert's kink: |n·(−l)| within LAMBERT_KINK_ULPS·eps counts as exactly 0 (gradient passes)
        ndl = torch.where(ndl.detach().abs() <= LAMBERT_KINK_ULPS * torch.finfo(dtype).eps, ndl - ndl.detach(), ndl)
        lambert = torch.clamp(ndl, min=0.0)
        corner_rgb = albedo * (ambient + diffuse * lambert)  # [B, F, 3 corners, 3]
        bg = _as_tensor(background, dtype)

    images = []
    for b in range(B):
        sxb, syb, oxb, oyb = (_pick(v, b) for v in (sx, sy, ox, oy))
        ray_o, ray_d = _rays(camera, (sxb, syb, oxb, oyb), xn, yn)

        ps, colours, depths, takes_part, insides = [], [], [], [], []
        for f in range(F):
            tri = [view[b, int(faces[f, c])] for c in range(3)]
            screen = _screen_polygon(camera, tri, near, (sxb, syb, oxb, oyb), W / H)
            if screen is None:
                continue
            d, inside = _signed_distance(screen, X, Y)
            p = distribution.cdf(ops, distribution.argument(ops, d, tau))
            if eps > 0:
                p = torch.where(p < eps, torch.zeros_like(p), p)
            ps.append(p)
            if blend is None:
                continue
            area2 = sum(screen[k][0] * screen[(k + 1) % len(screen)][1]
                        - screen[(k + 1) % len(screen)][0] * screen[k][1] for k in range(len(screen)))
            takes_part.append(bool(area2.detach() > 0) or not cull_backfaces)
            insides.append(inside)
            v0, v1, v2 = tri
            bary = torch.clamp(_barycentrics(tri, ray_o, ray_d), min=0.0)
            bary = bary / bary.sum(-1, keepdim=True)
            depth = (bary * torch.stack([-v0[2], -v1[2], -v2[2]])).sum(-1)  # [H, W]
            depths.append(torch.clamp(depth, min=near))  # a near-clipped face's corner behind the camera
            colours.append((bary[..., :, None] * corner_rgb[b, f]).sum(-2))  # [H, W, 3]

        if ps:
            alpha = _fold(tconorm, ps, F)
        else:
            alpha = torch.zeros(H, W, dtype=dtype)

        if blend is None:
            rgb = torch.zeros(H, W, 3, dtype=dtype)
        elif blend == "softmax":
            num = torch.zeros(H, W, 3, dtype=dtype)
            den = torch.zeros(H, W, dtype=dtype)
            p_min = softmax_min_coverage(str(dtype).replace("torch.", ""))
            part = [tp & (p >= p_min) for tp, p in zip(takes_part, ps)]
            m = torch.full((H, W), float(background_eps), dtype=dtype)
            for pt, depth in zip(part, depths):
                zt = (far - depth) / (far - near)
                m = torch.where(pt, torch.maximum(m, zt), m)
            for pt, p, depth, col in zip(part, ps, depths, colours):
                zt = (far - depth) / (far - near)
                w = torch.where(pt, p * torch.exp((torch.where(pt, zt, m) - m) / gamma), 0.0)
                num = num + w[..., None] * col
                den = den + w
            wb = torch.exp((background_eps - m) / gamma)
            rgb = (num + wb[..., None] * bg) / (den + wb)[..., None]
        elif blend == "hard":
            best = torch.full((H, W), math.inf, dtype=dtype)
            rgb = bg.expand(H, W, 3)
            for tp, inside, depth, col in zip(takes_part, insides, depths, colours):
                if not tp:
                    continue
                win = inside & (depth.detach() < best)
                best = torch.where(win, depth.detach(), best)
                rgb = torch.where(win[..., None], col, rgb)
        else:
            raise ValueError(f"blend {blend!r}")
        images.append(torch.cat([rgb, alpha[..., None]], -1))
    return torch.stack(images)


def pixel_face_geometry(vertices, faces, camera, image_size):
    """Per (batch, face, pixel), detached: signed distance d, the "kink gap" [B, F, H, W] and the
    unclamped barycentrics [B, F, H, W, 3].

    The gap is, for pixel centres inside a face, the difference between the distances to its two
    nearest edges (0 on the medial axis, where d is not differentiable); +inf outside (outside a
    convex polygon d is differentiable). Faces with no part in front of the near plane: d = nan.
    Barycentrics crossing 0 are kinks of the RGB blends (they are clamped there).
    """
    H, W = image_size
    with torch.no_grad():
        verts = vertices if vertices.ndim == 3 else vertices[None]
        dtype = verts.dtype
        faces = torch.as_tensor(faces, dtype=torch.long)
        P, Bc = _camera_params(camera, dtype)
        B = max(verts.shape[0], Bc)
        verts = verts.expand(B, -1, -1)
        xv, yv, zv = camera.view_coords(ops, P, verts[..., 0], verts[..., 1], verts[..., 2])
        view = torch.stack(torch.broadcast_tensors(xv, yv, zv), -1).expand(B, -1, -1)
        affine = camera.ndc_affine(ops, P, H, W)
        j = torch.arange(W, dtype=dtype)
        i = torch.arange(H, dtype=dtype)
        xn, yn = torch.meshgrid(2 * (j + 0.5) / W - 1, 1 - 2 * (i + 0.5) / H, indexing="xy")
        d = torch.full((B, faces.shape[0], H, W), math.nan, dtype=dtype)
        gap = torch.full_like(d, math.inf)
        bary = torch.full((*d.shape, 3), math.nan, dtype=dtype)
        for b in range(B):
            aff = tuple(_pick(v, b) for v in affine)
            ray_o, ray_d = _rays(camera, aff, xn, yn)
            for f in range(faces.shape[0]):
                tri = [view[b, int(faces[f, c])] for c in range(3)]
                screen = _screen_polygon(camera, tri, camera.near, aff, W / H)
                if screen is None:
                    continue
                dd, inside, per_edge = _signed_distance(screen, xn * (W / H), yn, edges=True)
                two = per_edge.sort(0).values[:2]
                d[b, f] = dd
                gap[b, f] = torch.where(inside, two[1] - two[0], math.inf)
                bary[b, f] = _barycentrics(tri, ray_o, ray_d)
    return d, gap, bary


def render_naive_settings(settings, vertices, faces, camera, *, vertex_colors=None, face_colors=None):
    """:func:`render_naive` with everything taken from a :class:`gendr.RenderSettings`."""
    s = settings
    return render_naive(vertices, faces, camera, distribution=s.distribution, tconorm=s.tconorm,
                        tau=s.tau, image_size=s.image_size, eps=s.eps, blend=s.blend, gamma=s.gamma,
                        background_eps=s.background_eps, background=s.background, ambient=s.ambient,
                        diffuse=s.diffuse, light_direction=s.light_direction,
                        cull_backfaces=s.cull_backfaces, vertex_colors=vertex_colors,
                        face_colors=face_colors)
