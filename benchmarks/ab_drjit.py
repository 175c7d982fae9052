"""Interleaved A/B of two versions of the Dr.Jit rasterizer in one process (for shared, noisy machines).

    git show HEAD~1:backends/gendr_drjit/raster.py > /tmp/raster_base.py   # a recent version: below
    .venv/bin/python benchmarks/ab_drjit.py /tmp/raster_base.py --tau 0.01 --steps 14
    .venv/bin/python benchmarks/ab_drjit.py /tmp/raster_base.py --tau 0.003 --threads 2 --steps 20
    .venv/bin/python benchmarks/ab_drjit.py /tmp/raster_base.py --dist cauchy --steps 3 --target paper:airplane.obj

The other file must take the calls of the current backend: one from before an interface change
fails at its first call (76367e8's: "'Types' object has no attribute 'device'"); compare such
versions with ``ab_render.py``, which alternates processes of two source trees.

One shape step of the paper protocol (``gendr_experiments.shape.ShapeProblem``: 24 views at 64², the
1,280-face template; by default towards the built-in ``airplane``, as ``bench_step.py``), with
unfrozen renders: the other module replaces ``gendr_drjit.backend.raster`` on alternate steps, and
each step traces its renders from the module it gets (Dr.Jit's kernel cache makes that cheap after
the first steps). The machine's speed drifts by ±20 % within minutes, which alternating processes
only average out over many runs; alternate steps in one process see the same drift. (Two *frozen*
problems side by side in one process are no A/B: both ran at one speed, fast in one process, slow in
the next.)

Prints and writes (``--out``) per version: the two largest kernels of a step (the forward and the
backward loop), all kernels (Dr.Jit's kernel history) and the step's wall time, each as median, min,
max and stdev over ``--steps`` steps; and, measured first at the same mesh, the largest differences
of the image and of the vertex gradient between the versions (0 and 0: bit-identical, which with
several threads only holds for the image: the order of scatter-adds across threads varies).
"""
from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

import gendr_drjit.backend as backend
import gendr_drjit.raster as current
from ab_raster import load
from bench_render import machine
from bench_step import CASES, versions
from gendr_experiments.common import set_threads
from gendr_experiments.shape import ShapeProblem


def use(module, renderer):
    """Make the backend render with ``module`` (its own Types/ops caches: a module's Types may differ)."""
    backend.raster = module
    be = renderer.backend
    be._types.clear()


def image_and_gradient(prob):
    v = prob.model().detach().requires_grad_(True)
    img = prob.renderer.render(v, prob.model.faces, prob.camera)
    w = torch.randn(img.shape, generator=torch.Generator().manual_seed(3), dtype=img.dtype)
    (g,) = torch.autograd.grad((img * w).sum(), [v])
    return img.detach(), g


def stats(xs):
    return {"median_ms": statistics.median(xs), "min_ms": min(xs), "max_ms": max(xs),
            "stdev_ms": statistics.stdev(xs) if len(xs) > 1 else 0.0, "steps": len(xs)}


def _spec(text):
    """A distribution or T-conorm for the problem's config: a name, or a JSON object of keyword arguments."""
    return json.loads(text) if text.lstrip().startswith("{") else text


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("other", help="path of the other raster.py (e.g. from git show REV:backends/gendr_drjit/raster.py)")
    ap.add_argument("--dist", default="logistic", type=_spec,
                    help='a name, or JSON keyword arguments: \'{"name": "levy", "reversed": true}\'')
    ap.add_argument("--tconorm", default="probabilistic", type=_spec, help='a name, or JSON: \'{"name": "dombi", "p": 0.5}\'')
    ap.add_argument("--tau", type=float, default=0.01, help="width (renderer τ = width² for squared distributions)")
    ap.add_argument("--target", default="airplane", help="built-in name or paper:airplane.obj (user-supplied data)")
    ap.add_argument("--threads", type=int, default=1, help="Dr.Jit threads (torch keeps one)")
    ap.add_argument("--steps", type=int, default=10, help="timed steps per version")
    ap.add_argument("--out", type=Path, help="JSON file")
    a = ap.parse_args(argv)

    import drjit as dr
    set_threads("drjit", a.threads)
    other = load(a.other, "gendr_drjit._raster_other")
    cfg = dict(CASES["shape"][1], target=a.target, tau=a.tau, eps=1e-6, cutoff=100.0)
    prob = ShapeProblem(cfg, protocol="paper", backend="drjit", distribution=a.dist, tconorm=a.tconorm,
                        backend_options={"freeze": False})
    versions_ = {"current": current, "other": other}
    ref = {}
    threads = dr.thread_count()
    dr.set_thread_count(1)  # the difference check on one thread: a fixed order of the sums
    for name, module in versions_.items():
        use(module, prob.renderer)
        ref[name] = image_and_gradient(prob)
    dr.set_thread_count(threads)
    diff = {"image_max_abs": float((ref["current"][0] - ref["other"][0]).abs().max()),
            "vertex_gradient_max_abs": float((ref["current"][1] - ref["other"][1]).abs().max())}
    for name, module in versions_.items():  # warm-up: trace and compile both
        use(module, prob.renderer)
        prob.step(0)
    res = {name: {"loop_a": [], "loop_b": [], "kernels": [], "step": []} for name in versions_}
    for i in range(a.steps):
        for name in (("current", "other") if i % 2 == 0 else ("other", "current")):
            use(versions_[name], prob.renderer)
            dr.set_flag(dr.JitFlag.KernelHistory, True)
            dr.kernel_history()
            t = time.perf_counter()
            prob.step(1 + i)
            wall = 1000.0 * (time.perf_counter() - t)
            ks = sorted((k.get("execution_time", 0.0) for k in dr.kernel_history()), reverse=True)
            dr.set_flag(dr.JitFlag.KernelHistory, False)
            r = res[name]
            r["loop_a"].append(ks[0])
            r["loop_b"].append(ks[1])
            r["kernels"].append(sum(ks))
            r["step"].append(wall)
    use(current, prob.renderer)
    out = {"machine": machine(), "versions": versions(), "other": a.other,
           "case": {"distribution": a.dist, "tconorm": a.tconorm, "tau": a.tau, "target": a.target,
                    "threads": a.threads, "protocol": "paper", "freeze": False},
           "difference": diff,
           "results": {name: {k: stats(v) for k, v in r.items()} for name, r in res.items()}}
    for name, r in out["results"].items():
        print(f"{name:8s} loops {r['loop_a']['median_ms']:.2f} + {r['loop_b']['median_ms']:.2f} ms, "
              f"kernels {r['kernels']['median_ms']:.2f} ms, step {r['step']['median_ms']:.2f} ms "
              f"(medians of {a.steps})")
    print(f"difference: image {diff['image_max_abs']:.3g}, vertex gradient {diff['vertex_gradient_max_abs']:.3g}")
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
