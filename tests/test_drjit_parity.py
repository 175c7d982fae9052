"""The Dr.Jit backend against the torch backend (same scene as test_renderer_reference.py).

float64: images and gradients (vertices, τ, camera parameters, colours) agree to F64_TOL absolute:
the two backends evaluate the same spec formulas, so only rounding differs (measured ~4e-12).
float32: both backends are float32 approximations of the same float64 function, and for some
ill-conditioned instances (gamma shape 0.5 with aczel_alsina p=4, frank/hamacher with heavy tails)
torch's own float32 gradients are 1e-4..3e-4 (relative to the largest) away from float64. So the
Dr.Jit float32 result is checked against the float64 torch reference with the tolerances the torch
backend's own tests use (forward 2e-5, gradients 1e-3·max + 1e-5), and against torch float32 directly
(forward 1e-5 absolute, gradients 1e-4 relative to the largest) on well-conditioned instances.
Instances with a kink that float32 rounding can move a pixel across (yager p = 1: A = min(1, Σp)
switches its gradient off exactly at Σp = 1) are left out of the float32 cases.

Inputs are torch tensors (the dr.wrap path, gradients flow into torch) unless a test says otherwise.
Default run: every distribution setting of the paper's grid (plain and squared, T-conorm rotating),
every T-conorm setting (distribution rotating), every blend × camera × colour kind, batches, NumPy
and Dr.Jit inputs. ``pytest -m slow`` adds the whole paper grid (1,242 instances) in float64.
"""
from __future__ import annotations

import numpy as np
import pytest

dr = pytest.importorskip("drjit", reason="the Dr.Jit backend needs drjit (pip install gendr[drjit])")
torch = pytest.importorskip("torch")

import gendr  # noqa: E402
from gendr.scenes import icosphere  # noqa: E402
from gendr.grid import DISTRIBUTION_SETTINGS, TCONORM_SETTINGS  # noqa: E402
from test_renderer_reference import (FACES, FACES_SOFTMAX, ZERO_AREA, H, W, face_colors, make_camera,  # noqa: E402
                                     scene_vertices, vertex_colors)

F64_TOL = 1e-9
F32_FWD_VS_F64, F32_GRAD_VS_F64 = 2e-5, 1e-3
F32_FWD_VS_TORCH32, F32_GRAD_VS_TORCH32 = 1e-5, 1e-4
# float32's own rounding floor on this scene, for checks of one backend's float32 error against the
# other's: forward ~3e-7, gradients up to 3.6e-6 of the largest (sums of ~10^3 pixel terms in
# another order), measured when the near-clipped face's float32 error fell to that floor (it was
# ~3e-4 of the gradients, shared by both backends, before its edges were measured from their
# nearer corners: docs/conventions.md, near-plane clipping)
F32_FLOOR_FWD, F32_FLOOR_GRAD = 1e-6, 1e-5


def _tau0(dist):
    return 0.012 if dist.squared else 0.1


def run(backend, dist, tcn, *, dtype=torch.float64, blend=None, eps=1e-3, camera="perspective", colors=None,
        faces=None, verts=None, tau=None, **kw):
    """(image, {name: gradient}) of (image * fixed_randn).sum() w.r.t. every input."""
    faces = (FACES_SOFTMAX if blend == "softmax" else FACES) if faces is None else faces
    v = (scene_vertices() if verts is None else verts).to(dtype).requires_grad_(True)
    tau = torch.tensor(_tau0(dist) if tau is None else tau, dtype=dtype, requires_grad=True)
    cam, params = make_camera(camera, dtype)
    ckw = {}
    if colors == "vertex":
        ckw["vertex_colors"] = vertex_colors(dtype).requires_grad_(True)
    elif colors == "face":
        ckw["face_colors"] = face_colors(dtype)[:faces.shape[0]].requires_grad_(True)
    r = gendr.Renderer(dist, tcn, tau=tau, image_size=(H, W), eps=eps, blend=blend, backend=backend, **kw)
    img = r.render(v, faces, cam, **ckw)
    assert isinstance(img, torch.Tensor) and img.dtype == dtype and img.shape == (2, H, W, 4)
    inputs = {"vertices": v, "tau": tau, **params, **ckw}
    w = torch.randn(img.shape, generator=torch.Generator().manual_seed(7), dtype=torch.float64).to(dtype)
    if img.requires_grad:
        grads = torch.autograd.grad((img * w).sum(), list(inputs.values()), allow_unused=True)
    else:
        grads = [None] * len(inputs)
    out = {}
    for (k, x), g in zip(inputs.items(), grads):
        g = torch.zeros_like(x) if g is None else g
        if k == "vertices":  # the zero-area face's own vertices: a kink (see test_renderer_reference)
            g = g[..., :ZERO_AREA.start, :]
        out[k] = g.detach().double()
    return img.detach().double(), out


