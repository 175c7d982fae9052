"""Autograd at the edges of what a render supports: second derivatives, float32 sums that turn
subnormal, and NumPy inputs torch cannot wrap as they are (reversed strides, big-endian)."""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import gendr  # noqa: E402

FACES = torch.tensor([[0, 1, 2], [3, 4, 5]])
CAM = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=40.0)


def _verts(dtype=torch.float64):
    return torch.tensor([[-0.5, -0.4, 0.0], [0.6, -0.5, 0.0], [0.05, 0.55, 0.0],
                         [-0.2, -0.1, -0.3], [0.8, 0.1, -0.3], [0.3, 0.7, -0.3]], dtype=dtype)


def _backends():
    import importlib.util
    return ["torch"] + (["drjit"] if importlib.util.find_spec("drjit") else [])


@pytest.mark.parametrize("backend", _backends())
def test_double_backward_through_alpha_is_refused(backend):
    """The alpha paths have analytic first derivatives only. Under create_graph=True the gradient
    came back with a graph whose own derivative autograd took as 0 for that part: a Hessian-vector
    product of sum(alpha·w) was 20-50 % off, silently (torch's once_differentiable attaches its
    error only where the incoming gradient requires grad). Now NotImplementedError."""
    r = gendr.Renderer("logistic", "probabilistic", tau=0.05, image_size=8, blend=None, backend=backend)
    v = _verts().requires_grad_(True)
    loss = r.render(v, FACES, CAM)[..., 3].sum()
    with pytest.raises(NotImplementedError, match="first derivatives only"):
        torch.autograd.grad(loss, v, create_graph=True)
    (g,) = torch.autograd.grad(r.render(v, FACES, CAM)[..., 3].sum(), v)  # first order: as before
    assert torch.isfinite(g).all() and float(g.abs().max()) > 0


def test_torch_softmax_rgb_hessian_vector_product():
    """A loss on the softmax RGB alone never reaches the alpha path (its incoming gradient is a
    constant 0), so torch's second derivatives stay available there and are right: the
    Hessian-vector product equals central differences of the gradient (h = 1e-5, float64;
    truncation ~h²·|f''''| and round-off ~1e-16·|g|/h, both < 1e-8 relative here), to 1e-6."""
    r = gendr.Renderer("logistic", "probabilistic", tau=0.05, image_size=8, blend="softmax", gamma=0.05)
    cols = torch.as_tensor(np.random.default_rng(0).random((6, 3)))
    direction = torch.as_tensor(np.random.default_rng(1).standard_normal((6, 3)))

    def grad(v, create_graph=False):
        v = v.clone().requires_grad_(True)
        (g,) = torch.autograd.grad(r.render(v, FACES, CAM, vertex_colors=cols)[..., 0].sum(), v,
                                   create_graph=create_graph)
        return v, g
    v, g = grad(_verts(), create_graph=True)
    (hv,) = torch.autograd.grad((g * direction).sum(), v)
    h = 1e-5
    fd = (grad(_verts() + h / 2 * direction)[1] - grad(_verts() - h / 2 * direction)[1]) / h
    assert float((hv - fd).abs().max()) <= 1e-6 * float(fd.abs().max()), float((hv - fd).abs().max())
    assert float(fd.abs().max()) > 0


def test_torch_softmax_rgb_second_derivatives_refused_for_gamma():
    """Gamma's CDF (a series) carries a first derivative only (ops.with_derivative), so even the
    softmax RGB has no second derivative with a gamma distribution: NotImplementedError, as
    docs/conventions.md says, never a Hessian-vector product that takes that part as 0."""
    r = gendr.Renderer(gendr.distribution("gamma", shape=2.0), "probabilistic", tau=0.05, image_size=8,
                       blend="softmax", gamma=0.05)
    v = _verts().requires_grad_(True)
    cols = torch.as_tensor(np.random.default_rng(0).random((6, 3)))
    rgb = r.render(v, FACES, CAM, vertex_colors=cols)[..., 0].sum()
    with pytest.raises(NotImplementedError, match="first derivatives only"):
        torch.autograd.grad(rgb, v, create_graph=True)


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("name", ["yager", "aczel_alsina", "dombi"])
def test_float32_large_p_sums_give_finite_gradients(backend, name):
    """float32 and p = 20: a pixel's generator sum S can be subnormal (~4e-42), where
    dA/dS = S^(1/p − 1)/p overflows: torch's vertex gradients were NaN (Dr.Jit's kernels flush S to
    0). A subnormal S now counts as 0 in both backends. (Their values stay float32's: x^20
    underflows, 3 % of the largest gradient from float64 here, documented in gendr.tconorms.)"""
    v = _verts(torch.float32).requires_grad_(True)
    r = gendr.Renderer("logistic", gendr.tconorm(name, p=20.0), tau=0.05, image_size=16, blend=None, backend=backend)
    img = r.render(v, FACES, CAM)
    w = torch.randn(img.shape, generator=torch.Generator().manual_seed(0))
    (img * w).sum().backward()
    assert torch.isfinite(v.grad).all() and float(v.grad.abs().max()) > 0


@pytest.mark.parametrize("backend", _backends())
def test_numpy_inputs_with_reversed_strides_or_big_endian(backend):
    """np.flip'd vertices and colours and a reversed camera eye raised torch's raw ValueError
    ("At least one stride ... is negative"); big-endian float64 vertices ('>f8') were refused as not
    float64 by both backends, and torch refused a big-endian camera ("byte order different from the
    native byte order") where Dr.Jit rendered it. Each now renders exactly as its native, contiguous
    copy."""
    V = _verts().numpy()
    C = np.random.default_rng(0).random((6, 3))
    r = gendr.Renderer("logistic", "probabilistic", tau=0.05, image_size=8, backend=backend)
    want = r.to_numpy(r.render(V, FACES.numpy(), CAM, vertex_colors=C))
    got = {
        "flipped": r.render(np.flip(np.flip(V, 0), 0), FACES.numpy(), CAM, vertex_colors=np.flip(C[::-1], 0)),
        "big-endian": r.render(V.astype(">f8"), FACES.numpy(), CAM, vertex_colors=C.astype(">f8")),
        "reversed eye": r.render(V, FACES.numpy(), gendr.PerspectiveCamera(eye=np.array([3.0, 0.0, 0.0])[::-1],
                                                                          fov_y=40.0), vertex_colors=C),
        "big-endian camera": r.render(V, FACES.numpy(), gendr.PerspectiveCamera(eye=np.array([0.0, 0.0, 3.0], ">f8"),
                                                                                fov_y=np.array(40.0, ">f8")), vertex_colors=C),
    }
    for tag, img in got.items():
        np.testing.assert_array_equal(r.to_numpy(img), want, err_msg=tag)
