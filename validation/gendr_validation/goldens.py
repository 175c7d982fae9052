"""Regression goldens: alpha, RGB and gradients of fixed scenes × instances × backends.

Stored in ``tests/goldens/<backend>.npz`` (float64, as computed; ~150 kB each).
``tests/test_validation_goldens.py`` compares against them with :data:`TOLERANCE`.

Regenerate deliberately (prints the difference to the committed files first)::

    python -m gendr_validation.goldens --regenerate            # all backends that import
    python -m gendr_validation.goldens                         # only show the diff, write nothing
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

import gendr
from gendr.scenes import get_scene

GOLDEN_DIR = os.path.join(os.path.dirname(__file__), "..", "..", "tests", "goldens")
SIZE = (24, 32)
#: (scene, grid instance index): one of each kind of tail / aggregation
CASES = (("icosphere", 271), ("cube", 0), ("torus", 164), ("teapot_like", 649), ("open_mesh", 28), ("chair", 391))
#: float64 computed and stored: |new − golden| <= TOLERANCE · max(1, max |golden|) per array (alpha and
#: RGB lie in [0, 1]; grad_tau reaches ~1e3). Recomputing in another summation order moves values by
#: ~1e-13 relative (the torch and drjit backends on these cases differ by at most 5e-14 · max(1, |g|)),
#: so 1e-9 leaves four orders of magnitude for that while a real change of the images or gradients
#: (1e-6 and up) fails. (Until 2026-11-24 the goldens were float32 with absolute 1e-5 / 1e-4: loose for
#: the small values and within 1.5x of float32 storage rounding for grad_tau.)
TOLERANCE = 1e-9
TAU = 0.03
#: unlit (ambient only) with random face albedo: the RGB still varies per face, and the goldens do not
#: encode Lambert-shading vertex gradients, which are one-sided at the kink n·(−l) = 0 that
#: symmetric scenes under the default light sit on (docs/validation.md, "known issues")
SHADING = {"ambient": 1.0, "diffuse": 0.0}


def face_colors(mesh):
    return np.random.default_rng(mesh.num_faces).uniform(0.2, 1.0, (mesh.num_faces, 3))


def _camera():
    return gendr.orbit_camera(30.0, 20.0, 3.0, fov_y=40.0)


def compute_torch(scene, index, backend="torch"):
    """{'alpha', 'rgb', 'grad_vertices', 'grad_tau'} for one case, through torch autograd (the torch
    backend, or the drjit backend which takes and returns torch tensors)."""
    import torch
    inst = gendr.paper_grid()[index]
    mesh = get_scene(scene)
    tau = torch.tensor(TAU ** 2 if inst.distribution.squared else TAU, dtype=torch.float64, requires_grad=True)
    r = gendr.Renderer(inst.distribution, inst.tconorm, tau=tau, image_size=SIZE, backend=backend, blend="softmax",
                       gamma=0.05, **SHADING)
    v = torch.tensor(mesh.vertices, dtype=torch.float64, requires_grad=True)
    img = r.render(v, mesh.faces, _camera(), face_colors=face_colors(mesh))[0]
    w = torch.as_tensor(np.random.default_rng(index).standard_normal(img.shape))
    (img * w).sum().backward()
    return {"alpha": img[..., 3].detach().numpy(), "rgb": img[..., :3].detach().numpy(),
            "grad_vertices": v.grad.numpy(), "grad_tau": np.array([tau.grad.item()])}


COMPUTE = {"torch": compute_torch, "drjit": lambda scene, index: compute_torch(scene, index, "drjit")}


def compute(backend):
    out = {}
    for scene, index in CASES:
        for k, v in COMPUTE[backend](scene, index).items():
            out[f"{scene}/{index}/{k}"] = v
    return out


def path(backend):
    return os.path.normpath(os.path.join(GOLDEN_DIR, f"{backend}.npz"))


def load(backend):
    with np.load(path(backend)) as z:
        return {k: z[k] for k in z.files}


def diff(new, old):
    """[(key, max abs diff, tolerance, ok)] over the union of keys (missing key: inf); the tolerance
    is TOLERANCE · max(1, max |old|)."""
    rows = []
    for k in sorted(set(new) | set(old)):
        if k not in new or k not in old or new[k].shape != old[k].shape:
            rows.append((k, float("inf"), TOLERANCE, False))
            continue
        a, b = np.asarray(new[k], np.float64), np.asarray(old[k], np.float64)
        tol = TOLERANCE * max(1.0, float(np.abs(b).max()) if b.size else 0.0)
        d = float(np.abs(a - b).max()) if a.size else 0.0
        rows.append((k, d, tol, d <= tol))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gendr_validation.goldens", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--regenerate", action="store_true", help="write the new goldens after showing the diff")
    ap.add_argument("--backends", default=None, help="comma-separated (default: every backend with a golden computer)")
    a = ap.parse_args(argv)
    from .hardlimit import usable_backends
    names = a.backends.split(",") if a.backends else usable_backends(sorted(COMPUTE))
    status = 0
    for b in names:
        if b not in COMPUTE:
            print(f"{b}: no golden computer (add one to COMPUTE in {__file__})")
            status = 1  # asked for and not compared: not a pass
            continue
        new = compute(b)
        if os.path.exists(path(b)):
            rows = diff(new, load(b))
            bad = [r for r in rows if not r[3]]
            print(f"{b}: {len(rows) - len(bad)}/{len(rows)} arrays within tolerance of {path(b)}")
            for k, d, tol, ok in rows:
                if not ok or d > 0:
                    print(f"  {'CHANGED' if not ok else 'ok     '} {k}: max |diff| {d:.3e} (tol {tol:g})")
            status |= bool(bad)
        else:
            print(f"{b}: no goldens yet at {path(b)}")
            status = 1
        if a.regenerate:
            os.makedirs(os.path.dirname(path(b)), exist_ok=True)
            np.savez_compressed(path(b), **{k: np.asarray(v, np.float64) for k, v in new.items()})
            print(f"{b}: wrote {path(b)} ({os.path.getsize(path(b)) / 1e3:.0f} kB)")
            status = 0
    if not names:
        print("no backend to compare (none usable)")
        return 1
    return status


if __name__ == "__main__":
    sys.exit(main())