def compare(a, b):
    """(max |forward difference|, {name: max |gradient difference|}, {name: max |reference gradient|})."""
    (ia, ga), (ib, gb) = a, b
    assert torch.isfinite(ia).all() and all(torch.isfinite(g).all() for g in ga.values())
    return (float((ia - ib).abs().max()), {k: float((ga[k] - gb[k]).abs().max()) for k in gb},
            {k: float(gb[k].abs().max()) for k in gb})


def assert_parity_f64(dist, tcn, **kw):
    fwd, bwd, _ = compare(run("drjit", dist, tcn, **kw), run("torch", dist, tcn, **kw))
    assert fwd <= F64_TOL, f"forward differs by {fwd:.3g}"
    for k, e in bwd.items():
        assert e <= F64_TOL, f"gradient w.r.t. {k} differs by {e:.3g}"


def _dist(setting, squared=False):
    name, params, rev = setting
    return gendr.distribution(name, reversed=rev, squared=squared, **params)


def _tcn(setting):
    return gendr.tconorm(setting[0], **setting[1])


def _id(x):
    return x.label() if hasattr(x, "label") else str(x)


# --- the representative subset of the paper grid ---------------------------------------------------
DIST_CASES = [(_dist(s, sq), _tcn(TCONORM_SETTINGS[(2 * i + sq) % len(TCONORM_SETTINGS)]))
              for i, s in enumerate(DISTRIBUTION_SETTINGS) for sq in (False, True)]
TCONORM_CASES = [(_dist(DISTRIBUTION_SETTINGS[(3 * i) % len(DISTRIBUTION_SETTINGS)], i % 2 == 1), _tcn(s))
                 for i, s in enumerate(TCONORM_SETTINGS)]


@pytest.mark.parametrize("dist,tcn", DIST_CASES, ids=[f"{d.label()}|{t.label()}" for d, t in DIST_CASES])
def test_every_distribution_setting_f64(dist, tcn):
    assert_parity_f64(dist, tcn)


@pytest.mark.parametrize("dist,tcn", TCONORM_CASES, ids=[f"{d.label()}|{t.label()}" for d, t in TCONORM_CASES])
def test_every_tconorm_setting_f64(dist, tcn):
    assert_parity_f64(dist, tcn, eps=0.0 if tcn.name == "max" else 1e-3)


@pytest.mark.parametrize("camera", ["perspective", "orthographic", "intrinsics", "orbit"])
@pytest.mark.parametrize("blend", ["softmax", "hard"])
def test_blends_cameras_colours_f64(blend, camera):
    colors = "face" if camera in ("intrinsics", "orbit") else "vertex"
    assert_parity_f64(gendr.distribution("logistic"), gendr.tconorm("probabilistic"), blend=blend, camera=camera,
                      colors=colors, light_direction=(-0.6, 0.5, -1.0))


@pytest.mark.parametrize("blend", ["softmax", "hard"])
def test_cull_backfaces_no_colours_f64(blend):
    assert_parity_f64(gendr.distribution("gaussian", squared=True), gendr.tconorm("einstein"), blend=blend,
                      cull_backfaces=True, background=(0.2, 0.3, 0.4))


F32_CASES = [("logistic", {}, "probabilistic", {}), ("logistic", {"squared": True}, "probabilistic", {}),
             ("gaussian", {}, "max", {}), ("gamma", {"shape": 0.5}, "aczel_alsina", {"p": 4.0}),
             ("gamma", {"shape": 3.0, "reversed": True}, "frank", {"p": 0.1}),
             ("exponential", {"reversed": True}, "yager", {"p": 2.0}), ("laplace", {}, "hamacher", {"p": 0.5}),
             ("cauchy", {"squared": True}, "dombi", {"p": 4.0}), ("levy", {"reversed": True}, "schweizer_sklar", {"p": -4.0}),
             ("wigner_semicircle", {}, "einstein", {}), ("heaviside", {}, "or", {})]
