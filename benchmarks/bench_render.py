"""Render benchmark: JSON with median and spread, peak extra memory, versions and machine.

    .venv/bin/python benchmarks/bench_render.py --out out/bench_torch.json            # default cases
    .venv/bin/python benchmarks/bench_render.py --case large --repeats 1              # 1024², 20,480 faces
    .venv/bin/python benchmarks/bench_render.py --backend drjit --out out/bench_drjit.json
    .venv/bin/python benchmarks/bench_render.py --backend torch-compiled --out out/bench_torch_compiled.json

``--backend torch-compiled``: the torch backend with ``compile=True`` (per-pair chains fused by
``torch.compile``); ``first_call_cold_ms`` is then the first call with an empty Inductor cache.

With ``--backend drjit`` the inputs are Dr.Jit tensors (LLVM on CPU, float32) and each call ends with
``dr.sync_thread()`` (launches are asynchronous). Extra fields: ``first_call_cold_ms`` (first call
in a fresh process with an empty Dr.Jit kernel cache: tracing + LLVM compilation;
``first_call_cold_kernels_compiled``, the kernels it wrote to that cache, shows it was empty), per-call kernel
statistics from Dr.Jit's kernel history (kernels launched, kernels compiled = cache misses, summed
kernel execution time), and ``optimization_loop``: 100 forward+backward steps on changing vertices
(a training loop; wall times and kernels compiled), then 5 renders with different τ
(``kernels_compiled_tau_changes``: τ is opaque, so none may compile a kernel; the τ stay on one
side of the face-major switch, a culling radius of 16 px at 256², which changes the backward layout
and so compiles, and records, once by design); ``time_split``: the
median wall time of each mode split into kernel execution and host time (tracing, launches); and
``frozen``: forward, forward+backward, time split and optimisation loop again with
``freeze=True`` (renders replayed by ``dr.freeze``; the loop reports how many recordings, i.e.
Python traces, its 100 steps and its 5 τ changes made: 0 after the first call). ``--no-freeze``
skips that part.

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


def run_fresh(script, args, cold=False):
    """Run ``script args`` in a fresh interpreter; the last line of its output, parsed as JSON.

    ``cold``: with HOME (and the Inductor cache) pointing to an empty directory, so Dr.Jit and
    torch.compile find no cached kernels."""
    import tempfile
    with tempfile.TemporaryDirectory(prefix="gendr-bench-home-") as home:
        env = dict(os.environ, HOME=home, TORCHINDUCTOR_CACHE_DIR=os.path.join(home, "inductor")) if cold else None
        res = subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True, env=env)
    if res.returncode != 0 or not res.stdout.strip():  # say why (check=True would drop the child's stderr)
        raise RuntimeError(f"{script} {' '.join(map(str, args))} exited {res.returncode}: {res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def probe(backend, name, mode, threads, cold=False, device="cpu"):
    """Run one call of ``mode`` in a fresh interpreter: {"peak_extra_mb", "first_call_ms"} (``cold``:
    with an empty Dr.Jit kernel cache, see :func:`run_fresh`)."""
    return run_fresh(__file__, ["--backend", backend, "--threads", str(threads), "--device", device,
                                "--memory-probe", name, mode], cold)


def peak_extra_mb(backend, name, mode, threads):
    """Run one call of ``mode`` in a fresh interpreter and return its peak extra RSS in MB."""
    return probe(backend, name, mode, threads)["peak_extra_mb"]


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
    versions = {}
    for lib in ("torch", "drjit"):  # whichever is installed, whether or not this run used it
        try:
            versions[lib] = __import__(lib).__version__
        except ImportError:
            pass
    return {"cpu": cpu, "cores": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version(),
            "numpy": np.__version__, "gendr": gendr.__version__, "git_commit": commit, "versions": versions}


def _drjit_tensor(device):
    """Dr.Jit's float32 AD tensor type of ``device`` ("llvm" or "cuda")."""
    import importlib
    return importlib.import_module(f"drjit.{device}.ad").TensorXf


