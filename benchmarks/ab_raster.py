"""Interleaved A/B of two versions of the torch rasterizer in one process (for shared, noisy machines).

    git show HEAD~1:backends/gendr_torch/raster.py > /tmp/raster_base.py   # a recent version: below
    .venv/bin/python benchmarks/ab_raster.py /tmp/raster_base.py --threads 1 --n 20 [--fwd]
    .venv/bin/python benchmarks/ab_raster.py /tmp/raster_base.py --threads 1 --n 6 --dist cauchy --size 64 --batch 4
    .venv/bin/python benchmarks/ab_raster.py /tmp/raster_base.py --threads 1 --shape --n 8

The other file must take the calls of the current backend (``raster.render``'s arguments): one
from before an interface change fails at its first call (02f31c3's: "render() takes 6 positional
arguments but 8 were given"). Compare such versions with ``ab_render.py``, which alternates
processes of two source trees.

The other module replaces ``gendr_torch.backend.raster`` on alternate calls (``--shape``: on
alternate steps of one optimisation; its first step, a warm-up, is not timed). Reports the largest
image and gradient differences, then wall and CPU time per call (CPU time of this process: less
disturbed by other processes when running on one thread), median, min, max and stdev; ``--out
FILE``: the same as JSON, with the machine and versions. Scene: the benchmark's
(``icosphere(3)`` from distance 3, logistic + probabilistic, τ = 0.01, eps = 1e-4, blend=None), loss
(alpha · fixed randn).sum(); ``--batch N``: N cameras around it. ``--shape``: time per step of
``run_shape(subdivisions=3, image_size=64, views=24)`` (24 views, soft IoU, Adam).
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
import time
from pathlib import Path

import torch

import gendr
import gendr_torch.backend as backend
import gendr_torch.raster as current
from gendr.scenes import icosphere
from bench_render import machine, summary  # (benchmarks/ is the script's directory: first on sys.path)


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
    ap.add_argument("--out", type=Path, help="write the results here as JSON too")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    mods = {"other": load(a.other), "this": current}
    wall, cpu, diffs = {k: [] for k in mods}, {k: [] for k in mods}, {}
    if a.shape:
        from gendr_experiments.shape import run_shape
        order, last = ["other", "this"], {}

        def step_done(*_):  # the step that just ended ran with order[0]; the next runs with the other
            now = (time.perf_counter(), time.process_time())
            if last:
                wall[order[0]].append(now[0] - last["t"][0])
                cpu[order[0]].append(now[1] - last["t"][1])
            last["t"] = now
            order.reverse()
            backend.raster = mods[order[0]]
        backend.raster = mods[order[0]]
        run_shape(subdivisions=3, image_size=64, views=24, steps=2 * a.n + 1, distribution=a.dist, callback=step_done)
    else:
        call = scene_call(a)
        out = {}
        for k, m in mods.items():
            backend.raster = m
            out[k] = call()
        diffs["image_max_diff"] = float((out["other"][0] - out["this"][0]).detach().abs().max())
        print("image max diff", diffs["image_max_diff"])
        if not a.fwd:
            go, gt = out["other"][1], out["this"][1]
            diffs["gradient_max_diff"] = float((go - gt).abs().max())
            diffs["gradient_max_diff_relative"] = float((go - gt).abs().max() / go.abs().max())
            print("gradient max diff", diffs["gradient_max_diff"], "relative", diffs["gradient_max_diff_relative"])
        for i in range(a.n):
            for k in (mods if i % 2 else reversed(list(mods))):
                backend.raster = mods[k]
                c, t = time.process_time(), time.perf_counter()
                call()
                wall[k].append(time.perf_counter() - t)
                cpu[k].append(time.process_time() - c)
    times = {k: {"wall": summary(wall[k]), "cpu": summary(cpu[k])} for k in mods}
    for k, t in times.items():
        print(f"{k}: wall median {t['wall']['median_ms']:.1f} ms (min {t['wall']['min_ms']:.1f}), "
              f"CPU median {t['cpu']['median_ms']:.1f} ms (min {t['cpu']['min_ms']:.1f})")
    if a.out:
        with open(a.out, "w") as f:
            json.dump({"machine": machine(), "args": {k: str(v) for k, v in vars(a).items()}, **diffs,
                       "times": times}, f, indent=2)


if __name__ == "__main__":
    main()
