"""The fast path (gendr.Renderer, torch backend) against the naive dense reference (naive_reference.py).

float64: forward and backward agree to TOL = 1e-9, absolute for the images and relative to
max(1, max |reference gradient|) for the gradients: both evaluate the same float64 formulas in
another order, measured ≤ 5e-14 for the images and ≤ 3e-12 (2e-14 relative) for the gradients over
the default run, so 1e-9 leaves four orders of magnitude for rounding while any formula or gradient
error (1e-6 and up) fails. Backward is compared through
loss = (image * fixed_randn).sum(), gradients w.r.t. the vertices, τ (a 0-d tensor requiring grad)
and the camera's parameters (tensors requiring grad).

The scene (16×20 pixels, non-square on purpose, batch of 2 with different vertices) has 6 faces:
two overlapping at different depths, a back-facing one, one crossing the near plane (clipped to a
quad that reaches far off screen), one entirely behind the camera, and a zero-area one (three
distinct collinear vertices).

Default run: every distribution setting × {eps 0, 1e-3} (blend and camera rotate with the index),
every T-conorm setting × {eps 0, 1e-3}, every blend × camera × eps for a fixed instance, plus the
targeted tests. ``pytest -m slow`` adds the exhaustive products.
"""
from __future__ import annotations


import pytest
import torch

import gendr
from gendr_torch.ops import torch_ops
from naive_reference import render_naive_settings

TOL = 1e-9  # float64: forward absolute, gradients relative to max(1, max |reference|) (see above)
F32_FWD_TOL = 2e-5  # float32 fast path vs float64 reference, values in [0, 1] (measured ~2e-6)
F32_GRAD_RTOL = 1e-3  # float32 gradients: |g32 − g64| <= F32_GRAD_RTOL · max|g64| + 1e-5 (measured ~5e-5)

H, W = 16, 20

# ------------------------------------------------------------------------------------------------
# the scene
# ------------------------------------------------------------------------------------------------
_V0 = [
    [-0.8, -0.6, 0.0], [0.7, -0.5, 0.0], [-0.1, 0.75, 0.0],          # 0: big, at z = 0
    [-0.2, -0.3, 0.5], [0.75, 0.1, 0.3], [0.1, 0.6, 0.4],            # 1: nearer, overlaps 0
    [0.3, -0.8, -0.3], [0.6, -0.1, -0.35], [-0.4, -0.2, -0.2],       # 2: back face (FACES: 6, 8, 7)
    [-0.9, 0.3, 0.2], [-0.5, 0.9, 0.1], [-0.6, 0.5, 4.5],            # 3: crosses the near plane
    [0.1, 0.1, 5.5], [0.5, 0.2, 6.0], [0.2, 0.6, 5.2],               # 4: entirely behind the eye
    [0.25, -0.75, 0.25], [0.5, -0.5, 0.25], [0.75, -0.25, 0.25],     # 5: zero area (collinear)
]
FACES = torch.tensor([[0, 1, 2], [3, 4, 5], [6, 8, 7], [9, 10, 11], [12, 13, 14], [15, 16, 17]])
ZERO_AREA = slice(15, 18)
#: the softmax blend gives a zero-area face p > 0 around it but an undefined colour and depth
#: (barycentrics of a degenerate triangle): compared on the scene without it
FACES_SOFTMAX = FACES[:5]


def scene_vertices(dtype=torch.float64):
    """[2, 18, 3]: the scene and a perturbed copy (the zero-area face moved rigidly: stays collinear)."""
    v = torch.tensor(_V0, dtype=torch.float64)
    g = torch.Generator().manual_seed(1)
    v1 = v + 0.04 * torch.randn(v.shape, generator=g, dtype=torch.float64)
    v1[ZERO_AREA] = v[ZERO_AREA] + torch.tensor([0.0625, -0.125, 0.0], dtype=torch.float64)
    return torch.stack([v, v1]).to(dtype)


def vertex_colors(dtype=torch.float64):
    g = torch.Generator().manual_seed(2)
    return torch.rand(len(_V0), 3, generator=g, dtype=torch.float64).to(dtype)


def face_colors(dtype=torch.float64):
    g = torch.Generator().manual_seed(3)
    return torch.rand(FACES.shape[0], 3, generator=g, dtype=torch.float64).to(dtype)


