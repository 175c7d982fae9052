"""Interleaved A/B of two versions of the torch rasterizer in one process (for shared, noisy machines).

    git show 02f31c3:backends/gendr_torch/raster.py > /tmp/raster_base.py
    .venv/bin/python benchmarks/ab_raster.py /tmp/raster_base.py --threads 1 --n 20 [--fwd]
    .venv/bin/python benchmarks/ab_raster.py /tmp/raster_base.py --threads 1 --n 6 --dist cauchy --size 64 --batch 4
    .venv/bin/python benchmarks/ab_raster.py /tmp/raster_base.py --threads 1 --shape --n 8

The other module replaces ``gendr_torch.backend.raster`` on alternate calls. Reports the largest
image and gradient differences, then median wall and CPU time per call (CPU time of this process:
less disturbed by other processes when running on one thread). Scene: the benchmark's
(``icosphere(3)`` from distance 3, logistic + probabilistic, τ = 0.01, eps = 1e-4, blend=None), loss
(alpha · fixed randn).sum(); ``--batch N``: N cameras around it. ``--shape``: time per step of
``run_shape(subdivisions=3, image_size=64, views=24)`` (24 views, soft IoU, Adam).
"""
from __future__ import annotations

import argparse
import importlib.util
import math
import statistics
import sys
import time

import torch

import gendr
import gendr_torch.backend as backend
import gendr_torch.raster as current
from gendr.scenes import icosphere


def load(path, name="gendr_torch._raster_other"):
    """The module at ``path``, registered as ``name`` (ab_drjit.py loads a Dr.Jit rasterizer with it)."""
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def scene_call(a):
    mesh = icosphere(3)
    verts, faces = torch.tensor(mesh.vertices, dtype=torch.float32), torch.tensor(mesh.faces)
    if a.batch > 1:
        ang = torch.linspace(0, 2 * math.pi, a.batch + 1)[:-1]
        eye = torch.stack([3 * torch.sin(ang), 0.5 * torch.ones_like(ang), 3 * torch.cos(ang)], 1)
        cam = gendr.PerspectiveCamera(eye=eye, fov_y=60.0)
    else:
        cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=60.0)
    r = gendr.Renderer(a.dist, "probabilistic", tau=0.01, image_size=a.size, eps=1e-4, blend=None, backend="torch")
    w = torch.randn(a.batch, a.size, a.size, generator=torch.Generator().manual_seed(0))

    def call():
        v = verts.clone().requires_grad_(True)
        if a.fwd:
            with torch.no_grad():
                return r.render(v, faces, cam), None
        img = r.render(v, faces, cam)
        (img[..., 3] * w).sum().backward()
        return img, v.grad
    return call


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("other", help="the other raster.py")
    ap.add_argument("--n", type=int, default=15)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--dist", default="logistic")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--batch", type=int, default=1)
    ap.add_argument("--fwd", action="store_true", help="forward only")
    ap.add_argument("--shape", action="store_true", help="time shape-optimisation steps instead")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    mods = {"other": load(a.other), "this": current}
    wall, cpu = {k: [] for k in mods}, {k: [] for k in mods}
    if a.shape:
        from gendr_experiments.shape import run_shape
        for k, m in mods.items():
            backend.raster = m
            stamps = []
            run_shape(subdivisions=3, image_size=64, views=24, steps=a.n, distribution=a.dist,
                      callback=lambda *_: stamps.append((time.perf_counter(), time.process_time())))
            wall[k] = [1000 * (b[0] - p[0]) for p, b in zip(stamps, stamps[1:])]
            cpu[k] = [1000 * (b[1] - p[1]) for p, b in zip(stamps, stamps[1:])]
    else:
        call = scene_call(a)
        out = {}
        for k, m in mods.items():
            backend.raster = m
            out[k] = call()
        print("image max diff", float((out["other"][0] - out["this"][0]).detach().abs().max()))
        if not a.fwd:
            go, gt = out["other"][1], out["this"][1]
            print("gradient max diff", float((go - gt).abs().max()), "relative", float((go - gt).abs().max() / go.abs().max()))
        for i in range(a.n):
            for k in (mods if i % 2 else reversed(list(mods))):
                backend.raster = mods[k]
                c, t = time.process_time(), time.perf_counter()
                call()
                wall[k].append(1000 * (time.perf_counter() - t))
                cpu[k].append(1000 * (time.process_time() - c))
    for k in mods:
        print(f"{k}: wall median {statistics.median(wall[k]):.1f} ms (min {min(wall[k]):.1f}), "
              f"CPU median {statistics.median(cpu[k]):.1f} ms (min {min(cpu[k]):.1f})")


if __name__ == "__main__":
    main()
