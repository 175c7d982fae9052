"""torch.autograd.gradcheck (float64) through the whole renderer.

Inputs checked: vertices, τ (a 0-d tensor) and camera parameters (perspective eye and fov_y; orbit
azimuth, elevation, distance; intrinsics fx, cx; orthographic eye, xmag, ymag). Every differentiable
distribution (heaviside is not) with the probabilistic T-conorm, and every differentiable T-conorm
("or" is not) with the logistic distribution; then the RGB blends; then every camera parameter
alone (intrinsics fy and cy too), in both backends.

The image is tiny (6×7) and τ large (0.4 screen units plain, 0.15 squared units for the squared
variant: ~1.2 pixels), eps = 0 (the eps mask is a discontinuity). The scene was chosen so that no
pixel sits near a kink of the rendered function, and each test checks that before calling gradcheck
(``kink_near``; ``pick_tau`` moves τ by a few percent where the default one would put a pixel near
one), with a margin of KINK_MARGIN:

* the signed distance is not differentiable on a polygon's medial axis (two nearest edges tie):
  the gap between the two nearest edge distances must exceed the margin;
* a CDF's derivative can jump (or blow up) at the ends of its support and at 0 (exponential, gamma,
  uniform, ...): x = d/τ must stay that far from 0 and from finite support bounds;
* ``max`` switches faces where the two largest coverages tie; ``yager`` saturates where Σ p^q = 1;
* RGB: barycentrics are clamped at 0 (a kink where one crosses 0), Lambert clamps n·(−l) at 0,
  "hard" jumps at edges (d = 0, covered above).

Tolerances: gradcheck's central differences with step EPS = 1e-6 have truncation error
~EPS²·|f'''|/6 (≲1e-10 here: the largest third derivatives are ~(1/τ)³·|F'''| away from kinks) and
rounding error ~1e-16·|f|/EPS ≈ 1e-10; so ATOL = 1e-6 and RTOL = 1e-4 leave four orders of magnitude
of headroom while still catching any real gradient error (those are O(1) relative).
The default run uses gradcheck's fast mode (a random projection of the Jacobian); the slow run
(``pytest -m slow``) adds the distribution × T-conorm product and full-Jacobian checks.
"""
from __future__ import annotations

import math

import pytest
import torch

import gendr
from gendr.tconorms import MAX
from gendr_torch.ops import torch_ops
from naive_reference import pixel_face_geometry

EPS, ATOL, RTOL = 1e-6, 1e-6, 1e-4
KINK_MARGIN = 1e-3
H, W = 6, 7
TAU, TAU_SQUARED = 0.4, 0.15
LIGHT = (-0.6, 0.5, -1.0)  # lights every face of the scene (n·(−l) well above 0)

# two overlapping faces at different depths and one crossing the near plane (clipped to a quad,
# with corners beyond FAR_CORNER: one of its edges is measured from its far end, which checks the
# backward's exchange of that edge's corner parts; test_near_plane.py)
VERTS = [[-0.85, -0.49, 0.0], [0.49, -0.36, 0.14], [-0.04, 0.72, 0.0],
         [-0.06, -0.22, 0.4], [0.79, 0.06, 0.37], [0.23, 0.66, 0.44],
         [-0.95, 0.33, 0.33], [-0.62, 0.7, 0.06], [-0.67, 0.42, 3.43]]
FACES = torch.tensor([[0, 1, 2], [3, 4, 5], [6, 7, 8]])


def verts():
    return torch.tensor(VERTS, dtype=torch.float64, requires_grad=True)


def t(v):
    return torch.tensor(v, dtype=torch.float64, requires_grad=True)


# camera kind -> (builder from parameter tensors, initial parameter values)
CAMERAS = {
    "perspective": (lambda eye, fov: gendr.PerspectiveCamera(eye=eye, fov_y=fov), ([0.05, -0.03, 3.0], 40.0)),
    "orbit": (lambda az, el, dist: gendr.orbit_camera(az, el, dist, fov_y=40.0), (4.0, -3.0, 3.1)),
    "intrinsics": (lambda fx, cx: gendr.IntrinsicsCamera(eye=(0.0, 0.0, 3.0), fx=fx, fy=8.5, cx=cx, cy=3.1),
                   (8.0, 3.6)),
    "orthographic": (lambda eye, xm, ym: gendr.OrthographicCamera(eye=eye, xmag=xm, ymag=ym),
                     ([0.02, 0.01, 3.0], 1.25, 1.05)),
}