def make_camera(kind, dtype=torch.float64):
    """(camera, {name: parameter tensor requiring grad})."""
    t = lambda v: torch.tensor(v, dtype=dtype, requires_grad=True)
    if kind == "perspective":
        P = {"eye": t([0.1, 0.05, 3.0]), "fov_y": t(40.0)}
        return gendr.PerspectiveCamera(eye=P["eye"], fov_y=P["fov_y"]), P
    if kind == "orthographic":
        P = {"eye": t([0.0, 0.1, 3.0]), "xmag": t(1.3), "ymag": t(1.1)}
        return gendr.OrthographicCamera(eye=P["eye"], xmag=P["xmag"], ymag=P["ymag"]), P
    if kind == "intrinsics":
        P = {"fx": t(40.0), "fy": t(42.0), "cx": t(10.3), "cy": t(7.6)}
        return gendr.IntrinsicsCamera(eye=(0.05, -0.05, 3.0), **P), P
    if kind == "orbit":
        P = {"azimuth": t(10.0), "elevation": t(-5.0), "distance": t(3.2)}
        return gendr.orbit_camera(P["azimuth"], P["elevation"], P["distance"], fov_y=45.0), P
    raise ValueError(kind)


CAMERAS = ("perspective", "orthographic", "intrinsics", "orbit")
BLENDS = (None, "softmax", "hard")
EPSS = (0.0, 1e-3)

# ------------------------------------------------------------------------------------------------
# settings to sweep
# ------------------------------------------------------------------------------------------------
#: example parameters for families that need some (others use their declared defaults)
FAMILY_PARAMS = {"gamma": [{"shape": 2.0}, {"shape": 0.5}]}
#: extra variants (reversed / squared / shift) for a few families
VARIANTS = [
    ("logistic", {"squared": True}), ("logistic", {"shift": 0.5}), ("gaussian", {"reversed": True}),
    ("exponential", {"reversed": True}), ("exponential", {"squared": True}),
    ("gamma", {"shape": 2.0, "reversed": True}), ("gamma", {"shape": 0.5, "squared": True}),
    ("levy", {"reversed": True}), ("cauchy", {"squared": True}), ("uniform", {"shift": -0.5}),
    ("gumbel_min", {"reversed": True, "squared": True, "shift": 0.25}),
]
TCONORM_PARAMS = {
    "hamacher": [0.0, 0.5, 4.0], "frank": [0.01, 0.5, 10.0, 100.0], "yager": [0.5, 1.0, 2.0],
    "aczel_alsina": [0.5, 2.0], "dombi": [0.5, 1.0, 4.0], "schweizer_sklar": [-4.0, -1.0, -0.5],
}
FIXED_DISTRIBUTION = ("logistic", {})
FIXED_TCONORM = ("probabilistic", {})


def distribution_settings():
    out = []
    for name in sorted(gendr.DISTRIBUTIONS):
        for params in FAMILY_PARAMS.get(name, [{}]):
            out.append((name, dict(params)))
    out += [(n, dict(kw)) for n, kw in VARIANTS if n in gendr.DISTRIBUTIONS]
    return out


def tconorm_settings():
    out = []
    for name in sorted(gendr.TCONORMS):
        ps = TCONORM_PARAMS.get(name)
        out += [(name, {"p": p}) for p in ps] if ps else [(name, {})]
    return out


def _id(setting):
    name, kw = setting
    return name + ("(" + ",".join(f"{k}={v}" for k, v in kw.items()) + ")" if kw else "")


def default_tau(dist):
    """τ in screen units: ~0.8 px plain; squared variants work in squared units."""
    return 0.012 if dist.squared else 0.1


