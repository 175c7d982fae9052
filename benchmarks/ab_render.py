"""Interleaved A/B timing of two versions of gendr on a machine whose speed drifts.

Prints one JSON line: which version ran (``gendr_drjit``: the path of the imported package), the
machine and versions, and per timing its median, min, max and stdev (``bench_render.summary``).
Run it alternately against an older checkout (a git worktree put first on ``PYTHONPATH``) and the
current one, in one sitting:

    git worktree add /tmp/wt-old 02f31c3
    for i in 1 2 3; do
      PYTHONPATH=/tmp/wt-old:/tmp/wt-old/backends:/tmp/wt-old/experiments .venv/bin/python benchmarks/ab_render.py render 256 3 20
      .venv/bin/python benchmarks/ab_render.py render 256 3 20
    done

``render SIZE SUBDIVISIONS REPEATS``: the Dr.Jit render of bench_render.py (icosphere, logistic +
probabilistic, τ = 0.01, eps = 1e-4, alpha only, 2 threads): medians of forward and forward+backward.
``shape STEPS``: the paper's shape step (24 views at 64², 1,280-face template, drjit) through
``gendr_experiments.shape.run_shape``: wall time per step after two warm-up steps (STEPS >= 3).
"""
from __future__ import annotations

import json
import sys
import time

import numpy as np
import drjit as dr

import gendr
import gendr_drjit
from bench_render import machine, measure, summary  # (benchmarks/ is the script's directory: first on sys.path)


def render_case(size, subdivisions, repeats):
    from drjit.llvm.ad import TensorXf
    from gendr.scenes import icosphere
    mesh = icosphere(subdivisions)
    verts, faces = TensorXf(mesh.vertices.astype(np.float32)), mesh.faces
    cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=60.0)
    r = gendr.Renderer("logistic", "probabilistic", tau=0.01, image_size=size, eps=1e-4, blend=None,
                       backend="drjit", device="llvm")

    def fwd():
        dr.eval(r.render(verts, faces, cam))
        dr.sync_thread()

    def fwd_bwd():
        v = TensorXf(verts)
        dr.enable_grad(v)
        dr.backward(dr.sum(r.render(v, faces, cam)[..., 3].array))
        dr.eval(dr.grad(v))
        dr.sync_thread()

    return {name: summary(measure(fn, repeats)) for name, fn in (("fwd", fwd), ("fwd_bwd", fwd_bwd))}


def shape_case(steps):
    import torch
    from gendr_experiments.shape import run_shape
    torch.set_num_threads(2)
    stamps = []
    run_shape(dict(target="airplane", subdivisions=3, image_size=64, views=24, distance=2.732, fov_y=30.0,
                   lr=10 ** -1.5, steps=steps, backend="drjit", tau=0.01),
              callback=lambda *a: stamps.append(time.perf_counter()))
    # stamps[k]: the end of step k; steps 0 and 1 warm up, so step k >= 2 took stamps[k] − stamps[k − 1]
    return {"step": summary(list(np.diff(stamps[1:])))}


def main(argv):
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="case", required=True)
    r = sub.add_parser("render", help="the Dr.Jit render of bench_render.py")
    for name in ("size", "subdivisions", "repeats"):
        r.add_argument(name, type=int)
    s = sub.add_parser("shape", help="the paper's shape step")
    s.add_argument("steps", type=int)
    a = ap.parse_args(argv)
    if a.case == "shape" and a.steps < 3:
        ap.error(f"shape needs STEPS >= 3 (two warm-up steps, then the timed ones), got {a.steps}")
    dr.set_thread_count(2)
    out = render_case(a.size, a.subdivisions, a.repeats) if a.case == "render" else shape_case(a.steps)
    print(json.dumps({"gendr_drjit": gendr_drjit.__file__, "case": a.case, "args": vars(a), "machine": machine(),
                      "threads": 2, "results": out}))


if __name__ == "__main__":
    main(sys.argv[1:])
