"""``average``: the mean aggregation A = (1/F)·Σ_t p_t over all F faces of the mesh (not a T-conorm).

* closed form: a small orthographic scene (two overlapping triangles, one apart, one behind the
  camera that reaches no pixel but still counts in F) against a direct NumPy computation of the
  signed distances and coverages, in both backends, float64 and float32, batched, for the silhouette
  and for the alpha channel of both RGB blends; with eps culling and with the reference cut-off
  (culled pairs add 0 to the sum and still count in F); a crisp coverage p = 1 adds exactly 1 (it
  does not saturate the pixel, as it would an archimedean T-conorm: A = count/F);
* Dr.Jit against torch, images and gradients (vertices, τ, camera, colours) at the tolerances of
  test_drjit_parity.py, on its scene (faces crossing and behind the near plane, zero-area and
  back-facing faces), including the frozen renderer and Dr.Jit's generic reverse-mode loop;
* gradients against float64 central finite differences, both backends;
* typed errors, and that ``average`` stays out of the paper grid and is listed apart by ``gendr list``.

The registry-wide loops of test_renderer_reference.py (naive dense reference), test_gradcheck.py and
test_drjit_gradcheck.py (torch.autograd.gradcheck) cover ``average`` as well; test_tconorms.py checks
its spec (which T-conorm axioms hold and which fail).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import gendr  # noqa: E402
from gendr.errors import ParameterError, UnknownNameError  # noqa: E402

HAS_DRJIT = "drjit" in gendr.available_backends()
try:
    import drjit  # noqa: F401
except ImportError:
    HAS_DRJIT = False
BACKENDS = ["torch"] + (["drjit"] if HAS_DRJIT else [])
needs_drjit = pytest.mark.skipif(not HAS_DRJIT, reason="needs the Dr.Jit backend")

# --- the closed-form scene: orthographic camera at z = 2 looking down −Z, screen = world (x, y) -------
H = W = 24
FACES = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11]])
VERTS = np.array([
    [-0.6, -0.5, 0.0], [0.4, -0.5, 0.0], [-0.1, 0.5, 0.0],     # A
    [-0.2, -0.3, 0.3], [0.6, 0.3, 0.3], [0.6, -0.4, 0.3],       # B: overlaps A, clockwise on screen
    [-0.9, 0.55, -0.2], [-0.55, 0.55, -0.2], [-0.7, 0.85, -0.2],  # C: apart
    [-0.2, -0.2, 5.0], [0.2, -0.2, 5.0], [0.0, 0.2, 5.0],       # D: behind the camera (z > 2)
])
NF = len(FACES)
VISIBLE = 3  # faces A, B, C have a polygon in front of the near plane


def camera():
    return gendr.OrthographicCamera(eye=(0.0, 0.0, 2.0), xmag=1.0, ymag=1.0, near=0.1, far=10.0)


def signed_distances(verts):
    """[VISIBLE, H, W] signed distance (inside > 0, either winding) of every pixel centre to the
    screen projection of faces A, B, C, float64 by brute force."""
    j, i = np.meshgrid(np.arange(W), np.arange(H))
    p = np.stack([2 * (j + 0.5) / W - 1, 1 - 2 * (i + 0.5) / H], -1)
    out = []
    for f in FACES[:VISIBLE]:
        tri = verts[f][:, :2]
        dist = np.full((H, W), np.inf)
        sides = []
        for k in range(3):
            s, e = tri[k], tri[(k + 1) % 3]
            ed = e - s
            t = np.clip(((p - s) @ ed) / (ed @ ed), 0, 1)
            q = p - (s + t[..., None] * ed)
            dist = np.minimum(dist, np.hypot(q[..., 0], q[..., 1]))
            sides.append(ed[0] * (p[..., 1] - s[1]) - ed[1] * (p[..., 0] - s[0]))
        sides = np.stack(sides)
        inside = np.all(sides > 0, 0) | np.all(sides < 0, 0)
        out.append(np.where(inside, dist, -dist))
    return np.stack(out)


def logistic_cdf(x):
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def batch_verts():
    """Two batch elements: the scene, and the scene shifted and scaled in the screen plane."""
    v2 = VERTS.copy()
    v2[:, :2] = 0.9 * v2[:, :2] + np.array([0.07, -0.04])
    return np.stack([VERTS, v2])


def render_alpha(backend, dist, tau, *, dtype=torch.float64, eps=0.0, blend=None, cutoff=None, verts=None):
    v = torch.tensor(batch_verts() if verts is None else verts, dtype=dtype)
    r = gendr.Renderer(dist, "average", tau=tau, image_size=(H, W), eps=eps, blend=blend, backend=backend,
                       cutoff=cutoff)
    img = r.render(v, torch.tensor(FACES), camera())
    out = np.asarray(r.to_numpy(img), np.float64)
    assert out.shape == (v.shape[0], H, W, 4)
    return out[..., 3]


def expected(dist_fn, eps=0.0, keep=None):
    """Σ over the visible faces of the kept coverages, / F (all 4 faces), per batch element."""
    out = []
    for verts in batch_verts():
        d = signed_distances(verts)
        p = dist_fn(d)
        k = p >= eps if keep is None else keep(d, p)
        out.append(np.where(k, p, 0.0).sum(0) / NF)
    return np.stack(out)


# ------------------------------------------------------------------------------------------------
# closed form
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("blend", [None, "softmax", "hard"], ids=str)
def test_closed_form_float64(backend, blend):
    tau = 0.06
    want = expected(lambda d: logistic_cdf(d / tau))
    got = render_alpha(backend, "logistic", tau, blend=blend)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    # the scene exercises overlaps (A + B > 1/4 somewhere) and F counts the face behind the camera
    assert want.max() > 0.4 and want.max() < 0.5 + 1e-12


@pytest.mark.parametrize("backend", BACKENDS)
def test_closed_form_float32(backend):
    tau = 0.06
    want = expected(lambda d: logistic_cdf(d / tau))
    got = render_alpha(backend, "logistic", tau, dtype=torch.float32)
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_closed_form_squared_with_eps_culling(backend):
    """Pairs with coverage < eps add 0 (and their face still counts in F)."""
    tau, eps = 0.004, 1e-3
    dist_fn = lambda d: logistic_cdf(d * np.abs(d) / tau)  # noqa: E731
    want = expected(dist_fn, eps=eps)
    got = render_alpha(backend, gendr.distribution("logistic", squared=True), tau, eps=eps)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    full = expected(dist_fn)
    assert np.abs(full - want).max() > 1e-6  # the culling is active on this scene


@pytest.mark.parametrize("backend", BACKENDS)
def test_closed_form_with_the_reference_cutoff(backend):
    """Outside pixels with d² >= cutoff·τ add 0 (cauchy: heavy-tailed, so the cut-off drops them)."""
    tau, cutoff = 0.05, 2.0
    want = expected(lambda d: 0.5 + np.arctan(d / tau) / math.pi,
                    keep=lambda d, p: (d >= 0) | (d * d < cutoff * tau))
    got = render_alpha(backend, "cauchy", tau, cutoff=cutoff)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("dist", ["heaviside", "uniform"])
def test_crisp_coverage_counts_faces_and_does_not_saturate(backend, dist):
    """p = 1 inside a face: A = (number of faces containing the pixel)/F, e.g. 2/4 where A and B
    overlap (an archimedean T-conorm would give 1 there)."""
    tau = 0.02
    d = np.stack([signed_distances(v) for v in batch_verts()])  # [B, 3, H, W]
    far = np.all(np.abs(d) > 2 * tau, axis=1)  # pixels away from every edge: p in {0, 1} exactly
    want = (d > 0).sum(1) / NF
    got = render_alpha(backend, dist, tau)
    np.testing.assert_array_equal(got[far], want[far])
    assert (want[far] == 0.5).sum() >= 8 and (want[far] == 0.25).sum() >= 50


@pytest.mark.parametrize("backend", BACKENDS)
def test_no_faces_and_one_face(backend):
    """F = 1: A = p; F = 0: A = 0 (no division by zero)."""
    tau = 0.06
    r = gendr.Renderer("logistic", "average", tau=tau, image_size=(H, W), eps=0.0, blend=None, backend=backend)
    img = r.render(torch.tensor(VERTS[:3]), torch.tensor(FACES[:1]), camera())
    np.testing.assert_allclose(np.asarray(r.to_numpy(img))[0, ..., 3], logistic_cdf(signed_distances(VERTS)[0] / tau),
                               rtol=1e-12, atol=1e-15)
    img = r.render(torch.tensor(VERTS), torch.zeros((0, 3), dtype=torch.int64), camera())
    assert np.asarray(r.to_numpy(img)).max() == 0.0


# ------------------------------------------------------------------------------------------------
# Dr.Jit against torch (the parity scene and tolerances of test_drjit_parity.py)
# ------------------------------------------------------------------------------------------------
PARITY = [
    ("logistic", {}, None, "perspective", None, 1e-3),
    ("logistic", {}, "softmax", "orbit", "vertex", 0.0),
    ("gaussian", {"squared": True}, "hard", "intrinsics", "face", 1e-3),
    ("cauchy", {}, None, "orthographic", None, 1e-3),
    ("exponential", {"reversed": True}, "softmax", "perspective", "face", 1e-3),
    ("gamma", {"shape": 2.0, "reversed": True}, None, "orbit", None, 0.0),
    ("uniform", {}, None, "perspective", None, 1e-3),
    ("levy", {"reversed": True, "squared": True}, None, "intrinsics", None, 1e-3),
]


@needs_drjit
@pytest.mark.parametrize("case", PARITY, ids=[f"{c[0]}{c[1]}|{c[2]}|{c[3]}|eps={c[5]}" for c in PARITY])
def test_drjit_matches_torch_f64(case):
    from test_drjit_parity import assert_parity_f64
    dn, dkw, blend, cam, colors, eps = case
    assert_parity_f64(gendr.distribution(dn, **dkw), gendr.tconorm("average"), blend=blend, camera=cam,
                      colors=colors, eps=eps)


@needs_drjit
def test_drjit_matches_torch_with_a_cutoff_f64():
    from test_drjit_parity import F64_TOL, run
    d, t = gendr.distribution("cauchy"), gendr.tconorm("average")
    ref, got, full = run("torch", d, t, cutoff=0.5), run("drjit", d, t, cutoff=0.5), run("torch", d, t)
    assert float((ref[0] - full[0]).abs().max()) > 1e-4  # the cut-off is active on this scene
    assert float((ref[0] - got[0]).abs().max()) <= F64_TOL
    for k, g in ref[1].items():
        assert float((g - got[1][k]).abs().max()) <= F64_TOL * max(1.0, float(g.abs().max())), k


@needs_drjit
@pytest.mark.parametrize("blend", [None, "softmax"], ids=str)
def test_drjit_float32(blend):
    """Dr.Jit float32 against torch float64 and torch float32 (test_drjit_parity's float32 tolerances)."""
    from test_drjit_parity import (F32_FWD_VS_F64, F32_FWD_VS_TORCH32, F32_GRAD_VS_F64, F32_GRAD_VS_TORCH32,
                                   compare, run)
    dist, tcn = gendr.distribution("logistic"), gendr.tconorm("average")
    colors = "vertex" if blend else None
    d32 = run("drjit", dist, tcn, dtype=torch.float32, blend=blend, colors=colors)
    fwd, bwd, scale = compare(d32, run("torch", dist, tcn, blend=blend, colors=colors))
    assert fwd <= F32_FWD_VS_F64
    for k, e in bwd.items():
        assert e <= F32_GRAD_VS_F64 * scale[k] + 1e-5, f"float32 gradient w.r.t. {k} vs float64: {e:.3g}"
    if blend is None:
        fwd, bwd, scale = compare(d32, run("torch", dist, tcn, dtype=torch.float32))
        assert fwd <= F32_FWD_VS_TORCH32
        for k, e in bwd.items():
            assert e <= F32_GRAD_VS_TORCH32 * max(scale[k], 1e-3), f"float32 gradient w.r.t. {k} vs torch: {e:.3g}"


@needs_drjit
@pytest.mark.parametrize("mode", ["frozen", "generic"])
def test_drjit_frozen_and_generic_backward(mode, monkeypatch):
    """The frozen renderer (replayed with new vertices) and Dr.Jit's generic reverse-mode sum loop
    (CUSTOM_BACKWARD = False) give the torch backend's images and gradients."""
    import gendr_drjit.raster as R
    from test_drjit_parity import F64_TOL, run
    d, t = gendr.distribution("gaussian"), gendr.tconorm("average")
    kw = {"freeze": True} if mode == "frozen" else {}
    if mode == "generic":
        monkeypatch.setattr(R, "CUSTOM_BACKWARD", False)
    for scale in (1.0, 1.05):  # (the second call replays the frozen function)
        from test_renderer_reference import scene_vertices
        verts = scene_vertices() * scale
        ref, got = run("torch", d, t, verts=verts), run("drjit", d, t, verts=verts, **kw)
        assert float((ref[0] - got[0]).abs().max()) <= F64_TOL
        for k, g in ref[1].items():
            assert float((g - got[1][k]).abs().max()) <= F64_TOL, k


# ------------------------------------------------------------------------------------------------
# finite differences
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", BACKENDS)
def test_gradients_match_central_differences(backend):
    """d/dθ of Σ w·alpha along random vertex directions and for τ, float64 central differences.
    eps = 0 (the eps mask is a discontinuity); logistic has no kinks."""
    tau0 = 0.06
    V = torch.tensor(batch_verts())
    w = torch.linspace(-1, 1, 2 * H * W, dtype=torch.float64).reshape(2, H, W)

    def f(v, tau):
        r = gendr.Renderer("logistic", "average", tau=tau, image_size=(H, W), eps=0.0, blend=None, backend=backend)
        return (r.render(v, torch.tensor(FACES), camera())[..., 3] * w).sum()

    v = V.clone().requires_grad_(True)
    tau = torch.tensor(tau0, dtype=torch.float64, requires_grad=True)
    gv, gt = torch.autograd.grad(f(v, tau), [v, tau])
    assert float(gv.abs().max()) > 0 and float(gt.abs()) > 0
    h = 1e-6
    gen = torch.Generator().manual_seed(0)
    for _ in range(3):
        u = torch.randn(V.shape, generator=gen, dtype=torch.float64)
        fd = float(f(V + 0.5 * h * u, tau0) - f(V - 0.5 * h * u, tau0)) / h
        ad = float((gv * u).sum())
        assert abs(ad - fd) <= 1e-6 * max(1.0, abs(fd)), f"AD {ad:.10g} vs FD {fd:.10g}"
    fd = float(f(V, tau0 + 0.5 * h) - f(V, tau0 - 0.5 * h)) / h
    assert abs(float(gt) - fd) <= 1e-6 * max(1.0, abs(fd)), f"dτ: AD {float(gt):.10g} vs FD {fd:.10g}"


# ------------------------------------------------------------------------------------------------
# selection, errors, listing
# ------------------------------------------------------------------------------------------------
def test_selection_by_name_object_and_experiment_config():
    t = gendr.tconorm("average")
    assert not t.is_tconorm and gendr.Renderer("logistic", "average").settings.tconorm == t
    assert "average" in repr(gendr.Renderer("logistic", t))
    pytest.importorskip("gendr_experiments")
    from gendr_experiments.common import instance_from_config
    d, t2, label = instance_from_config({"distribution": "logistic", "tconorm": "average"})
    assert t2 == t and label == "logistic|average"
    assert instance_from_config({"tconorm": {"name": "average"}})[1] == t


def test_typed_errors():
    with pytest.raises(ParameterError, match="tconorm 'average' got unexpected parameter 'p'"):
        gendr.tconorm("average", p=2.0)
    with pytest.raises(ParameterError, match="parameters cannot be combined"):
        gendr.tconorm(gendr.tconorm("average"), p=1.0)
    with pytest.raises(UnknownNameError) as e:
        gendr.Renderer("logistic", "mean_of_faces")
    assert "average" in str(e.value)


def test_not_in_the_paper_grid_and_listed_apart(capsys):
    grid = gendr.paper_grid()
    assert len(grid) == 1242 and not any(i.tconorm.name == "average" for i in grid)
    from gendr.cli import main
    assert main(["list", "tconorms"]) == 0
    out = capsys.readouterr().out
    head, _, tail = out.partition("not T-conorms")
    assert "average" not in head and "probabilistic" in head
    assert "average" in tail and "not a T-conorm" in tail and "probabilistic" not in tail
