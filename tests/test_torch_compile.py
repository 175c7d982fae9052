"""The torch backend's ``compile=True``: fused per-pair chains (gendr_torch.fused) give the eager
renderer's images and gradients, fall back to eager where they do not apply, and when compilation
fails, with a warning, for that instance only.

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
from torch._inductor.exc import InvalidCxxCompiler  # noqa: E402

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
    ("uniform", "probabilistic", {}),  # F reaches 1: not compiled, eager
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


def _count_fused_forwards(monkeypatch):
    """A list whose length grows by one per block the fused forward computed."""
    ran = []

    def spy(self, *a, _f=fused.FusedChains.forward):
        out = _f(self, *a)
        if out is not None:
            ran.append(self.key)
        return out
    monkeypatch.setattr(fused.FusedChains, "forward", spy)
    return ran


def _fresh_state(monkeypatch):
    monkeypatch.setattr(fused, "_FAILED", {})
    monkeypatch.setattr(fused, "_OVER_LIMIT", set())
    monkeypatch.setattr(fused, "_COMPILED", {})


def _alpha(dist="logistic", tconorm="probabilistic", tau=0.02, dtype=torch.float64):
    """Forward only (compiles only the forward chain), compile=True, a small image."""
    mesh = icosphere(2)
    verts = torch.tensor(mesh.vertices * [0.9, 0.75, 0.8] + [0.08, -0.05, 0.0], dtype=dtype)
    r = gendr.Renderer(dist, tconorm, tau=tau, image_size=(20, 24), blend=None, backend="torch", compile=True)
    return r.render(verts, torch.tensor(mesh.faces), gendr.orbit_camera(25.0, 15.0, 3.0, fov_y=45.0))[..., 3]


def _gendr_warnings(record):
    return [str(w.message) for w in record if str(w.message).startswith("gendr")]


def test_failed_compilation_warns_and_renders_eagerly(monkeypatch):
    _fresh_state(monkeypatch)

    def broken(fn, **kw):
        def call(*a):
            raise InvalidCxxCompiler()
        return call
    monkeypatch.setattr(torch, "compile", broken)
    with pytest.warns(RuntimeWarning, match="compile=True failed for logistic [+] probabilistic "
                                            ".*InvalidCxxCompiler.*rendering it eagerly"):
        out = _render_and_grads(True)
    assert "InvalidCxxCompiler" in fused.compile_status()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once per instance, not per block
        _assert_same(_render_and_grads(True), out)
    _assert_same(out, _render_and_grads(False))


def test_torch_compile_refusing_warns_and_renders_eagerly(monkeypatch):
    """torch 2.13's torch.compile() raises a plain RuntimeError where it is unsupported (Python
    3.15+, free-threaded 3.13.0-2): that rendered eagerly with a warning until e6c1215, then raised."""
    _fresh_state(monkeypatch)

    def refuse(fn, **kw):
        raise RuntimeError("torch.compile is not supported on Python 3.15+")
    monkeypatch.setattr(torch, "compile", refuse)
    with pytest.warns(RuntimeWarning, match="compile=True failed for logistic [+] probabilistic .*Python 3.15"):
        out = _render_and_grads(True)
    _assert_same(out, _render_and_grads(False))


def test_errors_other_than_compilation_propagate(monkeypatch):
    # e.g. out of memory on the first call is no reason to render eagerly (nor a compile failure)
    _fresh_state(monkeypatch)

    def oom(fn, **kw):
        def call(*a):
            raise torch.OutOfMemoryError("CPU out of memory")
        return call
    monkeypatch.setattr(torch, "compile", oom)
    with pytest.raises(torch.OutOfMemoryError):
        _alpha()
    assert fused.compile_status() is None


def test_a_failed_instance_leaves_the_others_fused(monkeypatch):
    _fresh_state(monkeypatch)
    ran = _count_fused_forwards(monkeypatch)
    fail = [False]

    def fake(fn, **kw):  # the chains uncompiled (same code path, no compile cost), or a failure
        if fail[0]:
            def fn(*a):
                raise InvalidCxxCompiler()
        return fn
    monkeypatch.setattr(torch, "compile", fake)
    _alpha("logistic", "probabilistic")
    fail[0] = True
    with pytest.warns(RuntimeWarning, match="InvalidCxxCompiler"):
        _alpha("logistic", "einstein")
    assert len(ran) > 0 and all(k[1].name == "probabilistic" for k in ran)
    del ran[:]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        _alpha("logistic", "probabilistic")
    assert len(ran) > 0, "the instance compiled before the failure must still run fused"


@pytest.fixture
def eager_dynamo(monkeypatch):
    """Real Dynamo with its eager backend (no Inductor: seconds, not a minute), recompile limit 1."""
    compile_ = torch.compile
    monkeypatch.setattr(torch, "compile", lambda fn, **kw: compile_(fn, **{**kw, "backend": "eager"}))
    with torch._dynamo.config.patch(recompile_limit=1):
        yield


def test_more_instances_than_the_recompile_limit_stay_fused(monkeypatch, eager_dynamo):
    # each instance has its own Dynamo cache: compiling one more never disables the others
    _fresh_state(monkeypatch)
    ran = _count_fused_forwards(monkeypatch)
    tconorms = ["probabilistic", "einstein", "probabilistic"]
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        counts = []
        for tcn in tconorms:
            n = len(ran)
            _alpha("logistic", tcn)
            counts.append(len(ran) - n)
    assert _gendr_warnings(record) == [] and fused.compile_status() is None
    assert all(c > 0 for c in counts), dict(zip(tconorms, counts))


def test_tau_requiring_grad_is_not_another_variant(monkeypatch, eager_dynamo):
    # the forward gets τ detached, as the backward: one compiled variant for both
    _fresh_state(monkeypatch)
    ran = _count_fused_forwards(monkeypatch)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        counts = []
        for tau in (torch.tensor(0.02, dtype=torch.float64, requires_grad=True), 0.02):
            n = len(ran)
            _alpha(tau=tau)
            counts.append(len(ran) - n)
    assert _gendr_warnings(record) == [] and all(c > 0 for c in counts), (counts, _gendr_warnings(record))


def test_recompile_limit_keeps_the_compiled_variants(monkeypatch, eager_dynamo):
    # a variant over the limit renders eagerly, said once and not as a compile failure
    _fresh_state(monkeypatch)
    ran = _count_fused_forwards(monkeypatch)
    _alpha(dtype=torch.float64)
    with pytest.warns(RuntimeWarning, match="reached torch._dynamo.config.recompile_limit"):
        n = len(ran)
        a32 = _alpha(dtype=torch.float32)
    assert len(ran) == n and fused.compile_status() is None
    torch.testing.assert_close(a32, _alpha(dtype=torch.float64).float(), rtol=0.0, atol=1e-5)
    assert len(ran) > n  # float64 still fused


SATURATING = ["uniform", "cubic_hermite", "wigner_semicircle", "heaviside", ("exponential", {"reversed": True}),
              ("gamma", {"shape": 0.5, "reversed": True}), ("levy", {"reversed": True})]


@pytest.mark.parametrize("dist", SATURATING, ids=str)
def test_distributions_reaching_one_are_not_compiled(dist, monkeypatch):
    # F = 1 inside faces saturates every block there: the fused forward would be compiled and
    # thrown away per block
    dist = gendr.distribution(dist[0], **dist[1]) if isinstance(dist, tuple) else gendr.distribution(dist)
    assert not fused.FusedChains(dist, gendr.tconorm("probabilistic"), 1e-4, 3, "cpu").ok
    assert fused.FusedChains(dist, gendr.tconorm("average"), 1e-4, 3, "cpu").ok  # the mean never saturates


def test_saturating_instance_renders_without_compiling(monkeypatch):
    _fresh_state(monkeypatch)

    def no_compile(*a, **k):
        raise AssertionError("nothing may be compiled here")
    monkeypatch.setattr(torch, "compile", no_compile)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        out = _render_and_grads(True, "uniform")
    _assert_same(out, _render_and_grads(False, "uniform"))
    for dist in ("logistic", "exponential", "cauchy"):  # F < 1 everywhere: compiled
        assert fused.FusedChains(gendr.distribution(dist), gendr.tconorm("probabilistic"), 1e-4, 3, "cpu").ok


@pytest.mark.parametrize("bad", ["yes", 1, None])
def test_compile_must_be_bool(bad):
    with pytest.raises(ParameterError, match=f"compile={bad!r}"):
        gendr.Renderer(backend="torch", compile=bad)