def dist_settings():
    out = []
    for name in sorted(gendr.DISTRIBUTIONS):
        fam = gendr.DISTRIBUTIONS[name]
        if not fam.differentiable:
            continue
        if name == "gamma":
            out += [(name, {"shape": 2.0}), (name, {"shape": 0.5})]
        else:
            out.append((name, {}))
    out += [(n, kw) for n, kw in [("logistic", {"squared": True}), ("exponential", {"reversed": True}),
                                  ("gamma", {"shape": 0.5, "reversed": True}), ("levy", {"reversed": True}),
                                  ("cauchy", {"squared": True}), ("uniform", {"squared": True})]
            if n in gendr.DISTRIBUTIONS]
    return out


TCONORM_PARAMS = {"hamacher": [0.0, 0.5, 4.0], "frank": [0.1, 10.0], "yager": [0.5, 1.0, 3.0],
                  "aczel_alsina": [0.5, 2.0], "dombi": [0.5, 2.0], "schweizer_sklar": [-2.0, -0.5]}


def tconorm_settings():
    out = []
    for name in sorted(gendr.TCONORMS):
        if not gendr.tconorm(name, **({"p": TCONORM_PARAMS[name][0]} if name in TCONORM_PARAMS else {})).differentiable:
            continue
        out += [(name, {"p": p}) for p in TCONORM_PARAMS[name]] if name in TCONORM_PARAMS else [(name, {})]
    return out


def _id(s):
    return s[0] + ("(" + ",".join(f"{k}={v}" for k, v in s[1].items()) + ")" if s[1] else "")


DISTS, TCNS = dist_settings(), tconorm_settings()


def kink_near(dist, tcn, camera, tau, *, rgb=False):
    """Why the rendered function may have a kink within KINK_MARGIN of this configuration (see
    the module docstring), or None."""
    v = torch.tensor(VERTS, dtype=torch.float64)
    d, gap, bary = pixel_face_geometry(v, FACES, camera, (H, W))
    valid = ~torch.isnan(d[..., 0, 0])
    d, gap, bary = d[valid], gap[valid], bary[valid]
    if gap.min() <= KINK_MARGIN:
        return f"a pixel is within {gap.min():.2g} of a medial axis"
    x = dist.argument(torch_ops, d, tau)
    lo, hi = dist.support()
    for s in {0.0, lo, hi}:
        if math.isfinite(s) and (x - s).abs().min() <= KINK_MARGIN:
            return f"x = d/τ comes within {(x - s).abs().min():.2g} of {s}"
    p = dist.cdf(torch_ops, x)
    if tcn.kind == MAX and p.shape[0] > 1:
        top = p.sort(0, descending=True).values
        # (ties at exactly 0 or 1 are flat, not kinks: bounded supports have F' = 0 there)
        if ((top[0] - top[1] <= KINK_MARGIN) & (top[1] > 0) & (top[0] < 1)).any():
            return "two faces tie for the max"
    if tcn.name == "yager":
        # (a face with p = 1 saturates the pixel on a flat part of its CDF: not a kink)
        near = (((p ** tcn.kwargs["p"]).sum(0) - 1).abs() <= KINK_MARGIN) & (p.amax(0) < 1)
        if near.any():
            return "a pixel is on yager's saturation boundary"
    if rgb:
        if bary.abs().min() <= KINK_MARGIN:
            return f"a barycentric is within {bary.abs().min():.2g} of 0"
        wt = v[FACES]
        n = torch.linalg.cross(wt[:, 1] - wt[:, 0], wt[:, 2] - wt[:, 0])
        light = torch.tensor(LIGHT, dtype=torch.float64)
        if ((n / n.norm(dim=-1, keepdim=True)) @ (-light / light.norm())).min() <= 0.05:
            return "Lambert clamp max(0, n·(−l)) near its kink"
    return None


def pick_tau(dist, tcn, camera, *, rgb=False):
    """The default τ, or the first nearby one that keeps every pixel away from kinks."""
    base = TAU_SQUARED if dist.squared else TAU
    reasons = []
    for factor in (1.0, 0.93, 1.08, 0.86, 1.17):
        why = kink_near(dist, tcn, camera, base * factor, rgb=rgb)
        if why is None:
            return base * factor
        reasons.append(why)
    pytest.fail(f"fixture: every candidate τ puts a pixel near a kink: {reasons}")