def setup(backend, name, threads, freeze=False, device="cpu"):
    """(forward, forward_backward, info) callables of one case. ``device``: "cpu" or "cuda" (torch:
    the inputs' device; drjit: its LLVM or CUDA variant)."""
    if backend == "drjit":
        return setup_drjit(name, threads, freeze=freeze, device="cuda" if device == "cuda" else "llvm")
    import torch  # the torch backend: inputs are torch tensors
    torch.set_num_threads(threads)
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    cfg = CASES[name]
    mesh = icosphere(cfg["subdivisions"])
    verts = torch.tensor(mesh.vertices, dtype=torch.float32, device=device)
    faces = torch.tensor(mesh.faces, device=device)
    cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=60.0)
    r = gendr.Renderer("logistic", "probabilistic", tau=0.01, image_size=cfg["size"], eps=1e-4,
                       blend=None, backend="torch", compile=backend == "torch-compiled")

    def forward():
        with torch.no_grad():
            img = r.render(verts, faces, cam)
        sync()
        return img

    def forward_backward():
        v = verts.clone().requires_grad_(True)
        r.render(v, faces, cam)[..., 3].sum().backward()
        sync()
        return v.grad

    info = {"case": name, "backend": backend, "device": device, "faces": int(faces.shape[0]), "image_size": cfg["size"],
            "instance": "logistic|probabilistic", "tau": 0.01, "eps": 1e-4, "blend": None, "threads": threads,
            "versions": {"torch": torch.__version__}}
    return {"forward": forward, "forward_backward": forward_backward}, info


def setup_drjit(name, threads, tau=0.01, freeze=False, device="llvm"):
    import drjit as dr
    TensorXf = _drjit_tensor(device)
    dr.set_thread_count(threads)
    cfg = CASES[name]
    mesh = icosphere(cfg["subdivisions"])
    verts = TensorXf(mesh.vertices.astype(np.float32))
    faces = mesh.faces
    cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=60.0)

    def renderer(t=tau):
        rr = gendr.Renderer("logistic", "probabilistic", tau=t, image_size=cfg["size"], eps=1e-4, blend=None,
                            backend="drjit", device=device, freeze=freeze)
        if freeze and shared:  # one backend object: its frozen functions serve every τ
            rr.backend = shared[0]
        shared.append(rr.backend)
        return rr
    shared = []
    r = renderer()

    def forward():
        img = r.render(verts, faces, cam)
        dr.eval(img)
        dr.sync_thread()
        return img

    def forward_backward(rr=None, vv=None):
        v = TensorXf(verts if vv is None else vv)
        dr.enable_grad(v)
        img = (rr or r).render(v, faces, cam)
        dr.backward(dr.sum(img[..., 3].array))
        g = dr.grad(v)
        dr.eval(g)
        dr.sync_thread()
        return g

    info = {"case": name, "backend": "drjit", "device": device, "dtype": "float32", "faces": int(faces.shape[0]),
            "image_size": cfg["size"], "instance": "logistic|probabilistic", "tau": tau, "eps": 1e-4, "blend": None,
            "threads": threads, "freeze": freeze, "versions": {"drjit": dr.__version__}}
    return {"forward": forward, "forward_backward": forward_backward, "_renderer": renderer, "_verts": verts,
            "_tensor": TensorXf}, info


def kernel_stats(fn):
    from gendr_drjit.diagnostics import kernel_stats as stats  # only for --backend drjit
    return stats(fn)


def optimization_loop(modes, steps=100):
    """``steps`` forward+backward calls on changing vertices (a training loop): wall times and the
    number of kernels compiled; then 5 renders with different τ (opaque: nothing may compile)."""
    import drjit as dr
    TensorXf = modes["_tensor"]
    fb, r = modes["forward_backward"], modes["_renderer"]()
    rng = np.random.default_rng(0)
    base = np.asarray(modes["_verts"].numpy())
    vs = [TensorXf((base + 1e-3 * rng.standard_normal(base.shape)).astype(np.float32)) for _ in range(steps)]
    dr.eval(vs)
    fb()  # warm
    times = []

    def loop():
        for v in vs:
            t0 = time.perf_counter()
            fb(r, v)
            times.append(time.perf_counter() - t0)

    frozen = r.backend.frozen
    rec0 = frozen.n_recordings if frozen is not None else None
    steps_stats = kernel_stats(loop)
    rec1 = frozen.n_recordings if frozen is not None else None
    tau_stats = kernel_stats(lambda: [fb(modes["_renderer"](t)) for t in (0.009, 0.0095, 0.0105, 0.011, 0.012)])
    out = summary(times) | {"steps": steps, "total_s": sum(times), "kernels_compiled": steps_stats["kernels_compiled"],
                            "kernels_compiled_tau_changes": tau_stats["kernels_compiled"]}
    if frozen is not None:  # recordings (Python traces) made during the 100 steps, and the 5 τ changes
        out |= {"frozen_recordings_during_steps": rec1 - rec0,
                "frozen_recordings_tau_changes": frozen.n_recordings - rec1}
    return out


