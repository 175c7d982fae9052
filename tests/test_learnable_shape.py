"""Learnable distribution parameter (the gamma shape k): ∂/∂k of the spec formulas against mpmath,
of renders against finite differences (both backends, every aggregation kind and the RGB blend),
values unchanged, domain checks, Dr.Jit-native arrays.

Spec reference: mpmath's numerical derivative of its regularized incomplete gamma function at 30
digits. The spec differentiates its own truncated series (32 terms) and continued fraction (depth
11) term by term; the worst measured error over the grid below is 1.2e-7 (relative, log Q at
k = 0.25, x = 1.76, just above the switch x = k + 1.5 where the fraction converges slowest), so the
tolerance 1e-6 (relative, or absolute where the derivative is below 1) has an 8x margin.

Render checks: Richardson-extrapolated central differences as in tests/test_learnable_p.py
(tolerance 1e-6 relative, floor 1e-3; worst measured 2.4e-8, drjit, k = 0.5 reversed, probabilistic).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")
mpmath = pytest.importorskip("mpmath")  # (a dependency of torch, through sympy)

import gendr  # noqa: E402
from gendr.distributions import DISTRIBUTIONS, _digamma  # noqa: E402
from gendr.errors import ParameterError  # noqa: E402
from gendr.params import Learnable  # noqa: E402
from gendr_validation.gradcheck import richardson  # noqa: E402
from test_learnable_p import _backends, _scene, drjit_native_grad  # noqa: E402  (shared with p's checks)

SPEC_TOL = 1e-6
RTOL, FLOOR = 1e-6, 1e-3


def test_digamma_against_mpmath():
    for k in (0.05, 0.5, 1.0, 1.5, 3.0, 15.9, 16.0, 20.0, 300.0):
        assert abs(_digamma(k) - float(mpmath.digamma(k))) < 1e-13 * max(1.0, abs(float(mpmath.digamma(k)))), k


def _spec_points():
    for k in (0.1, 0.5, 1.0, 2.0, 5.0, 20.0):
        for x in (1e-3, 0.1, 1.0, k, k + 1.49, k + 1.51, 2 * k + 5, 60.0):
            yield k, x


@pytest.mark.parametrize("fn", ["cdf", "log_sf", "log_cdf"])
def test_shape_derivative_matches_mpmath(fn):
    from gendr_torch.ops import torch_ops as ops
    mpmath.mp.dps = 30
    ref_fn = {"cdf": lambda k, x: mpmath.gammainc(k, 0, x, regularized=True),
              "log_sf": lambda k, x: mpmath.log(mpmath.gammainc(k, x, mpmath.inf, regularized=True)),
              "log_cdf": lambda k, x: mpmath.log(mpmath.gammainc(k, 0, x, regularized=True))}[fn]
    fam = DISTRIBUTIONS["gamma"]
    worst = 0.0
    for k, x in _spec_points():
        kt = torch.tensor(k, dtype=torch.float64, requires_grad=True)
        y = getattr(fam, fn)(ops, torch.tensor([x], dtype=torch.float64), shape=Learnable(k, kt))
        g, = torch.autograd.grad(y.sum(), kt)
        ref = float(mpmath.diff(lambda kv: ref_fn(kv, mpmath.mpf(x)), mpmath.mpf(k)))
        err = abs(float(g) - ref) / max(abs(ref), 1.0)
        worst = max(worst, err)
        assert err < SPEC_TOL, (fn, k, x, float(g), ref)
    assert worst > 0.0  # (compared something)


def test_shape_derivative_is_zero_outside_the_support_and_values_unchanged():
    from gendr_torch.ops import torch_ops as ops
    x = torch.tensor([-1.0, 0.0, 0.3, 4.0], dtype=torch.float64)
    kt = torch.tensor(2.0, dtype=torch.float64, requires_grad=True)
    learn = gendr.distribution("gamma", shape=kt)
    plain = gendr.distribution("gamma", shape=2.0)
    p = learn.cdf(ops, x)
    assert torch.equal(p.detach(), plain.cdf(ops, x))
    g, = torch.autograd.grad(p.sum(), kt)
    per = [float(torch.autograd.grad(learn.cdf(ops, x)[i], kt)[0]) for i in range(4)]
    assert per[0] == 0.0 and per[1] == 0.0 and per[2] < 0.0 and per[3] < 0.0  # P decreases with k
    assert math.isclose(float(g), sum(per), rel_tol=1e-12)


# --- renders ------------------------------------------------------------------------------------
def _render_loss(backend, k, *, tconorm="probabilistic", reversed=True, squared=False, blend=None,
                 grad=False, dtype=torch.float64, eps=0.0):
    v, f, cam = _scene()
    kt = torch.tensor(float(k), dtype=torch.float64, requires_grad=grad)
    dist = gendr.distribution("gamma", shape=kt, reversed=reversed, squared=squared)
    r = gendr.Renderer(dist, tconorm, tau=0.0064 if squared else 0.08, image_size=(12, 16), backend=backend,
                       eps=eps, blend=blend, gamma=0.05)
    colors = torch.as_tensor(np.random.default_rng(1).uniform(0.2, 1.0, (f.shape[0], 3)), dtype=dtype)
    img = r.render(torch.as_tensor(v, dtype=dtype), f, cam, face_colors=colors if blend else None)
    w = torch.as_tensor(np.random.default_rng(0).standard_normal((1, 12, 16, 4)), dtype=dtype)
    return (img * w).sum(), kt


#: every aggregation kind (archimedean with and without a parameter, max, mean), both sides of the
#: series/fraction switch (k = 0.5, 3), plain / reversed / squared, and the softmax RGB blend
RENDER_CASES = [(0.5, "probabilistic", True, False, None), (3.0, "probabilistic", False, False, None),
                (0.5, "max", True, True, None), (3.0, gendr.tconorm("yager", p=2.0), True, False, None),
                (0.5, "average", True, True, None), (3.0, "einstein", True, False, "softmax")]


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("k0,tconorm,reversed,squared,blend", RENDER_CASES,
                         ids=[f"k{c[0]:g}-{c[1]}-{'rev' if c[2] else 'plain'}{'-sq' if c[3] else ''}-{c[4]}"
                              for c in RENDER_CASES])
def test_render_dshape_matches_finite_differences(backend, k0, tconorm, reversed, squared, blend):
    kw = dict(tconorm=tconorm, reversed=reversed, squared=squared, blend=blend)
    L, kt = _render_loss(backend, k0, grad=True, **kw)
    L.backward()
    ad = float(kt.grad)
    fd = richardson(lambda s: float(_render_loss(backend, k0 + s, **kw)[0]), 1e-5 * k0)[0]
    assert abs(fd) > 1e-3  # the check has something to check
    assert abs(ad - fd) / max(abs(fd), FLOOR) < RTOL, (ad, fd)


@pytest.mark.parametrize("backend", _backends())
def test_learnable_shape_leaves_the_image_unchanged(backend):
    """The same image, bit for bit, as with the shape given as a float (the gradient term adds 0)."""
    v, f, cam = _scene()
    imgs = []
    for k in (2.0, torch.tensor(2.0, dtype=torch.float64, requires_grad=True)):
        r = gendr.Renderer(gendr.distribution("gamma", shape=k, reversed=True), "probabilistic", tau=0.08,
                           image_size=(12, 16), backend=backend, blend="softmax")
        imgs.append(r.render(torch.as_tensor(v), f, cam, face_colors=torch.ones(f.shape[0], 3, dtype=torch.float64)))
    assert torch.equal(imgs[0], imgs[1].detach())


@pytest.mark.parametrize("backend", _backends())
def test_shape_p_and_tau_together(backend):
    """shape, the T-conorm's p and τ all learnable in one render: each gradient as when alone."""
    v, f, cam = _scene()

    def grads(learn):
        k = torch.tensor(2.0, dtype=torch.float64, requires_grad="k" in learn)
        p = torch.tensor(2.0, dtype=torch.float64, requires_grad="p" in learn)
        tau = torch.tensor(0.08, dtype=torch.float64, requires_grad="tau" in learn)
        r = gendr.Renderer(gendr.distribution("gamma", shape=k, reversed=True), gendr.tconorm("dombi", p=p),
                           tau=tau, image_size=(12, 16), backend=backend, eps=0.0, blend=None)
        w = torch.as_tensor(np.random.default_rng(2).standard_normal((1, 12, 16)))
        (r.render(torch.as_tensor(v), f, cam)[..., 3] * w).sum().backward()
        return {n: float(t.grad) for n, t in (("k", k), ("p", p), ("tau", tau)) if n in learn}

    together = grads({"k", "p", "tau"})
    for n in ("k", "p", "tau"):
        alone = grads({n})[n]
        assert alone != 0.0
        np.testing.assert_allclose(together[n], alone, rtol=1e-12)


