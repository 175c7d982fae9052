"""What the reference implementation's distance cut-off changes: images and render time.

    .venv/bin/python benchmarks/cutoff_effect.py --out out/cutoff_effect.json

For each instance and τ: the silhouette (alpha) of the paper's shape-step scene (the 1,280-face
sphere template, 24 azimuths at elevation 30°, distance 2.732, fov 30°, 64×64) rendered exactly
(eps culling only, eps = 1e-4) and with ``cutoff`` (the reference's ``dist_eps``, 100 in its shape
and pose experiments): max and mean |Δ alpha| over all pixels, and the median forward+backward time
of each (gradient of alpha.sum() w.r.t. the vertices; median, min, max, stdev over the repeats after a
warm-up call). JSON with versions and machine, like the
other benchmarks.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import gendr
from gendr.scenes import icosphere

sys.path.insert(0, str(Path(__file__).parent))
from bench_render import emit, machine, summary  # noqa: E402

#: (distribution, kwargs, τ values): heavy tails, where the cut-off drops coverage, and a light tail
INSTANCES = [("cauchy", {}, (1e-2, 1e-3)), ("cauchy", {"squared": True}, (1e-4, 1e-5)),
             ("reciprocal", {}, (1e-2, 1e-3)), ("levy", {"reversed": True}, (1e-2, 1e-3)),
             ("logistic", {}, (1e-2, 1e-3))]


def scene():
    s = icosphere(3, radius=0.5)
    cam = gendr.orbit_camera(np.arange(24) * 15.0, 30.0, 2.732, fov_y=30.0)
    return s.vertices.astype(np.float32), s.faces, cam


def run(backend, dist, tau, cutoff, repeats):
    import torch
    verts, faces, cam = scene()
    r = gendr.Renderer(dist, "probabilistic", tau=tau, image_size=64, eps=1e-4, blend=None, backend=backend,
                       cutoff=cutoff)
    f = torch.tensor(faces)
    times, alpha = [], None
    for i in range(repeats + 1):
        v = torch.tensor(verts, requires_grad=True)
        t0 = time.perf_counter()
        a = r.render(v, f, cam)[..., 3]
        a.sum().backward()
        if i:  # the first call compiles / warms up
            times.append(time.perf_counter() - t0)
        alpha = a.detach().double().numpy()
    return alpha, summary(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backend", default="drjit")
    ap.add_argument("--cutoff", type=float, default=100.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    import torch
    torch.set_num_threads(a.threads)
    if a.backend == "drjit":
        import drjit as dr
        dr.set_thread_count(a.threads)
    rows = []
    for name, kw, taus in INSTANCES:
        dist = gendr.distribution(name, **kw)
        for tau in taus:
            exact, t_exact = run(a.backend, dist, tau, None, a.repeats)
            cut, t_cut = run(a.backend, dist, tau, a.cutoff, a.repeats)
            diff = np.abs(cut - exact)
            rows.append({"instance": dist.label() + "|probabilistic", "tau": tau, "cutoff": a.cutoff,
                         "max_abs_alpha_change": float(diff.max()), "mean_abs_alpha_change": float(diff.mean()),
                         "fwd_bwd_exact": t_exact, "fwd_bwd_cutoff": t_cut,
                         "speedup": t_exact["median_ms"] / t_cut["median_ms"]})
            print(json.dumps(rows[-1]), file=sys.stderr)
    out = {"machine": machine(), "backend": a.backend, "threads": a.threads, "repeats": a.repeats, "rows": rows}
    emit(out, a.out)


if __name__ == "__main__":
    sys.exit(main())
