"""Render benchmark: JSON with median and spread, peak extra memory, versions and machine.

    .venv/bin/python benchmarks/bench_render.py --out out/bench_torch.json            # default cases
    .venv/bin/python benchmarks/bench_render.py --case large --repeats 1              # 1024², 20,480 faces

Cases (DESIGN/issue 2): icosphere subdivision 3 (1,280 faces) at 256×256, logistic + probabilistic,
τ = 0.01, eps = 1e-4, silhouette only (blend=None, as PyTorch3D's soft silhouette), forward and
forward+backward (loss = alpha.sum(), gradient w.r.t. vertices). "large": subdivision 5 (20,480
faces) at 1024×1024, same settings.

Peak extra memory: measured in a fresh subprocess per case and mode, as the resident-set
high-water mark (Linux /proc/self/status VmHWM) during the first call minus the resident set just
before it (after imports and scene set-up). A fresh process matters: after a warm-up call the C
allocator keeps freed pages, which would hide the peak.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import gendr
from gendr.scenes import icosphere

CASES = {
    "default": dict(subdivisions=3, size=256),
    "large": dict(subdivisions=5, size=1024),
}


def _status_kb(field):
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def _reset_peak():
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def measure(fn, repeats):
    """Seconds per call (list), after one warm-up call."""
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return times


def peak_extra_mb(backend, name, mode, threads):
    """Run one call of ``mode`` in a fresh interpreter and return its peak extra RSS in MB."""
    cmd = [sys.executable, __file__, "--backend", backend, "--threads", str(threads), "--memory-probe", name, mode]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])["peak_extra_mb"]


def summary(times):
    ms = [1000.0 * t for t in times]
    return {"median_ms": statistics.median(ms), "min_ms": min(ms), "max_ms": max(ms),
            "stdev_ms": statistics.stdev(ms) if len(ms) > 1 else 0.0, "repeats": len(ms)}


def machine():
    cpu = platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((l.split(":", 1)[1].strip() for l in f if l.startswith("model name")), cpu)
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).parent).stdout.strip()
    except OSError:
        commit = ""
    return {"cpu": cpu, "cores": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version(),
            "numpy": np.__version__, "gendr": gendr.__version__, "git_commit": commit}


def setup(backend, name, threads):
    """(forward, forward_backward, info) callables of one case."""
    import torch  # only the torch backend exists so far; inputs are torch tensors for it
    torch.set_num_threads(threads)
    cfg = CASES[name]
    mesh = icosphere(cfg["subdivisions"])
    verts = torch.tensor(mesh.vertices, dtype=torch.float32)
    faces = torch.tensor(mesh.faces)
    cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=60.0)
    r = gendr.Renderer("logistic", "probabilistic", tau=0.01, image_size=cfg["size"], eps=1e-4,
                       blend=None, backend=backend)

    def forward():
        with torch.no_grad():
            return r.render(verts, faces, cam)

    def forward_backward():
        v = verts.clone().requires_grad_(True)
        r.render(v, faces, cam)[..., 3].sum().backward()
        return v.grad

    info = {"case": name, "backend": backend, "faces": int(faces.shape[0]), "image_size": cfg["size"],
            "instance": "logistic|probabilistic", "tau": 0.01, "eps": 1e-4, "blend": None, "threads": threads,
            "versions": {"torch": torch.__version__}}
    return {"forward": forward, "forward_backward": forward_backward}, info


def run_case(backend, name, repeats, threads):
    modes, out = setup(backend, name, threads)
    out["alpha_sum"] = float(modes["forward"]()[..., 3].sum())
    for label, fn in modes.items():
        out[label] = summary(measure(fn, repeats)) | {"peak_extra_mb": peak_extra_mb(backend, name, label, threads)}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backend", default="torch")
    ap.add_argument("--case", choices=sorted(CASES), action="append", help="default: the 'default' case")
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--out", type=Path, help="write the JSON here (also printed)")
    ap.add_argument("--memory-probe", nargs=2, metavar=("CASE", "MODE"), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.memory_probe:
        modes, _ = setup(a.backend, a.memory_probe[0], a.threads)
        rss0 = _status_kb("VmRSS")
        _reset_peak()
        modes[a.memory_probe[1]]()
        print(json.dumps({"peak_extra_mb": (_status_kb("VmHWM") - rss0) / 1024.0}))
        return 0
    result = {"machine": machine(), "results": [run_case(a.backend, c, a.repeats, a.threads) for c in (a.case or ["default"])]}
    text = json.dumps(result, indent=2)
    print(text)
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(text + "\n")


if __name__ == "__main__":
    sys.exit(main())