# ------------------------------------------------------------------------------------------------
# the comparison
# ------------------------------------------------------------------------------------------------
def run_both(dist, tcn, *, blend, eps, camera_kind, colors="vertex", tau=None, dtype=torch.float64,
             verts=None, faces=None, image_size=(H, W), **kw):
    """Render with the fast path (in ``dtype``) and the naive reference (float64).

    Returns (fast, ref, fast_grads, ref_grads) with gradients of (image * fixed_randn).sum() w.r.t.
    vertices, τ and each camera parameter (as dicts name -> tensor).
    """
    dist = gendr.distribution(dist[0], **dist[1]) if isinstance(dist, tuple) else dist
    tcn = gendr.tconorm(tcn[0], **tcn[1]) if isinstance(tcn, tuple) else tcn
    tau0 = default_tau(dist) if tau is None else tau
    verts = scene_vertices() if verts is None else verts
    if faces is None:
        faces = FACES_SOFTMAX if blend == "softmax" else FACES
    col = {"vertex": {"vertex_colors": vertex_colors()},
           "face": {"face_colors": face_colors()[:faces.shape[0]]}, None: {}}[colors]

    def one(impl, dt):
        v = verts.detach().to(dt).requires_grad_(True)
        tau_t = torch.tensor(tau0, dtype=dt, requires_grad=True)
        camera, cparams = make_camera(camera_kind, dt)
        r = gendr.Renderer(dist, tcn, tau=tau_t, image_size=image_size, eps=eps, blend=blend, **kw)
        c = {k: x.to(dt) for k, x in col.items()}
        if impl == "fast":
            img = r.render(v, faces, camera, **c)
        else:
            img = render_naive_settings(r.settings, v, faces, camera, **c)
        g = torch.Generator().manual_seed(7)
        weights = torch.randn(img.shape, generator=g, dtype=torch.float64).to(dt)
        inputs = {"vertices": v, "tau": tau_t, **cparams}
        if not img.requires_grad:  # piecewise-constant instances (heaviside, "or") without RGB
            grads = [None] * len(inputs)
        else:
            grads = torch.autograd.grad((img * weights).sum(), list(inputs.values()), allow_unused=True)
        grads = {k: (torch.zeros_like(x) if gr is None else gr) for (k, x), gr in zip(inputs.items(), grads)}
        return img.detach(), grads

    fast, fg = one("fast", dtype)
    ref, rg = one("ref", torch.float64)
    return fast, ref, fg, rg


def max_errors(fast, ref, fg, rg):
    """Max abs errors: forward, and per gradient. The gradient w.r.t. the zero-area face's own
    vertices is left out: the distance to a zero-area polygon has coincident edges, so it has a
    kink there (not differentiable; each implementation returns a different one-sided mixture)."""
    fwd = (fast.double() - ref).abs().max().item()
    bwd = {}
    for k in rg:
        a, b = fg[k].double(), rg[k]
        if k == "vertices" and a.shape[-2] == len(_V0):
            a, b = a[..., :ZERO_AREA.start, :], b[..., :ZERO_AREA.start, :]
        bwd[k] = (a - b).abs().max().item()
    return fwd, bwd


def assert_close(fast, ref, fg, rg, tol=TOL):
    assert fast.shape == ref.shape
    assert torch.isfinite(fast).all(), "fast path output has non-finite values"
    assert torch.isfinite(ref).all(), "reference output has non-finite values"
    fwd, bwd = max_errors(fast, ref, fg, rg)
    assert fwd <= tol, f"forward max abs error {fwd:.3g} > {tol:g}"
    for k in rg:
        assert torch.isfinite(fg[k]).all(), f"fast path gradient w.r.t. {k} has non-finite values"
        scale = max(1.0, rg[k].abs().max().item())
        assert bwd[k] <= tol * scale, (f"gradient w.r.t. {k}: max abs error {bwd[k]:.3g} > {tol:g} · {scale:.3g} "
                                       f"(max |ref|)")


# ------------------------------------------------------------------------------------------------
# default run
# ------------------------------------------------------------------------------------------------
DIST_SETTINGS = distribution_settings()
TCN_SETTINGS = tconorm_settings()


def test_scene_has_what_it_claims():
    """Sanity of the fixture: crossing, behind, zero-area and back-facing faces are what they claim."""
    v = scene_vertices()
    for kind in CAMERAS:
        camera, _ = make_camera(kind)
        P = {k: (tuple(torch.as_tensor(x, dtype=torch.float64).reshape(-1, 3)[:, i:i + 1] for i in range(3))
                 if t == "vec3" else torch.as_tensor(x, dtype=torch.float64).reshape(-1, 1))
             for k, (x, t) in camera.array_params().items()}
        _, _, z = camera.view_coords(torch_ops, P, v[..., 0], v[..., 1], v[..., 2])
        z = z.detach()
        front = z <= -camera.near
        assert front[:, FACES[3]].sum(-1).tolist() == [2, 2], kind  # one corner behind the near plane
        assert not front[:, FACES[4]].any(), kind
        assert front[:, FACES[[0, 1, 2, 5]]].all(), kind
    z = v[:, ZERO_AREA]
    e1, e2 = z[:, 1] - z[:, 0], z[:, 2] - z[:, 0]
    assert (torch.linalg.cross(e1, e2) == 0).all()
    tri = v[:, FACES]
    nz = torch.linalg.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])[..., 2]
    assert (nz[:, :2] > 0).all() and (nz[:, 2] < 0).all()  # faces 0, 1 face the camera; face 2 does not


