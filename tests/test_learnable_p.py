"""Learnable T-conorm parameter p: ∂/∂p against finite differences (spec and both backends), its
domain checks (at construction and at render time), dtypes.

Finite differences: Richardson-extrapolated central differences (4·D(h/2) − D(h))/3 in float64,
h = 1e-5·max(1, |p|) (validation.gradcheck.richardson). Their truncation error is O(h⁴) (negligible);
their round-off is ~1e-16·|L|/h ≈ 1e-10 absolute for these losses (|L| ≲ 10), so the relative
tolerance 1e-6 (floor 1e-3 on |FD|) leaves a margin of ~20x over the worst measured case
(frank p = 5: 5e-8, a small derivative 4e-3).
"""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import gendr  # noqa: E402
from gendr.errors import ParameterError  # noqa: E402
from gendr.ops import numpy_ops  # noqa: E402
from gendr.scenes import icosphere  # noqa: E402
from gendr_validation.gradcheck import richardson  # noqa: E402

#: every parametric family with values on both sides of its special cases (yager p = 1: a kink of
#: the power at 0; frank p < 1 and > 1: different evaluation forms)
FAMILIES = {"hamacher": [0.5, 3.0], "frank": [0.3, 5.0], "yager": [0.5, 1.0, 2.0],
            "aczel_alsina": [0.5, 2.0], "dombi": [0.5, 2.0], "schweizer_sklar": [-0.5, -2.0]}
CASES = [(f, p) for f, ps in FAMILIES.items() for p in ps]
#: one value per family for the (slower) render checks
RENDER_CASES = [(f, ps[-1]) for f, ps in FAMILIES.items()] + [("yager", 0.5), ("frank", 0.3)]
RTOL, FLOOR = 1e-6, 1e-3


def _rel(a, r):
    return abs(a - r) / max(abs(r), FLOOR)


def _step(p):
    return 1e-5 * max(1.0, abs(p))


@pytest.mark.parametrize("ones", [False, True])
@pytest.mark.parametrize("family,p0", CASES)
def test_aggregate_dp_matches_finite_differences(family, p0, ones):
    """``ones``: some inputs exactly 1 (fully covered pixels; the generator sum is inf for the strict
    families): the aggregate is 1 for every p there, so they add 0 to ∂/∂p (dombi's and
    schweizer_sklar's inverses gave inf·0 = NaN before)."""
    from gendr_torch.ops import torch_ops as ops
    x = np.random.default_rng(3).uniform(0.01, 0.99, (3, 40))
    if ones:
        x[1, ::3] = 1.0
    x = torch.as_tensor(x)
    w = torch.as_tensor(np.random.default_rng(4).standard_normal(40))

    def loss(p, grad=False):
        pt = torch.tensor(float(p), dtype=torch.float64, requires_grad=grad)
        return (gendr.tconorm(family, p=pt).aggregate(ops, list(x)) * w).sum(), pt

    L, pt = loss(p0, True)
    L.backward()
    fd = richardson(lambda s: float(loss(p0 + s)[0]), _step(p0))[0]
    assert np.isfinite(float(pt.grad)) and _rel(float(pt.grad), fd) < RTOL, (float(pt.grad), fd)
    # the value is the float setting's, to rounding
    with np.errstate(divide="ignore"):  # (log(1 − x) = −inf at x = 1, as it should be)
        ref = gendr.tconorm(family, p=p0).aggregate(numpy_ops, [t.numpy() for t in x])
    np.testing.assert_allclose(L.item(), float((ref * w.numpy()).sum()), rtol=1e-13, atol=1e-13)


def _scene():
    m = icosphere(1)
    v = m.vertices * np.array([0.9, 0.75, 0.8]) + np.array([0.08, -0.05, 0.0])
    return v, m.faces, gendr.orbit_camera(25.0, 15.0, 3.0, fov_y=40.0)


def _render_loss(backend, family, p, *, grad=False, dtype=torch.float64, tau=0.08, blend=None):
    v, f, cam = _scene()
    pt = torch.tensor(float(p), dtype=torch.float64, requires_grad=grad)
    r = gendr.Renderer("logistic", gendr.tconorm(family, p=pt), tau=tau, image_size=(12, 16), backend=backend,
                       eps=0.0, blend=blend)
    img = r.render(torch.as_tensor(v, dtype=dtype), f, cam)
    w = torch.as_tensor(np.random.default_rng(0).standard_normal((1, 12, 16, 4)), dtype=dtype)
    return (img * w).sum(), pt


