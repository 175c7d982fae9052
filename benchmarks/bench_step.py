"""Optimisation-step benchmark: one step of the shape and the pose experiment (render, loss,
backward, Adam), per backend and distribution. JSON like bench_render.py.

    .venv/bin/python benchmarks/bench_step.py --out out/bench_step.json         # every case
    .venv/bin/python benchmarks/bench_step.py --case pose --dist logistic --backend torch --quick
    python3 benchmarks/bench_step.py --device cuda --backend drjit --backend drjit-frozen   # on a GPU

Cases (the steps of ``gendr_experiments.shape.ShapeProblem`` and ``gendr_experiments.pose.PoseProblem``):

* ``shape``: the paper's shape step (§5.1): 24 azimuths 15° apart at elevation 30°, 64×64, camera
  distance 2.732, fov_y 30°, a 1,280-face template (icosphere subdivisions=3) deformed towards the
  built-in ``airplane`` scene; soft IoU + 0.03·Laplacian + 0.0003·flatten; Adam lr 10**-1.5;
  τ = 0.01, eps = 1e-4.
* ``pose``: one pose step (§5.2) on the built-in ``teapot_like`` (2,336 faces) at 64×64, pose
  defaults otherwise (seed 0), at a fixed τ = 1e-3 (tau_start = tau_end), the τ that the default
  schedule 1e-1 -> 1e-7 over 300 steps reaches at about step 100.

Each with the T-conorm probabilistic and the distribution ``logistic`` or ``cauchy`` (heavy tails:
no culling radius, every face reaches every pixel, so its steps are slow), and the backend
``torch``, ``torch-compiled`` (``compile=True``: per-pair chains fused by ``torch.compile``),
``drjit`` (LLVM, float32) or ``drjit-frozen`` (``freeze=True``: renders replayed by
``dr.freeze``). The model, loss and Adam are torch in every case (the drjit backend takes torch
tensors through its torch bridge). ``--threads`` go to the backend that renders; with drjit torch
keeps one thread (``gendr_experiments.common.set_threads``: torch's idle OpenMP workers spin-wait
and take cores from Dr.Jit's kernels), recorded as ``torch_threads``.

Per case: the step time over ``--repeats`` steps after one warm-up step (median, min, max, stdev;
repeats default to 10 for shape (3 for cauchy) and 60 for pose (10 for cauchy)), the step's loss, and the first call, set-up plus first step,
in a fresh process (``setup_ms``, ``first_step_ms``, ``first_call_ms``); for drjit that process has
an empty Dr.Jit kernel cache, for torch-compiled an empty Inductor cache (``first_call_cold``), as
bench_render.py's cold probe. Frozen rows
also give ``frozen_recordings`` (Python traces made in all steps so far: 2 = forward and backward
recorded once). Top level: machine, versions, load average before and after.
"""
from __future__ import annotations

import argparse
import itertools
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

import gendr
from bench_render import emit, machine, measure, run_fresh, summary
from gendr_experiments.common import set_threads
from gendr_experiments.pose import PoseProblem
from gendr_experiments.shape import ShapeProblem

CASES = {
    "shape": (ShapeProblem, dict(target="airplane", views=24, elevation=30.0, image_size=64, distance=2.732,
                                 fov_y=30.0, subdivisions=3, lambda_lap=0.03, lambda_flat=0.0003, lr=10 ** -1.5,
                                 tau=0.01, eps=1e-4)),
    "pose": (PoseProblem, dict(target="teapot_like", image_size=64, tau_start=1e-3, tau_end=1e-3)),
}
BACKENDS = {"torch": ("torch", {}), "torch-compiled": ("torch", {"compile": True}),
            "drjit": ("drjit", {"freeze": False}), "drjit-frozen": ("drjit", {"freeze": True})}
DISTS = ("logistic", "cauchy")
#: timed steps per (case, distribution): cauchy steps take seconds; a pose step a few ms, where 10
#: steps gave medians ±20 % apart on this machine (60 take a quarter of a second)
REPEATS = {("shape", "logistic"): 10, ("shape", "cauchy"): 3, ("pose", "logistic"): 60, ("pose", "cauchy"): 10}


