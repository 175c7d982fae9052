"""The torch backend's ``compile=True``: fused per-pair chains (gendr_torch.fused) give the eager
renderer's images and gradients, fall back to eager where they do not apply, and when compilation
fails, with a warning.

Tolerances: in float64 the fused and the eager chains evaluate the same formulas; the compiler
may contract multiply-adds and reorder the row sums, so values agree to a few ulps of float64
(atol 1e-12 on alpha in [0, 1]) and gradients to rtol 1e-9 (the sums over ~10⁵ pairs add
rounding of ~1e-13 relative per pair; a flip of the nearest edge at a kink tie would show as a
local error far above this, which is what the tolerance is there to catch).

The first compilation of an instance takes ~1 minute on 2 cores with an empty Inductor cache, so
the default run compiles one instance (logistic + probabilistic); the others are ``slow``.
"""
from __future__ import annotations

import warnings

import pytest

torch = pytest.importorskip("torch")

import gendr  # noqa: E402
import gendr_torch.fused as fused  # noqa: E402
from gendr.errors import ParameterError  # noqa: E402
from gendr.scenes import icosphere  # noqa: E402

ATOL_ALPHA, RTOL_GRAD = 1e-12, 1e-9


def _render_and_grads(compile, dist="logistic", tconorm="probabilistic", dtype=torch.float64, **kw):
    mesh = icosphere(2)  # squashed and moved off-centre: no symmetric ties between faces
    verts = torch.tensor(mesh.vertices * [0.9, 0.75, 0.8] + [0.08, -0.05, 0.0], dtype=dtype).requires_grad_(True)
    tau = torch.tensor(0.02, dtype=dtype, requires_grad=True)
    cam = gendr.orbit_camera(25.0, 15.0, 3.0, fov_y=45.0)
    r = gendr.Renderer(dist, tconorm, tau=tau, image_size=(40, 48), blend=None, backend="torch",
                       compile=compile, **kw)
    alpha = r.render(verts, torch.tensor(mesh.faces), cam)[..., 3]
    weights = torch.linspace(-1.0, 2.0, alpha.numel(), dtype=dtype).view_as(alpha)
    gv, gt = torch.autograd.grad((alpha * weights).sum(), (verts, tau))
    return alpha.detach(), gv, gt


def _assert_same(a, b):
    torch.testing.assert_close(a[0], b[0], rtol=0.0, atol=ATOL_ALPHA)
    for x, y in zip(a[1:], b[1:]):
        torch.testing.assert_close(x, y, rtol=RTOL_GRAD, atol=RTOL_GRAD * float(y.abs().max()))


def test_compiled_matches_eager(monkeypatch):
    ran = {"forward": 0, "backward": 0}  # blocks the fused chains computed (None: eager)
    for name in ran:
        def spy(self, *a, _f=getattr(fused.FusedChains, name), _n=name):
            out = _f(self, *a)
            ran[_n] += out is not None
            return out
        monkeypatch.setattr(fused.FusedChains, name, spy)
    out = _render_and_grads(True)
    assert fused.compile_status() is None, fused.compile_status()
    assert ran["forward"] >= 1 and ran["backward"] == ran["forward"], ran  # every block fused, both ways
    _assert_same(out, _render_and_grads(False))
    assert float(out[0].max()) > 0.99 and float(out[2].abs()) > 0  # a real silhouette and a τ gradient


@pytest.mark.slow
@pytest.mark.parametrize("dist, tconorm, kw", [
    ("uniform", "probabilistic", {}),  # saturated blocks (p = 1 inside) run eagerly
    ("logistic", "average", {}),  # the mean: sums p
    ("cauchy", "einstein", {"cutoff": 100.0}),  # heavy tail with the reference cut-off
    ("gaussian", "yager", {"eps": 0.0}),  # squared, a T-conorm parameter, no eps culling
])
def test_compiled_matches_eager_other_instances(dist, tconorm, kw):
    if dist == "gaussian":
        dist, tconorm = gendr.distribution(dist, squared=True), gendr.tconorm(tconorm, p=2.0)
    _assert_same(_render_and_grads(True, dist, tconorm, **kw), _render_and_grads(False, dist, tconorm, **kw))


def test_learnable_parameters_and_max_run_eagerly(monkeypatch):
    def no_compile(*a, **k):
        raise AssertionError("nothing may be compiled here")
    monkeypatch.setattr(torch, "compile", no_compile)
    p = torch.tensor(2.0, dtype=torch.float64, requires_grad=True)
    for tcn in (gendr.tconorm("yager", p=p), "max"):
        a = _render_and_grads(True, "logistic", tcn)
        _assert_same(a, _render_and_grads(False, "logistic", tcn))


def test_failed_compilation_warns_and_renders_eagerly(monkeypatch):
    monkeypatch.setattr(fused, "_BROKEN", [])
    monkeypatch.setattr(fused, "_COMPILED", {})

    def broken(fn, **kw):
        def call(*a):
            raise RuntimeError("InvalidCxxCompiler: no working C++ compiler found")
        return call
    monkeypatch.setattr(torch, "compile", broken)
    with pytest.warns(RuntimeWarning, match="compile=True failed .*InvalidCxxCompiler.*rendering eagerly"):
        out = _render_and_grads(True)
    assert "InvalidCxxCompiler" in fused.compile_status()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once per process, not per block
        _assert_same(_render_and_grads(True), out)
    _assert_same(out, _render_and_grads(False))


@pytest.mark.parametrize("bad", ["yes", 1, None])
def test_compile_must_be_bool(bad):
    with pytest.raises(ParameterError, match=f"compile={bad!r}"):
        gendr.Renderer(backend="torch", compile=bad)
