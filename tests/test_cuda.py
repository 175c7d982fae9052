"""CUDA: both backends on a GPU give the CPU's images and gradients (float64, 1e-9).

Runs only where a CUDA device is present (torch.cuda for the torch backend, Dr.Jit's CUDA variant
for the drjit backend); on a CPU-only machine the module reports itself skipped. The reference is
the torch backend on the CPU; the scene and instances are the parity tests'.
"""
from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")
import gendr  # noqa: E402
from test_renderer_reference import (FACES, FACES_SOFTMAX, H, W, ZERO_AREA, make_camera, scene_vertices,  # noqa: E402
                                     vertex_colors)

TOL = 1e-9


def _drjit_cuda():
    try:
        import drjit as dr
    except ImportError:
        return False
    return dr.has_backend(dr.JitBackend.CUDA)


CASES = [(("logistic", {}), ("probabilistic", {}), None, 1e-3),
         (("cauchy", {}), ("einstein", {}), None, 0.0),
         (("gamma", {"shape": 0.5, "reversed": True}), ("yager", {"p": 2.0}), None, 1e-4),
         (("gaussian", {"squared": True}), ("max", {}), "softmax", 1e-3),
         (("logistic", {}), ("probabilistic", {}), "hard", 1e-3)]


def run(backend, device, case, freeze=False):
    (dn, dkw), (tn, tkw), blend, eps = case
    dist = gendr.distribution(dn, **dkw)
    v = scene_vertices().to(device).requires_grad_(True)
    tau = torch.tensor(0.012 if dist.squared else 0.1, dtype=torch.float64, device=device, requires_grad=True)
    cam, params = make_camera("perspective", torch.float64)
    faces = (FACES_SOFTMAX if blend == "softmax" else FACES).to(device)
    kw = {"vertex_colors": vertex_colors(torch.float64).to(device).requires_grad_(True)} if blend else {}
    opts = {"device": "cuda" if device == "cuda" else "llvm", "freeze": freeze} if backend == "drjit" else {}
    r = gendr.Renderer(dist, gendr.tconorm(tn, **tkw), tau=tau, image_size=(H, W), eps=eps, blend=blend,
                       backend=backend, **opts)
    img = r.render(v, faces, cam, **kw)
    assert img.device.type == device
    w = torch.randn(img.shape, generator=torch.Generator().manual_seed(5), dtype=torch.float64).to(device)
    inputs = [v, tau, *kw.values()]
    grads = torch.autograd.grad((img * w).sum(), inputs, allow_unused=True)
    return img.detach().cpu(), [None if g is None else g.cpu() for g in grads]


def _close(a, b, skip_vertices=None):
    """Images to TOL, gradients to TOL relative to the largest; ``skip_vertices``: rows of the
    vertex gradient (the first) compared only for being finite."""
    assert float((a[0] - b[0]).abs().max()) <= TOL
    for i, (ga, gb) in enumerate(zip(a[1], b[1])):
        assert (ga is None) == (gb is None)
        if ga is not None:
            if i == 0 and skip_vertices is not None:
                assert bool(ga[:, skip_vertices].isfinite().all())
                keep = torch.ones(ga.shape[1], dtype=torch.bool)
                keep[skip_vertices] = False
                ga, gb = ga[:, keep], gb[:, keep]
            assert float((ga - gb).abs().max()) <= TOL * max(1.0, float(gb.abs().max()))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device for torch")
@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c[0][0]}|{c[1][0]}|{c[2]}")
def test_torch_backend_on_cuda_matches_cpu(case):
    _close(run("torch", "cuda", case), run("torch", "cpu", case))


@pytest.mark.skipif(not (_drjit_cuda() and torch.cuda.is_available()), reason="no CUDA device for Dr.Jit and torch")
@pytest.mark.parametrize("freeze", [False, True])
@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c[0][0]}|{c[1][0]}|{c[2]}")
def test_drjit_cuda_variant_matches_cpu(case, freeze):
    # The zero-area face's vertices: its orientation is the sign of a cross product that is exactly
    # 0 on the CPU; Dr.Jit's CUDA kernels fuse multiply-adds (FMA), whose single rounding leaves a
    # tiny area of either sign. The gradient jumps there (measured: up to 0.7 of its largest
    # entry); its image does not (coverage of a segment either way).
    _close(run("drjit", "cuda", case, freeze), run("torch", "cpu", case), skip_vertices=ZERO_AREA)