WELL_CONDITIONED = {0, 1, 2, 10}


@pytest.mark.parametrize("i", range(len(F32_CASES)), ids=[f"{c[0]}{c[1]}|{c[2]}{c[3]}" for c in F32_CASES])
def test_float32(i):
    dn, dkw, tn, tkw = F32_CASES[i]
    dist, tcn = gendr.distribution(dn, **dkw), gendr.tconorm(tn, **tkw)
    d32 = run("drjit", dist, tcn, dtype=torch.float32)
    fwd, bwd, scale = compare(d32, run("torch", dist, tcn))
    assert fwd <= F32_FWD_VS_F64, f"float32 forward vs float64 reference: {fwd:.3g}"
    for k, e in bwd.items():
        assert e <= F32_GRAD_VS_F64 * scale[k] + 1e-5, f"float32 gradient w.r.t. {k} vs float64: {e:.3g} (max {scale[k]:.3g})"
    if i in WELL_CONDITIONED:
        fwd, bwd, scale = compare(d32, run("torch", dist, tcn, dtype=torch.float32))
        assert fwd <= F32_FWD_VS_TORCH32, f"float32 forward vs torch float32: {fwd:.3g}"
        for k, e in bwd.items():
            assert e <= F32_GRAD_VS_TORCH32 * max(scale[k], 1e-3), f"float32 gradient w.r.t. {k} vs torch: {e:.3g}"


@pytest.mark.parametrize("dist", ["logistic", "cauchy", "reciprocal", "reversed cauchy"])
@pytest.mark.parametrize("tcn", ["probabilistic", "einstein", "hamacher(0.5)"])
@pytest.mark.parametrize("tau", [0.1, 1e-3])
def test_odds_product_where_faces_overlap_and_odds_overflow(tau, tcn, dist):
    """The distributions with closed-form odds (logistic e^x; Cauchy, reciprocal: one division)
    with probabilistic, einstein, hamacher(0.5): the Dr.Jit loops sum log Π(1 + c·odds)
    (raster.alpha_sums' odds product, capped at 2^100), torch sums the generator of each pair
    (log1p(c·p/(1 − p)) from log(1 − p)). At τ = 0.1 soft faces overlap widely; at τ = 1e-3 pixels
    lie up to hundreds of τ inside the faces, where the logistic's e^x overflows to inf and the
    product meets its cap (alpha exactly 1). float64: to F64_TOL. float32: x = d/τ turns the
    rounding of d into errors 100× those at τ = 0.1 (torch's own float32 forward is 3e-5 off at
    1e-3), so Dr.Jit's float32 error is held to torch float32's (a sum of logs) + 10 %."""
    dist = gendr.distribution("cauchy", reversed=True) if dist == "reversed cauchy" else gendr.distribution(dist)
    tcn = gendr.tconorm("hamacher", p=0.5) if tcn == "hamacher(0.5)" else gendr.tconorm(tcn)
    assert dist.has_odds and tcn.odds_product_factor() is not None  # the path under test
    _matches_torch_sum_of_generators(dist, tcn, tau, saturates=dist.family.name == "logistic")



@pytest.mark.parametrize("p", [1e28, 1e31, 2.0 ** 40])
def test_hamacher_large_p_one_face_alpha_is_its_coverage(p):
    """One face: every T-conorm's aggregate is the face's coverage. The odds product's cap 2^100
    saturated Hamacher's Q/(Q + p) to alpha 1 where p/Q was not negligible: p = 1e28 rendered 1 at
    coverage 0.9953, 1e31 at 0.16. Beyond ODDS_FACTOR_MAX = 2^40 the generator loop runs instead;
    at 2^40 itself the product stays exact. float64, to F64_TOL."""
    V = torch.tensor([[-0.5, -0.4, 0.0], [0.6, -0.3, 0.1], [0.0, 0.5, -0.1]], dtype=torch.float64)
    cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=40.0)
    cover = gendr.Renderer("logistic", "max", tau=0.01, image_size=10, blend=None, backend="torch")
    want = cover.render(V, np.array([[0, 1, 2]]), cam)[..., 3]
    r = gendr.Renderer("logistic", gendr.tconorm("hamacher", p=p), tau=0.01, image_size=10, blend=None,
                       backend="drjit")
    got = r.render(V, np.array([[0, 1, 2]]), cam)[..., 3]
    assert float((got - want).abs().max()) <= F64_TOL