#: Dr.Jit's reverse pass accumulates gradients with parallel atomic scatter-adds, whose summation
#: order (hence float64 rounding) depends on thread scheduling: repeated backward calls may differ at
#: the 1e-16 relative level (observed when the machine is loaded). gradcheck's default tolerance is 0.
NONDET_TOL = 1e-10


def check(dist, tcn, camera_kind="perspective", blend=None, fast_mode=True, colors=False, backend="torch",
          nondet_tol=0.0):
    dist = gendr.distribution(dist[0], **dist[1]) if isinstance(dist, tuple) else gendr.distribution(dist)
    tcn = gendr.tconorm(tcn[0], **tcn[1]) if isinstance(tcn, tuple) else gendr.tconorm(tcn)
    build, cam0 = CAMERAS[camera_kind]
    cam_params = [t(c) for c in cam0]
    tau0 = pick_tau(dist, tcn, build(*[c.detach() for c in cam_params]), rgb=blend is not None)
    vcol = torch.rand(len(VERTS), 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)

    def f(v, tau, *cp):
        r = gendr.Renderer(dist, tcn, tau=tau, image_size=(H, W), eps=0.0, blend=blend, gamma=0.1,
                           light_direction=LIGHT, backend=backend)
        out = r.render(v, FACES, build(*cp), **({"vertex_colors": vcol} if colors else {}))
        return out if blend is not None else out[..., 3]

    inputs = (verts(), t(tau0), *cam_params)
    assert torch.autograd.gradcheck(f, inputs, eps=EPS, atol=ATOL, rtol=RTOL, fast_mode=fast_mode,
                                    nondet_tol=nondet_tol)


def test_scene_is_not_degenerate():
    """Every face covers some pixel centre and the clipped one reaches the image: gradients are not
    trivially zero."""
    build, cam0 = CAMERAS["perspective"]
    d, _, _ = pixel_face_geometry(torch.tensor(VERTS, dtype=torch.float64), FACES, build(*cam0), (H, W))
    assert ((d > 0).sum((-1, -2)) >= 1).all()


@pytest.mark.parametrize("dist", DISTS, ids=[_id(s) for s in DISTS])
def test_every_distribution(dist):
    check(dist, "probabilistic")


@pytest.mark.parametrize("tcn", TCNS, ids=[_id(s) for s in TCNS])
def test_every_tconorm(tcn):
    check("logistic", tcn)


@pytest.mark.parametrize("camera", sorted(CAMERAS))
def test_camera_parameters(camera):
    check("logistic", "probabilistic", camera_kind=camera)


#: every camera parameter, one at a time: (kind, builder, initial values). The checks above always
#: differentiate the vertices too, which hid a Dr.Jit bug: it returned corner gradients only when the
#: x corners needed one, so orthographic ymag, intrinsics fy or cy alone got 0 (FD: −86, 5.1, 30)
ALONE = {**{k: v for k, v in CAMERAS.items() if k != "intrinsics"},
         "intrinsics": (lambda fx, fy, cx, cy: gendr.IntrinsicsCamera(eye=(0.0, 0.0, 3.0), fx=fx, fy=fy, cx=cx, cy=cy),
                        (8.0, 8.5, 3.6, 3.1))}
ALONE_CASES = [(k, i) for k, (_, init) in ALONE.items() for i in range(len(init))]


def _backends():
    try:
        import drjit  # noqa: F401
        return ["torch", "drjit"]
    except ImportError:
        return ["torch"]


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("camera,i", ALONE_CASES, ids=[f"{k}-{i}" for k, i in ALONE_CASES])
def test_each_camera_parameter_alone(camera, i, backend):
    """gradcheck with only camera parameter ``i`` requiring grad (the vertices, τ and the other
    parameters constant), the custom-op path (probabilistic, alpha) and the softmax RGB blend."""
    build, init = ALONE[camera]
    const = [torch.tensor(c, dtype=torch.float64) for c in init]
    tau0 = pick_tau(gendr.distribution("logistic"), gendr.tconorm("probabilistic"), build(*const), rgb=True)
    for blend in (None, "softmax"):
        def f(c):
            r = gendr.Renderer("logistic", "probabilistic", tau=tau0, image_size=(H, W), eps=0.0, blend=blend,
                               gamma=0.1, light_direction=LIGHT, backend=backend)
            out = r.render(verts().detach(), FACES, build(*[c if j == i else x for j, x in enumerate(const)]))
            return out if blend is not None else out[..., 3]
        x0 = torch.tensor(init[i], dtype=torch.float64)
        assert (f(x0 + 1e-3) - f(x0)).abs().max() > 1e-6  # the image depends on it: the check can fail
        assert torch.autograd.gradcheck(f, (t(init[i]),), eps=EPS, atol=ATOL, rtol=RTOL, nondet_tol=NONDET_TOL)