def loadavg():
    with open("/proc/loadavg") as f:
        return [float(x) for x in f.read().split()[:3]]


def versions():
    import drjit
    return {"torch": torch.__version__, "drjit": drjit.__version__, "numpy": np.__version__,
            "python": platform.python_version(), "gendr": gendr.__version__}


def first_call(case, backend, dist, threads, device="cpu"):
    """Build the problem and run its first step: (problem, {"setup_ms", "first_step_ms", "first_call_ms"}).
    ``device="cuda"``: the drjit renders on Dr.Jit's CUDA variant; the model, losses and Adam stay
    on the CPU (as `gendr experiment sweep --device cuda`)."""
    cls, cfg = CASES[case]
    name, options = BACKENDS[backend]
    if device == "cuda":
        options = dict(options, device="cuda")
    set_threads(name, threads)  # drjit: torch keeps 1 thread (its idle workers spin)
    t0 = time.perf_counter()
    prob = cls(cfg, backend=name, distribution=dist, tconorm="probabilistic", backend_options=options)
    t1 = time.perf_counter()
    prob.step(0)
    t2 = time.perf_counter()
    return prob, {"setup_ms": 1000 * (t1 - t0), "first_step_ms": 1000 * (t2 - t1), "first_call_ms": 1000 * (t2 - t0)}


def run_case(case, backend, dist, repeats, threads, device="cpu"):
    # the first call in a fresh process (drjit: with an empty kernel cache), then the steady state here
    cold = BACKENDS[backend][0] == "drjit" or "compile" in BACKENDS[backend][1]
    first = run_fresh(__file__, ["--first-call", case, backend, dist, "--threads", str(threads), "--device", device],
                      cold=cold)
    prob, _ = first_call(case, backend, dist, threads, device)
    counter = itertools.count(1)
    losses = []
    times = measure(lambda: losses.append(prob.step(next(counter))), repeats)  # + 1 warm-up step
    faces = prob.model.faces if case == "shape" else prob.faces
    out = {"case": case, "backend": BACKENDS[backend][0], "device": device, "freeze": bool(BACKENDS[backend][1].get("freeze")),
           "compile": bool(BACKENDS[backend][1].get("compile")),
           "distribution": dist, "tconorm": "probabilistic", "renderer_tau": prob.renderer.settings.tau_value,
           "faces": int(faces.shape[0]), "threads": threads, "torch_threads": torch.get_num_threads(),
           "loss_last": losses[-1]}
    out |= summary(times) | first | {"first_call_cold": cold}
    if out["freeze"]:
        out["frozen_recordings"] = prob.renderer.backend.frozen.n_recordings
    return out | {"config": prob.cfg}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", choices=sorted(CASES), action="append", help="default: all")
    ap.add_argument("--backend", choices=list(BACKENDS), action="append", help="default: all")
    ap.add_argument("--dist", choices=DISTS, action="append", help="default: all")
    ap.add_argument("--repeats", type=int, help="timed steps per case (default: shape 10, cauchy 3; pose 60, cauchy 10; --quick: 1)")
    ap.add_argument("--quick", action="store_true", help="1 timed step per case")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, help="write the JSON here (also printed)")
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                    help="cuda: drjit renders on Dr.Jit's CUDA variant (drjit backends only; model and Adam on the CPU)")
    ap.add_argument("--first-call", nargs=3, metavar=("CASE", "BACKEND", "DIST"), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.first_call:  # (the fresh process of run_case: its backend is in --first-call)
        print(json.dumps(first_call(*a.first_call, a.threads, a.device)[1]))
        return 0
    if a.device == "cuda" and any(not b.startswith("drjit") for b in (a.backend or BACKENDS)):
        ap.error("--device cuda: give drjit backends only (--backend drjit --backend drjit-frozen)")
    result = {"command": " ".join(sys.argv), "machine": machine(), "versions": versions(),
              "loadavg_before": loadavg(), "results": []}
    for case, dist, backend in itertools.product(a.case or CASES, a.dist or DISTS, a.backend or BACKENDS):
        repeats = a.repeats or (1 if a.quick else REPEATS[case, dist])
        result["results"].append(run_case(case, backend, dist, repeats, a.threads, a.device))
    result["loadavg_after"] = loadavg()
    emit(result, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