@pytest.mark.parametrize("dist", ["logistic", "cauchy", "reciprocal", "reversed logistic"])
@pytest.mark.parametrize("p", [0.5, 2.0])
@pytest.mark.parametrize("tau", [0.1, 1e-3])
def test_dombi_from_the_log_odds(tau, p, dist):
    """Dombi's generator (x/(1 − x))^p evaluated by the Dr.Jit loops as exp(p·log odds) from the
    distribution's closed-form log-odds (the logistic's: x), torch from F and log(1 − F): the same
    checks as the odds product's (at τ = 1e-3 the logistic's e^(p·x) overflows inside the faces,
    which saturates them)."""
    dist = gendr.distribution("logistic", reversed=True) if dist == "reversed logistic" else gendr.distribution(dist)
    tcn = gendr.tconorm("dombi", p=p)
    assert dist.has_odds and tcn.family.odds_generator is not None  # the path under test
    _matches_torch_sum_of_generators(dist, tcn, tau, saturates=dist.family.name == "logistic")


def _matches_torch_sum_of_generators(dist, tcn, tau, saturates):
    ref = run("torch", dist, tcn, tau=tau)
    alpha = ref[0][..., 3]
    assert ((alpha > 1e-3) & (alpha < 0.999)).any()
    assert tau > 0.01 or not saturates or (alpha == 1.0).any()
    fwd, bwd, _ = compare(run("drjit", dist, tcn, tau=tau), ref)
    assert fwd <= F64_TOL, f"forward differs by {fwd:.3g}"
    for k, e in bwd.items():
        assert e <= F64_TOL, f"gradient w.r.t. {k} differs by {e:.3g}"
    fwd, bwd, scale = compare(run("drjit", dist, tcn, tau=tau, dtype=torch.float32), ref)
    fwd_t, bwd_t, _ = compare(run("torch", dist, tcn, tau=tau, dtype=torch.float32), ref)
    assert fwd <= 1.1 * fwd_t + F32_FLOOR_FWD, f"float32 forward vs float64 reference: {fwd:.3g} (torch float32: {fwd_t:.3g})"
    for k, e in bwd.items():
        assert e <= 1.1 * bwd_t[k] + F32_FLOOR_GRAD * scale[k], \
            f"float32 gradient w.r.t. {k}: {e:.3g} (torch: {bwd_t[k]:.3g})"


def test_float32_rgb_softmax():
    dist, tcn = gendr.distribution("logistic"), gendr.tconorm("probabilistic")
    fwd, bwd, scale = compare(run("drjit", dist, tcn, dtype=torch.float32, blend="softmax", colors="vertex"),
                              run("torch", dist, tcn, blend="softmax", colors="vertex"))
    assert fwd <= F32_FWD_VS_F64
    for k, e in bwd.items():
        assert e <= F32_GRAD_VS_F64 * scale[k] + 1e-5, k