@pytest.mark.parametrize("eps", EPSS)
@pytest.mark.parametrize("setting", DIST_SETTINGS, ids=[_id(s) for s in DIST_SETTINGS])
def test_every_distribution(setting, eps):
    i = DIST_SETTINGS.index(setting) + EPSS.index(eps)
    blend, camera = BLENDS[i % 3], CAMERAS[i % 4]
    assert_close(*run_both(setting, FIXED_TCONORM, blend=blend, eps=eps, camera_kind=camera, gamma=0.05))


@pytest.mark.parametrize("eps", EPSS)
@pytest.mark.parametrize("setting", TCN_SETTINGS, ids=[_id(s) for s in TCN_SETTINGS])
def test_every_tconorm(setting, eps):
    i = TCN_SETTINGS.index(setting) + EPSS.index(eps)
    blend, camera = BLENDS[i % 3], CAMERAS[(i + 1) % 4]
    assert_close(*run_both(FIXED_DISTRIBUTION, setting, blend=blend, eps=eps, camera_kind=camera, gamma=0.05))


@pytest.mark.parametrize("eps", EPSS)
@pytest.mark.parametrize("camera", CAMERAS)
@pytest.mark.parametrize("blend", BLENDS, ids=str)
def test_blends_and_cameras(blend, camera, eps):
    assert_close(*run_both(FIXED_DISTRIBUTION, FIXED_TCONORM, blend=blend, eps=eps, camera_kind=camera,
                           gamma=0.05))


@pytest.mark.parametrize("blend", ["softmax", "hard"])
@pytest.mark.parametrize("colors", ["face", None])
def test_face_colors_background_and_culling(blend, colors):
    assert_close(*run_both(("gaussian", {}), ("einstein", {}), blend=blend, eps=1e-3, camera_kind="perspective",
                           colors=colors, gamma=0.02, background=(0.2, 0.5, 0.9), cull_backfaces=True,
                           ambient=0.3, diffuse=0.6, light_direction=(0.3, -0.2, -1.0)))


def test_default_gamma_softmax():
    """The renderer's default γ = 1e-4 (a sharp softmax over depth) with τ ≈ 0.8 px."""
    assert_close(*run_both(("logistic", {"squared": True}), FIXED_TCONORM, blend="softmax", eps=1e-4,
                           camera_kind="perspective"))


def test_float32_against_float64_reference():
    """float32 fast path vs the float64 reference at a looser tolerance (F32_* above)."""
    fast, ref, fg, rg = run_both(FIXED_DISTRIBUTION, FIXED_TCONORM, blend="softmax", eps=1e-3,
                                 camera_kind="perspective", dtype=torch.float32, gamma=0.05)
    assert fast.dtype == torch.float32
    assert (fast.double() - ref).abs().max().item() <= F32_FWD_TOL
    for k in rg:
        err = (fg[k].double() - rg[k]).abs().max().item()
        assert err <= F32_GRAD_RTOL * rg[k].abs().max().item() + 1e-5, (k, err)


@pytest.mark.parametrize("blend", BLENDS, ids=str)
def test_row_bands_match_one_band(blend):
    """max_pairs=50 splits the image into many row bands (checkpointed): same result and gradients."""
    common = dict(blend=blend, eps=1e-3, camera_kind="perspective", gamma=0.05)
    one = run_both(("gaussian", {}), ("yager", {"p": 2.0}), **common)
    many = run_both(("gaussian", {}), ("yager", {"p": 2.0}), max_pairs=50, **common)
    assert_close(*many)
    assert (one[0] - many[0]).abs().max().item() <= 1e-12
    for k in one[2]:
        assert (one[2][k] - many[2][k]).abs().max().item() <= 1e-12, k


@pytest.mark.parametrize("dist, tcn, blend", [
    (("logistic", {}), ("probabilistic", {}), None), (("gaussian", {}), ("max", {}), "softmax"),
    (("cauchy", {}), ("yager", {"p": 2.0}), "hard")], ids=str)