def _backends():
    out = ["torch"]
    try:
        import drjit  # noqa: F401
        out.append("drjit")
    except ImportError:
        pass
    return out


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("family,p0", RENDER_CASES)
def test_render_dp_matches_finite_differences(backend, family, p0):
    L, pt = _render_loss(backend, family, p0, grad=True)
    L.backward()
    ad = float(pt.grad)
    fd = richardson(lambda s: float(_render_loss(backend, family, p0 + s)[0]), _step(p0))[0]
    assert abs(fd) > 1e-3  # the check has something to check
    assert _rel(ad, fd) < RTOL, (ad, fd)


def _one_sided(f, h):
    """f'(0) from the right (Hamacher's p cannot go below 0): the second-order one-sided difference
    (−3f(0) + 4f(h) − f(2h))/2h, Richardson-extrapolated over h and h/2 (truncation O(h³) ≈ 1e-12
    at h = 1e-4, round-off ~1e-16·|L|/h ≈ 1e-11; measured 6e-11 … 2e-10 relative)."""
    def d(h):
        return (-3.0 * f(0.0) + 4.0 * f(h) - f(2.0 * h)) / (2.0 * h)
    return (4.0 * d(h / 2.0) - d(h)) / 3.0


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("p0", [0.0, 1e-9])
def test_hamacher_dp_at_and_near_p_zero(backend, p0):
    """Hamacher's generator switches form at p = 0 (the Hamacher sum, o = x/(1 − x)), which has no
    p in it: ∂L/∂p was 0 at p = 0 (finite differences: −0.27), so a p started there never moved,
    and lost digits for tiny p. A learnable p now uses the generator log1p(p·o)/p, smooth through 0."""
    L, pt = _render_loss(backend, "hamacher", p0, grad=True)
    L.backward()
    fd = _one_sided(lambda s: float(_render_loss(backend, "hamacher", p0 + s)[0]), 1e-4)
    assert abs(fd) > 1e-3
    assert _rel(float(pt.grad), fd) < RTOL, (float(pt.grad), fd)


@pytest.mark.parametrize("backend", _backends())
def test_p_and_tau_together_with_rgb(backend):
    """p and τ both learnable, softmax RGB on (the blend does not depend on p): both gradients."""
    v, f, cam = _scene()
    p = torch.tensor(2.0, dtype=torch.float64, requires_grad=True)
    tau = torch.tensor(0.08, dtype=torch.float64, requires_grad=True)
    r = gendr.Renderer("logistic", gendr.tconorm("yager", p=p), tau=tau, image_size=(12, 16), backend=backend,
                       eps=0.0, blend="softmax", gamma=0.05)
    img = r.render(torch.as_tensor(v), f, cam)
    img[..., 3].sum().backward()
    ref_p = torch.tensor(2.0, dtype=torch.float64, requires_grad=True)
    r2 = gendr.Renderer("logistic", gendr.tconorm("yager", p=ref_p), tau=0.08, image_size=(12, 16), backend="torch",
                        eps=0.0, blend=None)
    r2.render(torch.as_tensor(v), f, cam)[..., 3].sum().backward()
    assert tau.grad is not None and float(tau.grad) != 0.0
    np.testing.assert_allclose(float(p.grad), float(ref_p.grad), rtol=1e-10)


@pytest.mark.parametrize("backend", _backends())
def test_float32_render_with_float64_p(backend):
    """A float64 p with float32 vertices: rendered in float32, gradient close to the float64 one."""
    L32, p32 = _render_loss(backend, "dombi", 2.0, grad=True, dtype=torch.float32)
    L32.backward()
    L64, p64 = _render_loss(backend, "dombi", 2.0, grad=True)
    L64.backward()
    assert L32.dtype == torch.float32
    np.testing.assert_allclose(float(p32.grad), float(p64.grad), rtol=1e-3)


def drjit_native_grad(value, specs):
    """∂L/∂θ from the drjit backend with θ = ``value`` given as a Dr.Jit AD array (no torch in the
    loop); ``specs(θ)`` returns (distribution, T-conorm). L is _render_loss's (weights of seed 0)."""
    dr = pytest.importorskip("drjit")
    from drjit.llvm.ad import Float64, TensorXf64
    v, f, cam = _scene()
    theta = Float64(value)
    dr.enable_grad(theta)
    r = gendr.Renderer(*specs(theta), tau=0.08, image_size=(12, 16), backend="drjit", device="llvm", eps=0.0,
                       blend=None)
    img = r.render(TensorXf64(np.ascontiguousarray(v)), f, cam)
    w = np.random.default_rng(0).standard_normal((1, 12, 16, 4))
    dr.backward(dr.sum((img * TensorXf64(w)).array))
    return float(dr.grad(theta)[0])