def test_batched_camera_f64():
    """A batch of orbit views of one (unbatched) mesh: camera batch 3, vertices [V, 3]."""
    outs = []
    for be in ("drjit", "torch"):
        az = torch.tensor([0.0, 25.0, -40.0], dtype=torch.float64, requires_grad=True)
        v = scene_vertices()[0].clone().requires_grad_(True)
        cam = gendr.orbit_camera(az, 10.0, 3.2)
        r = gendr.Renderer("logistic", gendr.tconorm("yager", p=2.0), tau=0.1, image_size=(H, W), backend=be,
                           blend="softmax")
        img = r.render(v, FACES_SOFTMAX, cam, vertex_colors=vertex_colors())
        assert img.shape == (3, H, W, 4)
        w = torch.randn(img.shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
        gv, ga = torch.autograd.grad((img * w).sum(), [v, az])
        outs.append((img.detach(), gv, ga))
    for a, b in zip(*outs):
        assert float((a - b).abs().max()) <= F64_TOL


# --- other input kinds ------------------------------------------------------------------------------
def test_numpy_inputs_give_a_drjit_tensor_of_the_vertices_dtype():
    for dt, tt in ((np.float32, torch.float32), (np.float64, torch.float64)):
        v = scene_vertices().numpy().astype(dt)
        cam = gendr.PerspectiveCamera(eye=(0.1, 0.05, 3.0))
        r = gendr.Renderer("logistic", "probabilistic", tau=0.1, image_size=(H, W), backend="drjit", blend="softmax")
        img = r.render(v, FACES_SOFTMAX.numpy(), cam, vertex_colors=vertex_colors().numpy())
        assert dr.is_tensor_v(img) and img.shape == (2, H, W, 4)
        assert dr.type_v(img) == (dr.VarType.Float32 if dt == np.float32 else dr.VarType.Float64)
        ref = gendr.Renderer("logistic", "probabilistic", tau=0.1, image_size=(H, W), blend="softmax").render(
            torch.tensor(v), FACES_SOFTMAX, cam, vertex_colors=vertex_colors().to(tt))
        out = r.to_numpy(img)
        assert isinstance(out, np.ndarray) and out.dtype == dt
        # (float32: softmax with γ = 1e-4 amplifies depth rounding 1e4-fold; both backends are float32 here)
        assert np.abs(out - ref.numpy()).max() <= (2e-4 if dt == np.float32 else F64_TOL)


def _torch_reference(w_seed=3):
    v_t = scene_vertices().requires_grad_(True)
    tau_t = torch.tensor(0.1, dtype=torch.float64, requires_grad=True)
    cam_t, P = make_camera("perspective")
    img_t = gendr.Renderer("gaussian", "einstein", tau=tau_t, image_size=(H, W), blend=None).render(v_t, FACES, cam_t)
    w = torch.randn(img_t.shape, generator=torch.Generator().manual_seed(w_seed), dtype=torch.float64)
    gv, gt, ge, gf = torch.autograd.grad((img_t * w).sum(), [v_t, tau_t, P["eye"], P["fov_y"]])
    return img_t.detach(), w, gv, gt, ge, gf


def test_drjit_inputs_gradients_through_drjit():
    """Dr.Jit tensors in (vertices, camera eye as a tensor, fov_y as an Array of width 1): a Dr.Jit
    tensor out, AD through Dr.Jit."""
    from drjit.llvm.ad import Float64, TensorXf64
    img_t, w, gv, _, ge, gf = _torch_reference()
    v = TensorXf64(scene_vertices().numpy())
    eye = TensorXf64(np.array([0.1, 0.05, 3.0]))
    fov = Float64(40.0)
    for x in (v, eye, fov):
        dr.enable_grad(x)
    r = gendr.Renderer("gaussian", "einstein", tau=0.1, image_size=(H, W), blend=None, backend="drjit")
    img = r.render(v, FACES.numpy(), gendr.PerspectiveCamera(eye=eye, fov_y=fov))
    assert dr.is_tensor_v(img) and img.shape == (2, H, W, 4)
    assert np.abs(img.numpy() - img_t.numpy()).max() <= F64_TOL
    dr.backward(dr.sum((img * TensorXf64(w.numpy())).array))
    assert np.abs(dr.grad(v).numpy() - gv.numpy()).max() <= F64_TOL
    assert np.abs(dr.grad(eye).numpy() - ge.numpy()).max() <= F64_TOL
    assert abs(float(dr.grad(fov).numpy()[0]) - float(gf)) <= F64_TOL


def test_drjit_tau_tensor():
    from drjit.llvm.ad import TensorXf64
    img_t, w, _, gt, _, _ = _torch_reference()
    tau = TensorXf64(np.array(0.1))
    dr.enable_grad(tau)
    r = gendr.Renderer("gaussian", "einstein", tau=tau, image_size=(H, W), blend=None, backend="drjit")
    img = r.render(scene_vertices().numpy(), FACES.numpy(), gendr.PerspectiveCamera(eye=(0.1, 0.05, 3.0)))
    dr.backward(dr.sum((img * TensorXf64(w.numpy())).array))
    assert abs(float(dr.grad(tau).numpy()) - float(gt)) <= F64_TOL


def test_torch_training_loop_switches_backend_with_one_argument():
    """A few Adam steps on the vertices give the same trajectory with either backend."""
    target = gendr.Renderer("logistic", "probabilistic", tau=0.1, image_size=(H, W), blend=None).render(
        scene_vertices() * 1.1, FACES, gendr.PerspectiveCamera()).detach()
    finals = []
    for be in ("torch", "drjit"):
        v = scene_vertices().clone().requires_grad_(True)
        opt = torch.optim.Adam([v], lr=0.01)
        r = gendr.Renderer("logistic", "probabilistic", tau=0.1, image_size=(H, W), blend=None, backend=be)
        for _ in range(5):
            opt.zero_grad()
            loss = ((r.render(v, FACES, gendr.PerspectiveCamera()) - target) ** 2).sum()
            loss.backward()
            opt.step()
        finals.append(v.detach())
    assert float((finals[0] - finals[1]).abs().max()) <= 1e-9


# --- the whole grid (slow) ----------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(gendr.paper_grid())))
def test_paper_grid_f64(index):
    inst = gendr.paper_grid()[index]
    assert_parity_f64(inst.distribution, inst.tconorm, eps=1e-3)


def test_mixed_input_dtypes_follow_the_vertices():
    """float32 vertices with float64 τ, camera parameters and integer colours: a float32 image,
    gradients into every torch input in its own dtype."""
    v = scene_vertices(torch.float32).requires_grad_(True)
    tau = torch.tensor(0.1, dtype=torch.float64, requires_grad=True)
    cam, P = make_camera("orbit", torch.float64)
    cols = torch.randint(0, 2, (FACES_SOFTMAX.shape[0], 3))
    r = gendr.Renderer("logistic", "probabilistic", tau=tau, image_size=(H, W), backend="drjit")
    img = r.render(v, FACES_SOFTMAX, cam, face_colors=cols)
    assert img.dtype == torch.float32
    img.sum().backward()
    assert v.grad.dtype == torch.float32 and tau.grad.dtype == torch.float64
    assert all(torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0 for x in (v, tau, *P.values()))
    ref = gendr.Renderer("logistic", "probabilistic", tau=0.1, image_size=(H, W)).render(
        scene_vertices(), FACES_SOFTMAX, make_camera("orbit")[0], face_colors=cols.double())
    assert float((img.detach().double() - ref.detach()).abs().max()) <= 2e-4


# --- Lambert's kink on a symmetric mesh (regression) ---------------------------------------------
# An icosphere under the default light (0, 0, −1): its 16 vertices on the z = 0 equator have normals
# with n·(−l) = 0 up to the rounding of the vertex-normal sums (±1e-18 here), whose sign depends on
# the summation order, which differs between the backends (torch index_add, face-major; Dr.Jit
# scatter_reduce, corner-major). Each backend's clamp max(0, n·(−l)) then took a different one-sided
# derivative there: vertex gradients differed by up to 5.6 (softmax, logistic), 10.4 (cauchy) and 8.4
# (hard) with |grad| ~ 130, images agreeing to 1e-14. Both now snap |n·(−l)| <= LAMBERT_KINK_ULPS·eps
# to exactly 0, where the gradient passes (gendr.renderer.LAMBERT_KINK_ULPS).
# (cauchy with the softmax blend also differed, by 10.4, but its infinite culling radius makes it ~30 s here)
KINK_CASES = [("softmax", gendr.distribution("logistic"), 0.01), ("hard", gendr.distribution("cauchy", squared=True), 1e-4)]


def _icosphere_grad(backend, blend, dist, tau, dtype=torch.float64, **kw):
    m = icosphere(2)
    v = torch.tensor(m.vertices, dtype=dtype, requires_grad=True)
    r = gendr.Renderer(dist, "probabilistic", tau=tau, image_size=48, blend=blend, gamma=1e-2, backend=backend, **kw)
    img = r.render(v, torch.tensor(m.faces), gendr.orbit_camera(30.0, 20.0, 3.0))
    w = torch.linspace(0, 1, img.numel(), dtype=torch.float64).reshape(img.shape).to(dtype)
    (img * w).sum().backward()
    return img.detach(), v.grad


@pytest.mark.parametrize("blend,dist,tau", KINK_CASES, ids=[f"{b}|{d.label()}" for b, d, _ in KINK_CASES])
def test_lambert_kink_icosphere_f64(blend, dist, tau):
    (it, gt), (id_, gd) = (_icosphere_grad(be, blend, dist, tau) for be in ("torch", "drjit"))
    assert float((it - id_).abs().max()) <= F64_TOL
    err = float((gt - gd).abs().max())
    assert err <= F64_TOL, f"vertex gradients differ by {err:.3g} (max |grad| {float(gt.abs().max()):.3g})"


def test_lambert_kink_icosphere_f32():
    """Dr.Jit float32 against the torch float64 reference (the float32 tolerances above)."""
    blend, dist, tau = KINK_CASES[0]
    (i64, g64), (i32, g32) = _icosphere_grad("torch", blend, dist, tau), _icosphere_grad("drjit", blend, dist, tau, torch.float32)
    assert float((i32.double() - i64).abs().max()) <= F32_FWD_VS_F64
    err, scale = float((g32.double() - g64).abs().max()), float(g64.abs().max())
    assert err <= F32_GRAD_VS_F64 * scale + 1e-5, f"float32 vertex gradients vs float64: {err:.3g} (max {scale:.3g})"


def test_icosphere_softmax_gradients_match_finite_differences():
    """The softmax blend's vertex gradients on the icosphere, both backends, against float64 central
    differences along random directions. A light in general position (no vertex on Lambert's kink,
    where central differences average the two one-sided derivatives) and eps = 0 (the eps mask is a
    discontinuity: a pair crossing it within the step would swamp the difference quotient)."""
    m = icosphere(2)
    V, F, cam = torch.tensor(m.vertices), torch.tensor(m.faces), gendr.orbit_camera(30.0, 20.0, 3.0)
    w = torch.linspace(0, 1, 24 * 24 * 4, dtype=torch.float64).reshape(1, 24, 24, 4)
    gen = torch.Generator().manual_seed(0)
    dirs = [torch.randn(V.shape, generator=gen, dtype=torch.float64) for _ in range(2)]
    h = 1e-6  # truncation ~h²·|f'''| (τ = 0.01) and rounding ~1e-16·|f|/h: both far below the tolerance
    for be in ("torch", "drjit"):
        r = gendr.Renderer("logistic", "probabilistic", tau=0.01, image_size=24, blend="softmax", gamma=1e-2,
                           backend=be, eps=0.0, light_direction=(0.1, 0.2, -1.0))
        v = V.clone().requires_grad_(True)
        (r.render(v, F, cam) * w).sum().backward()
        for u in dirs:
            fd = float(((r.render(V + h * u, F, cam) - r.render(V - h * u, F, cam)) * w).sum()) / (2 * h)
            ad = float((v.grad * u).sum())
            assert abs(ad - fd) <= 1e-6 * max(1.0, abs(fd)), f"{be}: AD {ad:.10g} vs FD {fd:.10g}"


def test_exact_ties_go_to_the_lowest_face():
    """Two coincident copies of a triangle (own vertices, different albedo): exact ties of depth
    (hard z-buffer) and of coverage (max T-conorm) go to the lower face index in both backends, as
    in the naive reference: face 0's colour, and the max's gradient on face 0's vertices only."""
    tri = torch.tensor([[-0.6, -0.5, 0.0], [0.6, -0.5, 0.0], [0.0, 0.6, 0.0]], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 2], [3, 4, 5]])
    albedo = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    cam = gendr.PerspectiveCamera(eye=(0.05, 0.02, 3.0), fov_y=40.0)
    for be in ("torch", "drjit"):
        v = torch.cat([tri, tri]).requires_grad_(True)
        r = gendr.Renderer("logistic", "max", tau=0.05, image_size=(16, 20), eps=1e-3, blend="hard", backend=be)
        img = r.render(v, faces, cam, face_colors=albedo)
        rgb = img.detach()[0]
        covered = rgb[..., 3] > 0.5
        assert int(covered.sum()) > 20
        assert float(rgb[..., 0][covered].min()) > 0.0 and float(rgb[..., 2][covered].abs().max()) == 0.0, be
        img[..., 3].sum().backward()
        assert float(v.grad[:3].abs().max()) > 0.0 and float(v.grad[3:].abs().max()) == 0.0, be


