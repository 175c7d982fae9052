"""Probe: what ``torch.compile`` (Inductor, C++ on CPU) would buy the torch backend's per-pair chain.

Not used by the renderer. Times the two per-pair chains of ``gendr_torch.raster`` on one block of
pairs (the 256² / 1,280-face benchmark render has 6 blocks of ~262k pairs), eager vs compiled
(``dynamic=True``: block shapes vary), with an empty Inductor cache so the first call shows the
cold compile time a fresh machine pays:

* forward: signed distance → x = d/τ → (F, log(1 − F)) → generator g (what the forward sums);
* backward: tracked signed distance (nearest edge, its parameter t, unit vector) and ∂g/∂d per pair
  (eager: autograd as the backward's ``local_grad``; compiled: ``torch.func.jvp``, elementwise).

    .venv/bin/python benchmarks/compile_probe.py --out out/compile_probe.json [--dist logistic]

JSON: per chain and mode the median / min / max / stdev over ``--repeats`` calls (ms), the first
call (s), the largest difference to eager, versions, machine, load average, git commit.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

import torch


class _Block:
    """The parts of a raster block that signed_distance reads: pixel abscissae [R, W], ordinates [R, 1]."""

    def __init__(self, px, py):
        self._px, self.py = px, py

    def px(self):
        return self._px


def _inputs(rows, width, seed=0):
    """Random faces (edge_table rows of triangles around the pixels) and pixel coordinates."""
    from gendr_torch.raster import edge_table
    g = torch.Generator().manual_seed(seed)
    cx, cy = torch.rand(rows, 1, generator=g) * 2 - 1, torch.rand(rows, 1, generator=g) * 2 - 1
    X = cx + 0.05 * torch.randn(rows, 3, generator=g)
    Y = cy + 0.05 * torch.randn(rows, 3, generator=g)
    geom = edge_table(X, Y)  # (either orientation: the table carries it)
    px = cx + (torch.arange(width) - width / 2) / 128.0
    return geom, px, cy + 0.01


def _time(fn, repeats):
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return out, {"first_call_s": first, "median_ms": statistics.median(times), "min_ms": min(times),
                 "max_ms": max(times), "stdev_ms": statistics.stdev(times) if len(times) > 1 else 0.0}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dist", default="logistic")
    ap.add_argument("--tconorm", default="probabilistic")
    ap.add_argument("--rows", type=int, default=8192)
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = tempfile.mkdtemp(prefix="inductor-")  # cold: nothing cached
    torch.set_num_threads(a.threads)
    import gendr
    from gendr_torch.ops import torch_ops as ops
    from gendr_torch.raster import signed_distance
    dist, tcn = gendr.distribution(a.dist), gendr.tconorm(a.tconorm)
    tau = torch.tensor(0.01)
    geom, px, py = _inputs(a.rows, a.width)

    def forward(geom, px, py, tau):
        d = signed_distance(geom, 3, _Block(px, py))
        p, log1m = dist.cdf_and_log_sf(ops, dist.argument(ops, d, tau))
        return tcn.generator(ops, p, log1m)

    def backward_eager(geom, px, py, tau):
        d, k, t, ux, uy = signed_distance(geom, 3, _Block(px, py), track=True)
        with torch.enable_grad():
            d_ = d.detach().requires_grad_(True)
            p, log1m = dist.cdf_and_log_sf(ops, dist.argument(ops, d_, tau))
            gd, = torch.autograd.grad(tcn.generator(ops, p, log1m), d_, torch.ones_like(d_))
        return gd, k, t, ux, uy

    def backward_jvp(geom, px, py, tau):
        d, k, t, ux, uy = signed_distance(geom, 3, _Block(px, py), track=True)

        def g_of(dd):
            p, log1m = dist.cdf_and_log_sf(ops, dist.argument(ops, dd, tau))
            return tcn.generator(ops, p, log1m)
        _, gd = torch.func.jvp(g_of, (d,), (torch.ones_like(d),))
        return gd, k, t, ux, uy

    args = (geom, px, py, tau)
    rows = []
    for chain, eager, compiled_src in (("forward", forward, forward), ("backward", backward_eager, backward_jvp)):
        with torch.no_grad():
            ref, stats = _time(lambda: eager(*args), a.repeats)
            rows.append({"chain": chain, "mode": "eager", **stats})
            try:
                fn = torch.compile(compiled_src, dynamic=True)
                out, stats = _time(lambda: fn(*args), a.repeats)
                refs = ref if isinstance(ref, tuple) else (ref,)
                outs = out if isinstance(out, tuple) else (out,)
                diff = max(float((o - r).abs().max()) for o, r in zip(outs, refs))
                rows.append({"chain": chain, "mode": "compiled", **stats, "max_abs_diff_vs_eager": diff})
            except Exception as e:  # a machine without a working C++ toolchain, an unsupported op
                rows.append({"chain": chain, "mode": "compiled", "error": f"{type(e).__name__}: {str(e)[:500]}"})
    for r in rows:
        print(json.dumps(r))
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    except OSError:
        commit = None
    with open("/proc/loadavg") as f:
        load = [float(x) for x in f.read().split()[:3]]
    result = {"benchmark": "compile_probe", "pairs_per_block": a.rows * a.width, "dist": a.dist,
              "tconorm": a.tconorm, "threads": a.threads, "dtype": "float32", "results": rows,
              "versions": {"torch": torch.__version__, "python": platform.python_version()},
              "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform()},
              "loadavg_after": load, "git_commit": commit}
    if a.out:
        os.makedirs(os.path.dirname(a.out) or ".", exist_ok=True)
        with open(a.out, "w") as f:
            json.dump(result, f, indent=1)
    return result


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