@pytest.mark.parametrize("backend", _backends())
def test_float32_render_with_float64_shape(backend):
    L32, k32 = _render_loss(backend, 0.5, grad=True, dtype=torch.float32)
    L32.backward()
    L64, k64 = _render_loss(backend, 0.5, grad=True)
    L64.backward()
    assert L32.dtype == torch.float32
    np.testing.assert_allclose(float(k32.grad), float(k64.grad), rtol=1e-3)


def test_drjit_native_learnable_shape():
    """A Dr.Jit AD array as the shape (no torch in the loop): dr.grad equals the torch backend's."""
    g = drjit_native_grad(0.5, lambda k: (gendr.distribution("gamma", shape=k, reversed=True), "probabilistic"))
    L_t, kt = _render_loss("torch", 0.5, grad=True)
    L_t.backward()
    np.testing.assert_allclose(g, float(kt.grad), rtol=1e-10)


# --- domain -------------------------------------------------------------------------------------
def test_bad_tensor_shape_at_construction():
    with pytest.raises(ParameterError, match=r"distribution 'gamma' parameter shape=-0.5"):
        gendr.distribution("gamma", shape=torch.tensor(-0.5, requires_grad=True))
    with pytest.raises(ParameterError, match="scalar"):
        gendr.distribution("gamma", shape=torch.ones(2))