def test_block_layouts_agree(monkeypatch, dist, tcn, blend):
    """The torch backend evaluates narrow blocks transposed ([width, R], raster.TRANSPOSE_BELOW) and
    the others as [R, width]; this scene's blocks are all narrow, so each layout is forced in turn.
    Both match the reference; images are bit-identical (sums over pairs run row by row in both);
    gradients differ only by the order of the per-row sums (float64 rounding, ≤ 1e-12 relative)."""
    import gendr_torch.raster as raster
    out = {}
    for name, below in (("rows", 0), ("transposed", 10 ** 9)):
        monkeypatch.setattr(raster, "TRANSPOSE_BELOW", below)
        out[name] = run_both(dist, tcn, blend=blend, eps=1e-3, camera_kind="perspective")
        assert_close(*out[name])
    (a, _, ga, _), (b, _, gb, _) = out["rows"], out["transposed"]
    assert torch.equal(a, b)
    for k in ga:
        assert (ga[k] - gb[k]).abs().max().item() <= 1e-12 * max(ga[k].abs().max().item(), 1.0), k


def test_gbuffer_block_layouts_agree(monkeypatch):
    """The G-buffer (nearest face, barycentrics, depth, normal) is the same in both block layouts."""
    import gendr_torch.raster as raster
    camera, _ = make_camera("perspective")
    r = gendr.Renderer(image_size=(H, W), backend="torch")
    out = []
    for below in (0, 10 ** 9):
        monkeypatch.setattr(raster, "TRANSPOSE_BELOW", below)
        g = r.rasterize(scene_vertices(), FACES, camera)
        out.append([g.face_id, g.bary, g.depth, g.normal])
    assert (out[0][0] >= 0).any()
    for a, b in zip(*out):
        assert torch.equal(a, b)


def test_offscreen_face_with_eps0_is_not_culled():
    """eps=0 promises the exact dense result ("disables culling"): a face far off screen (here ~10–14
    screen units right of the image) still has coverage > 0 everywhere for an unbounded
    distribution (cauchy, τ = 1: p ≈ 0.02–0.03)."""
    v = torch.tensor([[[12.5, -0.3, 0.0], [13.5, -0.3, 0.0], [13.0, 0.5, 0.0]]], dtype=torch.float64)
    f = torch.tensor([[0, 1, 2]])
    fast, ref, fg, rg = run_both(("cauchy", {}), FIXED_TCONORM, blend=None, eps=0.0, camera_kind="perspective",
                                 colors=None, verts=v, faces=f, tau=1.0)
    assert ref[..., 3].min() > 0.01  # the reference sees it everywhere
    assert_close(fast, ref, fg, rg)


def test_softmax_with_underflowing_coverage_is_finite():
    """eps=0, small τ: far from every face p underflows to exactly 0 while exp((z̃ − m)/γ) overflows
    (default γ = 1e-4); the blend must treat those faces as absent, not produce 0·inf = NaN."""
    fast, ref, fg, rg = run_both(FIXED_DISTRIBUTION, FIXED_TCONORM, blend="softmax", eps=0.0,
                                 camera_kind="perspective", tau=1e-3)
    assert_close(fast, ref, fg, rg)


def test_bounded_support_softmax_is_finite():
    """The same with a bounded-support distribution: p = 0 exactly inside the grown box."""
    fast, ref, fg, rg = run_both(("uniform", {}), FIXED_TCONORM, blend="softmax", eps=0.0,
                                 camera_kind="perspective", tau=0.1)
    assert_close(fast, ref, fg, rg)


def test_face_collapsed_to_a_point_softmax():
    """A face whose three corners coincide: coverage from the distance to that point; its colour is
    the (unique) colour there. Must be finite, forward and backward."""
    v = scene_vertices()
    v[:, ZERO_AREA] = v[:, 15:16]  # collapse the zero-area face to one point
    assert_close(*run_both(FIXED_DISTRIBUTION, FIXED_TCONORM, blend="softmax", eps=1e-3,
                           camera_kind="perspective", verts=v, faces=FACES, gamma=0.05, diffuse=0.0))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_zero_area_face_gets_no_diffuse_light_on_any_backend(dtype):
    """Corners collinear in float64: e1 × e2 is rounding noise (−2.7e-17 in float64, +2.9e-8 in
    float32), which normalised to ±n lit the face fully or not at all by chance: at its centre torch
    rendered (1, 1, 1), drjit (0.5, 0.5, 0.5). Its Lambert term is now 0 (ZERO_AREA_ULPS) on every
    backend: the render equals the one without diffuse light, and the backends agree."""
    import numpy as np
    v = torch.tensor([[-0.18185339938462564, 0.42421689650682415, 0.2], [-0.026846325622841588, 0.1099827432696946, 0.2],
                      [0.1669125165793885, -0.28280994827671735, 0.2]], dtype=dtype)
    faces = torch.tensor([[0, 1, 2]])
    cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0))
    images = {}
    for backend in ("torch", "drjit") if "drjit" in gendr.available_backends() else ("torch",):
        for diffuse in (0.7, 0.0):
            r = gendr.Renderer(tau=0.2, image_size=(4, 4), backend=backend, diffuse=diffuse)
            images[backend, diffuse] = np.asarray(r.to_numpy(r.render(v, faces, cam)))
        np.testing.assert_array_equal(images[backend, 0.7], images[backend, 0.0])
        assert images[backend, 0.7][0, 1, 1, 3] > 0.3  # the face does cover the centre (soft)
    if ("drjit", 0.7) in images:
        np.testing.assert_allclose(images["torch", 0.7], images["drjit", 0.7], rtol=0,
                                   atol=1e-6 if dtype == torch.float32 else 1e-12)


