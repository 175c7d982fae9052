"""Dr.Jit backend gradients against float64 central finite differences (torch.autograd.gradcheck).

The scene, kink avoidance, τ choice and tolerances are those of test_gradcheck.py (see its
docstring; plus NONDET_TOL below): the renderer is called with torch tensors, so gradcheck differentiates through
dr.wrap and Dr.Jit's reverse-mode AD of the per-pixel sum loop (and, for max / hard, through the
arg-max face re-evaluated outside the loop).

Default run: every differentiable distribution with a rotating T-conorm (probabilistic, max, yager,
frank, dombi), every differentiable T-conorm with logistic, camera parameters of every camera kind,
and the RGB blends. ``pytest -m slow``: the exhaustive distribution × T-conorm product.
"""
from __future__ import annotations

import pytest

pytest.importorskip("drjit", reason="the Dr.Jit backend needs drjit (pip install gendr[drjit])")
torch = pytest.importorskip("torch")

import gendr  # noqa: E402
from test_gradcheck import (ATOL, CAMERAS, DISTS, EPS, FACES, LIGHT, RTOL, TCNS, VERTS, H, W, _id,  # noqa: E402
                            pick_tau, t, verts)

#: Dr.Jit's reverse pass accumulates gradients with parallel atomic scatter-adds, whose summation
#: order (hence float64 rounding) depends on thread scheduling: repeated backward calls may differ at
#: the 1e-16 relative level (observed when the machine is loaded). gradcheck's default tolerance is 0.
NONDET_TOL = 1e-10

ROTATE = [("probabilistic", {}), ("max", {}), ("yager", {"p": 3.0}), ("frank", {"p": 10.0}), ("dombi", {"p": 2.0})]


def check(dist, tcn, camera_kind="perspective", blend=None, fast_mode=True, colors=False):
    dist = gendr.distribution(dist[0], **dist[1])
    tcn = gendr.tconorm(tcn[0], **tcn[1])
    build, cam0 = CAMERAS[camera_kind]
    cam_params = [t(c) for c in cam0]
    tau0 = pick_tau(dist, tcn, build(*[c.detach() for c in cam_params]), rgb=blend is not None)
    vcol = torch.rand(len(VERTS), 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)

    def f(v, tau, *cp):
        r = gendr.Renderer(dist, tcn, tau=tau, image_size=(H, W), eps=0.0, blend=blend, gamma=0.1,
                           light_direction=LIGHT, backend="drjit")
        out = r.render(v, FACES, build(*cp), **({"vertex_colors": vcol} if colors else {}))
        return out if blend is not None else out[..., 3]

    inputs = (verts(), t(tau0), *cam_params)
    assert torch.autograd.gradcheck(f, inputs, eps=EPS, atol=ATOL, rtol=RTOL, fast_mode=fast_mode, nondet_tol=NONDET_TOL)


@pytest.mark.parametrize("i", range(len(DISTS)), ids=[_id(d) for d in DISTS])
def test_every_distribution(i):
    check(DISTS[i], ROTATE[i % len(ROTATE)])


@pytest.mark.parametrize("tcn", TCNS, ids=_id)
def test_every_tconorm(tcn):
    check(("logistic", {}), tcn)


@pytest.mark.parametrize("camera", list(CAMERAS))
def test_camera_parameters(camera):
    check(("gaussian", {}), ("einstein", {}), camera)


@pytest.mark.parametrize("blend,camera", [("softmax", "perspective"), ("hard", "orthographic"),
                                          ("softmax", "orbit"), ("hard", "intrinsics")])
def test_rgb_blends(blend, camera):
    check(("logistic", {}), ("probabilistic", {}), camera, blend=blend, colors=True)


def test_full_jacobian_one_instance():
    check(("gamma", {"shape": 2.0}), ("hamacher", {"p": 0.5}), fast_mode=False)


@pytest.mark.slow
@pytest.mark.parametrize("dist", DISTS, ids=_id)
@pytest.mark.parametrize("tcn", TCNS, ids=_id)
def test_distribution_times_tconorm(dist, tcn):
    check(dist, tcn)