def time_split(fn, repeats):
    """Median wall time of ``fn`` split into kernel execution (Dr.Jit's kernel history) and the
    rest (Python tracing, host work, launch overhead)."""
    walls, kern = [], []
    for _ in range(repeats):
        t = time.perf_counter()
        st = kernel_stats(fn)
        walls.append(1000.0 * (time.perf_counter() - t))
        kern.append(st["kernel_exec_ms"])
    return {"wall_ms": statistics.median(walls), "kernel_exec_ms": statistics.median(kern),
            "host_ms": statistics.median([w - k for w, k in zip(walls, kern)])}


def run_case(backend, name, repeats, threads, freeze=True, device="cpu"):
    """One case's JSON. On a CUDA device the peak extra memory (host RSS) is left out."""
    modes, out = setup(backend, name, threads, device=device)
    if backend == "drjit":
        img = modes["forward"]()
        out["alpha_sum"] = float(np.asarray(img.numpy())[..., 3].astype(np.float64).sum())
    else:
        out["alpha_sum"] = float(modes["forward"]()[..., 3].sum())
    for label in ("forward", "forward_backward"):
        fn = modes[label]
        out[label] = summary(measure(fn, repeats))
        if device == "cpu":
            out[label]["peak_extra_mb"] = peak_extra_mb(backend, name, label, threads)
        if backend in ("drjit", "torch-compiled"):
            cold = probe(backend, name, label, threads, True, device)
            out[label]["first_call_cold_ms"] = cold["first_call_ms"]
            if backend == "drjit":  # > 0: the call compiled its kernels, the cache was cold
                out[label]["first_call_cold_kernels_compiled"] = cold["drjit_kernels_cached"]
        if backend == "drjit":
            out[label] |= kernel_stats(fn)
    if backend == "drjit":
        out["time_split"] = {label: time_split(modes[label], repeats) for label in ("forward", "forward_backward")}
    if backend == "drjit" and name == "default":
        out["optimization_loop"] = optimization_loop(modes)
    if backend == "drjit" and freeze:  # the same with freeze=True (dr.freeze replays, gendr_drjit.frozen)
        fmodes, _ = setup(backend, name, threads, freeze=True, device=device)
        fr = out["frozen"] = {}
        for label in ("forward", "forward_backward"):
            fr[label] = summary(measure(fmodes[label], repeats)) | kernel_stats(fmodes[label])
        fr["time_split"] = {label: time_split(fmodes[label], repeats) for label in ("forward", "forward_backward")}
        if name == "default":
            fr["optimization_loop"] = optimization_loop(fmodes)
    return out


def emit(result, out=None):
    """Print the JSON of a benchmark result and, with ``out``, write it there too."""
    text = json.dumps(result, indent=2)
    print(text)
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + "\n")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backend", default="torch", choices=("torch", "torch-compiled", "drjit"))
    ap.add_argument("--case", choices=sorted(CASES), action="append", help="default: the 'default' case")
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--out", type=Path, help="write the JSON here (also printed)")
    ap.add_argument("--no-freeze", action="store_true", help="drjit: skip the freeze=True measurements")
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                    help="cuda: torch inputs on the GPU / Dr.Jit's CUDA variant (no host-memory figures)")
    ap.add_argument("--memory-probe", nargs=2, metavar=("CASE", "MODE"), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.memory_probe:
        modes, _ = setup(a.backend, a.memory_probe[0], a.threads, device=a.device)
        rss0 = _status_kb("VmRSS")
        _reset_peak()
        t0 = time.perf_counter()
        modes[a.memory_probe[1]]()
        dt = time.perf_counter() - t0
        # kernels this call compiled and wrote to Dr.Jit's disk cache (a cold probe's HOME starts empty)
        cache = Path.home() / ".drjit"
        cached = sum(1 for f in cache.glob("*.bin")) if cache.is_dir() else 0
        print(json.dumps({"peak_extra_mb": (_status_kb("VmHWM") - rss0) / 1024.0, "first_call_ms": 1000.0 * dt,
                          "drjit_kernels_cached": cached}))
        return 0
    result = {"machine": machine(), "results": [run_case(a.backend, c, a.repeats, a.threads, not a.no_freeze, a.device)
                                                for c in (a.case or ["default"])]}
    emit(result, a.out)


if __name__ == "__main__":
    sys.exit(main())