def test_drjit_native_learnable_p():
    """A Dr.Jit AD array as p (no torch in the loop): dr.grad(p) equals the torch backend's."""
    g = drjit_native_grad(2.0, lambda p: ("logistic", gendr.tconorm("aczel_alsina", p=p)))
    L_t, pt = _render_loss("torch", "aczel_alsina", 2.0, grad=True)
    L_t.backward()
    np.testing.assert_allclose(g, float(pt.grad), rtol=1e-10)


# --- domain -------------------------------------------------------------------------------------
BAD = {"hamacher": -0.5, "frank": 1.0, "yager": 0.0, "aczel_alsina": -1.0, "dombi": 0.0, "schweizer_sklar": 0.5}


@pytest.mark.parametrize("family", sorted(BAD))
def test_bad_tensor_p_at_construction(family):
    with pytest.raises(ParameterError, match=f"p={BAD[family]!r}"):
        gendr.tconorm(family, p=torch.tensor(BAD[family], requires_grad=True))


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("family", sorted(BAD))
def test_bad_tensor_p_at_render_time(backend, family):
    """An optimizer step that leaves the domain is caught at the next render, naming the value."""
    v, f, cam = _scene()
    good = FAMILIES[family][0]
    p = torch.tensor(good, dtype=torch.float64, requires_grad=True)
    r = gendr.Renderer("logistic", gendr.tconorm(family, p=p), tau=0.08, image_size=(6, 8), backend=backend, blend=None)
    r.render(torch.as_tensor(v), f, cam)
    with torch.no_grad():
        p.fill_(BAD[family])
    with pytest.raises(ParameterError, match=rf"tconorm '{family}' parameter p={BAD[family]!r}.*render time"):
        r.render(torch.as_tensor(v), f, cam)


def test_non_scalar_or_nan_p():
    with pytest.raises(ParameterError, match="scalar"):
        gendr.tconorm("yager", p=torch.ones(2))
    with pytest.raises(ParameterError, match="p=nan"):
        gendr.tconorm("yager", p=torch.tensor(float("nan")))


def test_bool_or_foreign_arrays_as_p():
    """A bool tensor was taken as p = 1 (p=True and np.array(True) were refused); a Dr.Jit array
    rendered with the torch backend raised a bare TypeError from float()."""
    dr = pytest.importorskip("drjit")
    from drjit.llvm.ad import Bool, Float64
    for bad in (torch.tensor(True), Bool(True)):
        with pytest.raises(ParameterError, match="must be a real number"):
            gendr.tconorm("yager", p=bad)
    with pytest.raises(ParameterError, match="must be a real number"):
        gendr.distribution("gamma", shape=torch.tensor(True))
    p = Float64(2.0)
    dr.enable_grad(p)
    v, f, cam = _scene()
    r = gendr.Renderer("logistic", gendr.tconorm("yager", p=p), tau=0.08, image_size=8, backend="torch")
    with pytest.raises(ParameterError, match="parameter p is a Float64: the torch backend takes"):
        r.render(torch.as_tensor(v), f, cam)


def test_learnable_label_and_plain_floats_unchanged():
    p = torch.tensor(2.5, requires_grad=True)
    t = gendr.tconorm("dombi", p=p)
    assert t.label() == "dombi(p=2.5)" and set(t.learnable) == {"p"} and t.learnable["p"] is p
    assert gendr.tconorm("dombi", p=2.5).learnable == {}
    with torch.no_grad():
        p.fill_(3.0)
    assert t.refreshed().label() == "dombi(p=3)"


@pytest.mark.parametrize("family,p0", [("yager", 1.0), ("yager", 2.0), ("dombi", 1.0), ("aczel_alsina", 0.5)])
def test_learnable_p_keeps_the_x_gradients(family, p0):
    """∂A/∂x_k with a learnable p equals the float setting's, also at x = 0 (yager p = 1: slope 1)."""
    from gendr_torch.ops import torch_ops as ops
    grads = []
    for p in (p0, torch.tensor(p0, dtype=torch.float64, requires_grad=True)):
        x = torch.tensor([0.0, 0.0, 0.3, 0.7], dtype=torch.float64, requires_grad=True)
        y = torch.tensor([0.0, 0.2, 0.0, 0.1], dtype=torch.float64)
        gendr.tconorm(family, p=p).aggregate(ops, [x, y]).sum().backward()
        grads.append(x.grad.numpy())
    np.testing.assert_allclose(grads[1], grads[0], rtol=1e-12, atol=0)