def _two_small_faces():
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    verts = torch.tensor([[-0.5, -0.4, 0.0], [0.6, -0.3, 0.1], [0.0, 0.5, -0.1],
                          [-0.2, -0.1, 0.3], [0.4, 0.1, 0.3], [0.1, 0.6, 0.2]], dtype=torch.float64)
    return verts, faces, torch.as_tensor(np.random.default_rng(0).random((6, 3)))


def test_softmax_with_tiny_coverages_matches_finite_differences():
    """eps = 0 and τ = 1e-3: far from both faces every coverage is tiny (~1e-170) and the background
    weight underflows, so the softmax denominator was ~1e-170 and Dr.Jit's −a/b² derivative of the
    ratio overflowed: dτ NaN, vertex gradients 40 % off (-3.01 against -5.00), no error. The
    denominator is still that small (m = max(ε, z̃)); Dr.Jit now differentiates the ratio q = a/den
    as (da − q·dden)/den, which never squares den (torch's own division backward already did the
    same). Central differences with a 1e-6
    relative step; the tolerance 1e-5 relative is ~100x their round-off here."""
    verts, faces, cols = _two_small_faces()
    cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=40.0)
    weight = torch.as_tensor(np.random.default_rng(1).standard_normal((1, 12, 12, 4)))
    direction = torch.as_tensor(np.random.default_rng(3).standard_normal((6, 3)))

    def loss(backend, v, tau):
        r = gendr.Renderer("logistic", "probabilistic", tau=tau, image_size=12, eps=0.0, backend=backend)
        return (r.render(v, faces, cam, vertex_colors=cols) * weight).sum()

    h, tau0 = 1e-6, 1e-3
    fd_v = float(loss("torch", verts + h / 2 * direction, tau0) - loss("torch", verts - h / 2 * direction, tau0)) / h
    fd_t = float(loss("torch", verts, tau0 * (1 + h / 2)) - loss("torch", verts, tau0 * (1 - h / 2))) / (h * tau0)
    for backend in ("torch", "drjit"):
        v = verts.clone().requires_grad_()
        t = torch.tensor(tau0, dtype=torch.float64, requires_grad=True)
        loss(backend, v, t).backward()
        assert abs(float((v.grad * direction).sum()) - fd_v) < 1e-5 * abs(fd_v), backend
        assert abs(float(t.grad) - fd_t) < 1e-5 * abs(fd_t), backend


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_softmax_tiny_coverage_colours_agree(dtype):
    """A 0.003-wide face at 64², eps = 0, τ = 1e-3: pixels a few pixels away have coverage below
    1e-300 and a background weight of ~e^-3300. The softmax blend there gives the face's colour.
    Torch kept a subnormal coverage and Dr.Jit flushed it (RGB 0.96 apart at 14 pixels); where every
    weight underflowed, the colour came out 0. Both now agree everywhere to float rounding (1e-9 in
    float64, 1e-5 in float32 where RGB is a ratio of sums of ~1 terms)."""
    v = torch.tensor([[0.0, 0.0, 0.0], [0.003, 0.0, 0.0], [0.0, 0.003, 0.0]], dtype=dtype)
    col = torch.as_tensor(np.random.default_rng(0).random((3, 3)), dtype=dtype)
    cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=40.0)
    img = {}
    for backend in ("torch", "drjit"):
        r = gendr.Renderer("logistic", "probabilistic", tau=0.001, image_size=64, eps=0.0, backend=backend)
        img[backend] = r.to_numpy(r.render(v, np.array([[0, 1, 2]]), cam, vertex_colors=col))[0]
    tol = 1e-9 if dtype == torch.float64 else 1e-5
    np.testing.assert_allclose(img["drjit"], img["torch"], rtol=0, atol=tol)