@pytest.mark.parametrize("camera", ["perspective", "orthographic"])
@pytest.mark.parametrize("blend", ["softmax", "hard"])
def test_rgb_blends(blend, camera):
    check("gaussian", "einstein", camera_kind=camera, blend=blend, colors=True)


def test_full_jacobian_one_instance():
    """One instance with gradcheck's full (non-fast) Jacobian comparison."""
    check("logistic", "probabilistic", blend="softmax", fast_mode=False, colors=True)


@pytest.mark.slow
@pytest.mark.parametrize("tcn", TCNS, ids=[_id(s) for s in TCNS])
@pytest.mark.parametrize("dist", DISTS, ids=[_id(s) for s in DISTS])
def test_distribution_times_tconorm(dist, tcn):
    check(dist, tcn)


@pytest.mark.slow
@pytest.mark.parametrize("dist", DISTS, ids=[_id(s) for s in DISTS])
def test_every_distribution_full_jacobian(dist):
    check(dist, "probabilistic", fast_mode=False)


@pytest.mark.slow
@pytest.mark.parametrize("tcn", TCNS, ids=[_id(s) for s in TCNS])
def test_every_tconorm_full_jacobian(tcn):
    check("logistic", tcn, fast_mode=False)


@pytest.mark.slow
@pytest.mark.parametrize("camera", sorted(CAMERAS))
@pytest.mark.parametrize("blend", ["softmax", "hard"])
def test_rgb_blends_cameras_full_jacobian(blend, camera):
    check("logistic", "probabilistic", camera_kind=camera, blend=blend, fast_mode=False, colors=True)


@pytest.mark.parametrize("backend", ["torch", "drjit"])
@pytest.mark.parametrize("size,a,b,c", [(24, 0.55, 0.62, (0.45, 0.5)), (20, 0.7547, 0.8535, (0.8715, 0.2408))])
def test_edge_through_pixel_centres(backend, size, a, b, c):
    """An edge along y = −x passes through the pixel centres of an even-sized orthographic view;
    rounding puts some of them just outside (|d| ~ 1e-16), where the backward's direction
    (p − q)/|p − q| was noise: vertex gradients 2.5 % and 8 % (torch) and 15 % (Dr.Jit, the second scene) off here, up to 23 % on others,
    torch and Dr.Jit each where rounding fell. There it is the edge's outward normal, exactly.
    Central differences (h = 1e-7, float64; truncation ~h²·|f'''| and round-off ~1e-16·|f|/h,
    both < 1e-8 of the gradients here): 1e-7 relative to the largest."""
    if backend == "drjit":
        pytest.importorskip("drjit")
    V = torch.tensor([[-a, a, 0.0], [b, -b, 0.0], [c[0], c[1], 0.0]], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 2]])
    cam = gendr.OrthographicCamera(eye=(0.0, 0.0, 3.0), xmag=1.0, ymag=1.0)
    r = gendr.Renderer("logistic", "probabilistic", tau=0.05, image_size=size, blend=None, backend=backend)

    def loss(v):
        return r.render(v, faces, cam)[..., 3].sum()
    v = V.clone().requires_grad_(True)
    loss(v).backward()
    fd = torch.zeros(3, 2, dtype=torch.float64)
    for i in range(3):
        for j in range(2):
            e = torch.zeros(3, 3, dtype=torch.float64)
            e[i, j] = 1e-7
            fd[i, j] = (loss(V + e / 2) - loss(V - e / 2)) / 1e-7
    err = float((v.grad[:, :2] - fd).abs().max() / fd.abs().max())
    assert err < 1e-7, f"{backend}: vertex gradients {err:.3g} (relative) from central differences"
