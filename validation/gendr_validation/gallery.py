"""Documentation figures (``gendr gallery -o docs/gallery``).

* ``distributions_cdf.png`` / ``distributions_pdf.png``: every distribution setting of the paper grid
  (plain), CDF and density on x in [-4, 4];
* ``triangles.png``: one triangle rendered with each distribution (plain and squared);
* ``tconorms.png``: every T-conorm of the grid as a surface S(a, b) over [0, 1]² (contour plots);
* ``tau_sweep.png``: a scene rendered across τ for a few distributions.

Everything goes through the public API (spec formulas via NumPy ops, renders via gendr.Renderer).
"""
from __future__ import annotations

import os

import numpy as np

import gendr
import gendr.scenes
from gendr.grid import DISTRIBUTION_SETTINGS, TCONORM_SETTINGS
from gendr.ops import numpy_ops  # the spec's NumPy ops namespace


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _dists(squared=False):
    return [gendr.distribution(n, reversed=r, squared=squared, **p) for n, p, r in DISTRIBUTION_SETTINGS]


def _save(fig, outdir, name):
    plt = _plt()
    path = os.path.join(outdir, name)
    fig.savefig(path, dpi=72, bbox_inches="tight")
    plt.close(fig)
    return path, os.path.getsize(path)


def fig_distributions(outdir):
    plt = _plt()
    x = np.linspace(-4, 4, 801)
    out = []
    for kind in ("cdf", "pdf"):
        fig, axes = plt.subplots(4, 6, figsize=(15, 9), sharex=True)
        for ax, d in zip(axes.flat, _dists()):
            with np.errstate(all="ignore"):
                y = np.asarray(getattr(d, kind)(numpy_ops, x), dtype=np.float64)
            ax.plot(x, y, lw=1.2)
            ax.set_title(d.label(), fontsize=8)
            ax.tick_params(labelsize=6)
            if kind == "pdf":
                ax.set_ylim(0, min(max(1.05 * np.nanmax(np.where(np.isfinite(y), y, 0)), 0.1), 3))
        for ax in list(axes.flat)[len(DISTRIBUTION_SETTINGS):]:
            ax.axis("off")
        fig.suptitle(f"distribution {'CDFs F(x)' if kind == 'cdf' else 'densities f(x)'} of the paper grid")
        out.append(_save(fig, outdir, f"distributions_{kind}.png"))
    return out


def _triangle():
    return np.array([[-0.7, -0.6, 0.0], [0.75, -0.45, 0.0], [-0.1, 0.75, 0.0]]), np.array([[0, 1, 2]])


def fig_triangles(outdir, size=64):
    plt = _plt()
    v, f = _triangle()
    cam = gendr.OrthographicCamera(eye=(0.0, 0.0, 3.0), xmag=1.0, ymag=1.0)
    fig, axes = plt.subplots(4, 12, figsize=(18, 6.6))
    for k, (sq, d) in enumerate([(s, d) for s in (False, True) for d in _dists(s)]):
        ax = axes.flat[k]
        tau = 0.1 ** 2 if sq else 0.1
        r = gendr.Renderer(d, "probabilistic", tau=tau, image_size=size, blend=None, eps=1e-3)
        img = r.to_numpy(r.render(v, f, cam))[0, ..., 3]
        ax.imshow(img, cmap="magma", vmin=0, vmax=1)
        ax.set_title(d.label(), fontsize=6)
        ax.axis("off")
    for ax in list(axes.flat)[2 * len(DISTRIBUTION_SETTINGS):]:
        ax.axis("off")
    fig.suptitle("one triangle, alpha = F(d/τ) (τ = 0.1; squared: F(d|d|/τ), τ = 0.01)")
    return [_save(fig, outdir, "triangles.png")]


def fig_tconorms(outdir):
    plt = _plt()
    a = np.linspace(0, 1, 101)
    A, B = np.meshgrid(a, a)
    fig, axes = plt.subplots(3, 9, figsize=(18, 6.4))
    for ax, (n, p) in zip(axes.flat, TCONORM_SETTINGS):
        t = gendr.tconorm(n, **p)
        with np.errstate(all="ignore"):
            S = np.asarray(t.binary(numpy_ops, A, B), dtype=np.float64)
        ax.contourf(A, B, S, levels=np.linspace(0, 1, 11), cmap="viridis")
        ax.set_title(t.label(), fontsize=7)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=5)
    fig.suptitle("T-conorms S(a, b) on [0, 1]² (contours at 0.1 steps)")
    return [_save(fig, outdir, "tconorms.png")]


def fig_tau_sweep(outdir, size=64):
    plt = _plt()
    mesh = gendr.scenes.get_scene("torus", n_major=24, n_minor=12)  # few faces: wide τ means many pairs
    cam = gendr.orbit_camera(30.0, 20.0, 3.0)
    taus = (0.003, 0.01, 0.03, 0.1)
    rows = (("logistic", {}), ("uniform", {}), ("exponential", {"reversed": True}), ("gaussian", {"squared": True}))
    fig, axes = plt.subplots(len(rows), len(taus), figsize=(2.2 * len(taus), 2.3 * len(rows)))
    for i, (n, kw) in enumerate(rows):
        d = gendr.distribution(n, **kw)
        for j, tau in enumerate(taus):
            r = gendr.Renderer(d, "probabilistic", tau=tau ** 2 if d.squared else tau, image_size=size, gamma=0.05)
            img = r.to_numpy(r.render(mesh.vertices, mesh.faces, cam))[0]
            rgb = img[..., :3] * img[..., 3:] + 0.15 * (1 - img[..., 3:])
            axes[i, j].imshow(np.clip(rgb, 0, 1))
            axes[i, j].set_title(f"{d.label()} τ={tau:g}" + ("²" if d.squared else ""), fontsize=7)
            axes[i, j].axis("off")
    fig.suptitle("renders across τ (probabilistic T-conorm, softmax blend)")
    return [_save(fig, outdir, "tau_sweep.png")]


def generate(outdir="docs/gallery", size=64):
    """Write every figure; returns [(path, bytes)]. ``size``: render size in pixels (>= 1), checked
    before anything is written."""
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise gendr.ParameterError(f"gallery size={size!r} must be an integer >= 1 (pixels)")
    os.makedirs(outdir, exist_ok=True)
    out = []
    out += fig_distributions(outdir)
    out += fig_tconorms(outdir)
    out += fig_triangles(outdir, size)
    out += fig_tau_sweep(outdir, size)
    return out
