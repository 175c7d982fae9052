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
pytest.importorskip("torch")

from test_gradcheck import CAMERAS, DISTS, NONDET_TOL, TCNS, _id  # noqa: E402
from test_gradcheck import check as check_backend  # noqa: E402

ROTATE = [("probabilistic", {}), ("max", {}), ("yager", {"p": 3.0}), ("frank", {"p": 10.0}), ("dombi", {"p": 2.0})]


def check(dist, tcn, camera_kind="perspective", **kw):
    check_backend(dist, tcn, camera_kind, backend="drjit", nondet_tol=NONDET_TOL, **kw)


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