@pytest.mark.parametrize("backend", _backends())
def test_validation_suite_checks_p_of_every_family(backend):
    """gendr validate's gradient check covers ∂/∂p: one quick instance per parametric family."""
    gc = pytest.importorskip("gendr_validation.gradcheck")
    insts = [i for i in gc.select_instances("quick") if gc.has_spec_param(i, "p")]
    assert {i.tconorm.name for i in insts} == set(FAMILIES)
    adapter = gc.ADAPTERS[backend]()
    for inst in insts:
        (r,), _ = gc.check_instance(adapter, inst, params=("p",))
        assert r.param == "p" and r.passed, (inst.name, r.pixel_mean, r.pixel_max, r.loss_err)


# --- powers at the ends of the float range --------------------------------------------------------

@pytest.mark.parametrize("learnable", [False, True])
@pytest.mark.parametrize("family", ["yager", "dombi", "aczel_alsina"])
def test_drjit_powers_near_the_smallest_float64(family, learnable):
    """Dr.Jit's power (exp2 inside) returns −inf for results in [2^−1024, 2^−1023.5) in float64 (LLVM):
    one face whose x^p landed there made a pixel's generator sum −inf and its alpha 0 (dombi, p = 3:
    0.044 → 0). The aggregate of 0.3 with x = 2^(k/p), k = −1030 … −1018, is NumPy's to 1e-14."""
    dr = pytest.importorskip("drjit")
    from drjit.llvm.ad import Float64
    from gendr_drjit.ops import DrJitOps
    p0 = 3.0 if learnable else 2.5  # a float 3.0 multiplies (exact); learnable or 2.5: exp and log
    p = Float64(p0)
    if learnable:
        dr.enable_grad(p)
    x = 2.0 ** (np.linspace(-1030.0, -1018.0, 97) / p0)
    other = np.full_like(x, 0.3)
    got = gendr.tconorm(family, p=p if learnable else p0).aggregate(DrJitOps(Float64), [Float64(x), Float64(other)])
    ref = gendr.tconorm(family, p=p0).aggregate(numpy_ops, [x, other])
    np.testing.assert_allclose(np.array(dr.detach(got)), ref, rtol=1e-14, atol=0)


@pytest.mark.parametrize("learnable", [False, True])
@pytest.mark.parametrize("backend", _backends())
def test_overflowing_inverse_slope_with_zero_weight_is_not_nan(backend, learnable):
    """aczel_alsina(p = 30): the inverse s^(1/30) has slope s^(−29/30)/30, +inf at the s ~ 1e-320 of
    pixels far outside a Gaussian render. torch's pow backward multiplied it by those pixels' zero
    weight: 0·inf = NaN, in every vertex gradient and in ∂/∂p. The loss reads one interior pixel's
    alpha; its ∂/∂p, ~1.5e-8 (at p = 30 the aggregate is nearly the max), matches finite differences
    to 1e-11: their round-off, ~1e-16·|L|/h with h = 3e-4, is ~2e-13."""
    v, f, cam = _scene()

    def loss(p, grad=False):
        pt = torch.tensor(float(p), dtype=torch.float64, requires_grad=grad and learnable)
        vt = torch.tensor(v, dtype=torch.float64, requires_grad=grad)
        r = gendr.Renderer("gaussian", gendr.tconorm("aczel_alsina", p=pt if learnable else p), tau=0.08,
                           image_size=(12, 16), backend=backend, eps=0.0, blend=None)
        return r.render(vt, f, cam)[0, 5, 8, 3], vt, pt

    L, vt, pt = loss(30.0, grad=True)
    L.backward()
    assert torch.isfinite(vt.grad).all() and float(vt.grad.abs().max()) > 0
    if learnable:
        fd = richardson(lambda s: float(loss(30.0 + s)[0]), _step(30.0))[0]
        assert np.isfinite(float(pt.grad)) and abs(float(pt.grad) - fd) <= 1e-11, (float(pt.grad), fd)
