"""CUDA: both backends on a GPU give the CPU's images and gradients (float64, 1e-9; float32 and a sweep run
through device="cuda" to float32 accuracy and the single-run noise).

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


@pytest.mark.skipif(not (_drjit_cuda() and torch.cuda.is_available()), reason="no CUDA device for Dr.Jit and torch")
def test_drjit_cuda_float32_from_cpu_tensors():
    """The GPU sweep's setting (`sweep --device cuda`): float32 CPU torch tensors rendered with
    device="cuda"; the image and the gradient come back to the CPU and match LLVM's to float32
    accuracy. Tolerance 2e-5 (absolute for the image, relative to the largest entry for the
    gradient): 10x what an H100 gave on the 1,280-face scene at 256² (1.6e-6 / 1.9e-6; fused
    multiply-adds and another summation order)."""
    from gendr.scenes import icosphere
    mesh = icosphere(3)
    faces = torch.tensor(mesh.faces)
    cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=60.0)
    out = {}
    for device in ("cuda", "llvm"):
        v = torch.tensor(mesh.vertices, dtype=torch.float32, requires_grad=True)
        r = gendr.Renderer("logistic", "probabilistic", tau=0.01, image_size=128, eps=1e-4, blend=None,
                           backend="drjit", device=device)
        img = r.render(v, faces, cam)
        assert img.device.type == "cpu" and img.dtype == torch.float32
        img[..., 3].sum().backward()
        out[device] = img.detach().double(), v.grad.double()
    (ia, ga), (ib, gb) = out["cuda"], out["llvm"]
    assert float((ia - ib).abs().max()) <= 2e-5
    assert float((ga - gb).abs().max()) <= 2e-5 * float(gb.abs().max())


@pytest.mark.skipif(not (_drjit_cuda() and torch.cuda.is_available()), reason="no CUDA device for Dr.Jit and torch")
def test_sweep_run_on_cuda():
    """`run_config(cfg, "cuda")`: a drjit shape run renders on the GPU, keeps the CPU run's key,
    records the device, and reaches the CPU run's metric within the single-run noise (0.03)."""
    pytest.importorskip("gendr_experiments")
    from gendr_experiments.sweep import expand, run_config
    cfg = expand("shape", dict(target="tetrahedron", steps=3, image_size=12, views=2, subdivisions=1, backend="drjit"),
                 instances=[5], axes={"tau": [0.02], "lr": [0.05]})[0]
    gpu, cpu = run_config(cfg, "cuda"), run_config(cfg)
    assert gpu["status"] == "ok" and cpu["status"] == "ok", (gpu.get("error"), cpu.get("error"))
    assert gpu["key"] == cpu["key"] and gpu["provenance"]["device"] == "cuda" and gpu["provenance"]["gpu"]
    assert abs(gpu["metric"] - cpu["metric"]) <= 0.03