@pytest.mark.parametrize("backend", _backends())
def test_bad_tensor_shape_at_render_time(backend):
    """An optimizer step that leaves the domain is caught at the next render, naming the value."""
    v, f, cam = _scene()
    k = torch.tensor(1.0, dtype=torch.float64, requires_grad=True)
    r = gendr.Renderer(gendr.distribution("gamma", shape=k), "probabilistic", tau=0.08, image_size=(6, 8),
                       backend=backend, blend=None)
    r.render(torch.as_tensor(v), f, cam)
    with torch.no_grad():
        k.fill_(0.0)
    with pytest.raises(ParameterError, match=r"distribution 'gamma' parameter shape=0.0 .*render time"):
        r.render(torch.as_tensor(v), f, cam)


def test_learnable_shape_label_and_refresh():
    k = torch.tensor(0.5, requires_grad=True)
    d = gendr.distribution("gamma", shape=k, reversed=True)
    assert d.label() == "gamma(shape=0.5)+rev" and d.learnable["shape"] is k
    assert gendr.distribution("gamma", shape=0.5).learnable == {}
    q = d.quantile(1e-4)
    with torch.no_grad():
        k.fill_(2.0)
    d2 = d.refreshed()
    assert d2.label() == "gamma(shape=2)+rev" and d2.learnable["shape"] is k
    assert d2.quantile(1e-4) != q  # culling follows the current value


def test_validation_suite_checks_the_shape():
    """gendr validate's quick gradient check includes ∂/∂shape on a gamma instance."""
    gc = pytest.importorskip("gendr_validation.gradcheck")
    insts = [i for i in gc.select_instances("quick") if gc.has_spec_param(i, "shape")]
    assert [i.name for i in insts] == ["gamma(shape=0.5)+rev|probabilistic"]
    (r,), _ = gc.check_instance(gc.ADAPTERS["torch"](), insts[0], params=("shape",))
    assert r.param == "shape" and r.passed, (r.pixel_mean, r.pixel_max, r.loss_err)