def test_hard_blend_is_geometric_with_eps():
    """RGB "hard" is the nearest face covering the pixel centre, whatever its soft coverage: a
    distribution whose coverage is < eps just inside the edges must not punch holes into it."""
    assert_close(*run_both(("logistic", {"shift": -8.0}), FIXED_TCONORM, blend="hard", eps=1e-3,
                           camera_kind="perspective"))


# ------------------------------------------------------------------------------------------------
# exhaustive (pytest -m slow)
# ------------------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("camera", CAMERAS)
@pytest.mark.parametrize("blend", BLENDS, ids=str)
@pytest.mark.parametrize("eps", EPSS)
@pytest.mark.parametrize("setting", DIST_SETTINGS, ids=[_id(s) for s in DIST_SETTINGS])
def test_every_distribution_exhaustive(setting, eps, blend, camera):
    assert_close(*run_both(setting, FIXED_TCONORM, blend=blend, eps=eps, camera_kind=camera, gamma=0.05))


@pytest.mark.slow
@pytest.mark.parametrize("camera", CAMERAS)
@pytest.mark.parametrize("blend", BLENDS, ids=str)
@pytest.mark.parametrize("eps", EPSS)
@pytest.mark.parametrize("setting", TCN_SETTINGS, ids=[_id(s) for s in TCN_SETTINGS])
def test_every_tconorm_exhaustive(setting, eps, blend, camera):
    assert_close(*run_both(FIXED_DISTRIBUTION, setting, blend=blend, eps=eps, camera_kind=camera, gamma=0.05))


@pytest.mark.slow
@pytest.mark.parametrize("tcn", TCN_SETTINGS, ids=[_id(s) for s in TCN_SETTINGS])
@pytest.mark.parametrize("setting", DIST_SETTINGS, ids=[_id(s) for s in DIST_SETTINGS])
def test_distribution_times_tconorm(setting, tcn):
    assert_close(*run_both(setting, tcn, blend="softmax", eps=1e-3, camera_kind="perspective", gamma=0.05))


def test_with_tau_renders_like_a_new_renderer_at_that_tau():
    """Renderer.with_tau (a τ schedule's renderer, sharing the backend object) gives the image and
    the gradients (vertices, a tensor τ) of a renderer built anew at that τ, bit for bit."""
    cam, _ = make_camera("perspective")
    base = gendr.Renderer("gaussian", gendr.tconorm("yager", p=2.0), tau=0.3, image_size=(H, W), backend="torch", eps=1e-3, blend=None)
    results = []
    for make in (lambda t: base.with_tau(t), lambda t: gendr.Renderer("gaussian", gendr.tconorm("yager", p=2.0), tau=t, image_size=(H, W),
                                                                      backend="torch", eps=1e-3, blend=None)):
        verts = scene_vertices().requires_grad_(True)
        tau = torch.tensor(0.05, dtype=torch.float64, requires_grad=True)
        alpha = make(tau).render(verts, FACES, cam)[..., 3]
        (alpha * torch.linspace(-1.0, 1.0, alpha.numel(), dtype=torch.float64).reshape(alpha.shape)).sum().backward()
        results.append((alpha.detach(), verts.grad, tau.grad))
    assert base.settings.tau_value == 0.3
    assert results[0][0].max() > 0 and results[0][2] != 0
    for a, b in zip(*results):
        assert torch.equal(a, b)
