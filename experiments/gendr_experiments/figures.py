"""Figures of a sweep: heatmaps laid out like the paper's (distributions × T-conorms, a plain and a
squared panel), marginal histograms of the top 10 % of instances, and GIFs of an optimisation.

Only matplotlib's Agg backend is used (no display needed).
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from gendr.grid import DISTRIBUTION_SETTINGS, TCONORM_SETTINGS

from .sweep import EXPERIMENTS, summarize_best

__all__ = ["EXTRA_COLUMNS", "grid_labels", "column_labels", "score_matrix", "plot_heatmap", "plot_top_histograms", "write_gif", "make_figures"]


def _dist_label(name, params, rev):
    s = name + ("(" + ",".join(f"{v:g}" for v in params.values()) + ")" if params else "")
    return s + (" rev" if rev else "")


def _tconorm_label(name, params):
    return name + ("(" + ",".join(f"{v:g}" for v in params.values()) + ")" if params else "")


def grid_labels():
    """(23 distribution row labels, 27 T-conorm column labels) in the grid's order."""
    return ([_dist_label(*d) for d in DISTRIBUTION_SETTINGS], [_tconorm_label(*t) for t in TCONORM_SETTINGS])


#: aggregation columns drawn beside the grid's 27 T-conorms (not T-conorms; runs keyed by label)
EXTRA_COLUMNS = ("average",)


def column_labels():
    """The 27 T-conorm labels of the grid, then :data:`EXTRA_COLUMNS`."""
    return grid_labels()[1] + list(EXTRA_COLUMNS)


@lru_cache(maxsize=1)
def _distribution_rows():
    """gendr distribution label (``"gamma(shape=0.5)+rev+sq"``) -> (row, squared) in the grid."""
    from gendr.grid import paper_grid
    out = {}
    for inst in paper_grid():
        d, sq, _ = _position(inst.index)
        out[inst.distribution.label()] = (d, sq)
    return out


def _cell(key, entry):
    """(row, squared, column) of a :func:`~gendr_experiments.sweep.summarize_best` entry, or None."""
    if isinstance(key, (int, np.integer)):
        return _position(int(key))
    dist_label, _, tcn_label = str(entry.get("label") or key).partition("|")
    pos = _distribution_rows().get(dist_label)
    if pos is None or tcn_label not in EXTRA_COLUMNS:
        return None
    return pos[0], pos[1], len(TCONORM_SETTINGS) + EXTRA_COLUMNS.index(tcn_label)


def _position(index: int):
    """Grid index -> (distribution row, squared 0/1, T-conorm column) (grid is distribution-major)."""
    nt = len(TCONORM_SETTINGS)
    d, rest = divmod(index, 2 * nt)
    sq, t = divmod(rest, nt)
    return d, sq, t


def score_matrix(best: dict, key: str = "score"):
    """``[2, 23, 27 + len(EXTRA_COLUMNS)]`` array (plain, squared) of ``best[...][key]``: the grid's
    T-conorm columns, then the extra aggregations (e.g. "average", placed by label); NaN where not
    run. Other runs outside the grid (custom distribution / T-conorm) are skipped."""
    M = np.full((2, len(DISTRIBUTION_SETTINGS), len(TCONORM_SETTINGS) + len(EXTRA_COLUMNS)), np.nan)
    for k, b in best.items():
        cell = None if k is None else _cell(k, b)
        if cell is not None:
            d, sq, t = cell
            M[sq, d, t] = b[key]
    return M


def _trim(M):
    """Rows/columns that hold at least one value (a sweep over a subset draws only that subset)."""
    rows = np.where(~np.all(np.isnan(M), axis=(0, 2)))[0]
    cols = np.where(~np.all(np.isnan(M), axis=(0, 1)))[0]
    return rows, cols


def plot_heatmap(best: dict, path, *, key="score", title=None, trim=True, cmap="viridis_r", annotate=None):
    """Two panels (plain | squared) of distributions (rows) × T-conorms (columns); lower = better
    is drawn bright (``viridis_r``). Cells not run are gray."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    M = score_matrix(best, key)
    dl, tl = grid_labels()[0], column_labels()
    rows, cols = _trim(M) if trim else (np.arange(M.shape[1]), np.arange(M.shape[2]))
    if len(rows) == 0:
        raise ValueError("no grid instances in these results: nothing to plot")
    sub = M[:, rows][:, :, cols]
    finite = sub[np.isfinite(sub)]
    vmin, vmax = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    annotate = (len(rows) * len(cols) <= 200) if annotate is None else annotate
    # both panels as in the paper; a sweep of one variant only draws that panel
    panels = [k for k in (0, 1) if np.isfinite(sub[k]).any()]
    fig, axes = plt.subplots(1, len(panels), figsize=(4 + 0.45 * len(cols) * len(panels), 1.5 + 0.35 * len(rows)),
                             squeeze=False)
    cm = plt.get_cmap(cmap).with_extremes(bad="#cccccc")
    for n, (ax, k) in enumerate(zip(axes[0], panels)):
        name = ("plain", "squared")[k]
        im = ax.imshow(np.ma.masked_invalid(sub[k]), cmap=cm, vmin=vmin, vmax=vmax, aspect="auto")
        ax.set_xticks(range(len(cols)), [tl[c] for c in cols], rotation=90, fontsize=7)
        ax.set_yticks(range(len(rows)), [dl[r] for r in rows] if n == 0 else [], fontsize=7)
        ax.set_title(name, fontsize=9)
        if annotate:
            for i in range(len(rows)):
                for j in range(len(cols)):
                    v = sub[k, i, j]
                    if np.isfinite(v):
                        ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=5,
                                color="k" if (v - vmin) < 0.5 * (vmax - vmin + 1e-12) else "w")
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.8, label=key + " (lower is better)")
    if title:
        fig.suptitle(title, fontsize=10)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=150, bbox_inches="tight")
    plt.close(fig)
    return Path(path)


def top_fraction(best: dict, fraction=0.1, key="score"):
    """The instances of the best ``fraction`` (at least one), best first."""
    items = sorted(((b[key], inst) for inst, b in best.items() if inst is not None and np.isfinite(b[key])),
                   key=lambda si: si[0])
    n = max(1, int(round(fraction * len(items))))
    return [inst for _, inst in items[:n]]


def plot_top_histograms(best: dict, path, *, fraction=0.1, key="score", title=None):
    """How often each distribution (plain and squared stacked) and each T-conorm occurs among the
    top ``fraction`` of instances — the paper's marginal histograms."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    top = top_fraction(best, fraction, key)
    dl, tl = grid_labels()[0], column_labels()
    dcount = np.zeros((2, len(dl)))
    tcount = np.zeros(len(tl))
    for inst in top:
        cell = _cell(inst, best[inst])
        if cell is None:
            continue
        d, sq, t = cell
        dcount[sq, d] += 1
        tcount[t] += 1
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(14, 4))
    x = np.arange(len(dl))
    a1.bar(x, dcount[0], label="plain")
    a1.bar(x, dcount[1], bottom=dcount[0], label="squared")
    a1.set_xticks(x, dl, rotation=90, fontsize=7)
    a1.set_ylabel("count in top set")
    a1.legend(fontsize=8)
    a1.set_title("distributions", fontsize=9)
    a2.bar(np.arange(len(tl)), tcount, color="tab:green")
    a2.set_xticks(np.arange(len(tl)), tl, rotation=90, fontsize=7)
    a2.set_title("T-conorms", fontsize=9)
    fig.suptitle(title or f"top {fraction:.0%} of {len(best)} instances ({len(top)})", fontsize=10)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=150, bbox_inches="tight")
    plt.close(fig)
    return Path(path)


def write_gif(frames, path, *, fps=10):
    """Write ``frames`` (a list of ``[H, W]`` or ``[H, W, 3]`` floats in [0, 1] or uint8) as a GIF."""
    import imageio.v2 as imageio
    out = []
    for f in frames:
        a = np.asarray(f)
        if a.dtype != np.uint8:
            a = (np.clip(a, 0, 1) * 255 + 0.5).astype(np.uint8)
        out.append(a)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    imageio.mimsave(path, out, duration=1.0 / fps, loop=0)
    return Path(path)


def silhouette_frame(pred, target, max_views=8):
    """An RGB frame: rows of views, prediction in red/green over the target in blue (``[B, H, W]``)."""
    p = np.asarray(pred)[:max_views]
    t = np.asarray(target)[:max_views]
    rgb = np.stack([p, p * 0.6 + t * 0.4, t], axis=-1)  # overlap ~white, missing blue, extra orange
    return np.concatenate(list(rgb), axis=1)


def make_figures(rows, outdir, *, experiment=None, fraction=0.1) -> list[Path]:
    """Heatmap(s), top-fraction histograms and a best-settings table (CSV) for the rows of a sweep."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    written = []
    exps = [experiment] if experiment else sorted({r["experiment"] for r in rows})
    for exp in exps:
        best = summarize_best([r for r in rows if r["experiment"] == exp], exp)
        if not best:
            continue
        exp_rows = [r for r in rows if r["experiment"] == exp]
        lookat = any("pairs" in r for r in exp_rows)
        if exp == "shape":
            what = "hard IoU loss"
        else:
            deg = sorted({r.get("config", {}).get("success_degrees", 3.0) for r in exp_rows})
            what = f"failure rate (1 − success within {'/'.join(f'{d:g}' for d in deg)}°)"
        written.append(plot_heatmap(best, outdir / f"{exp}_heatmap.png",
                                    title=f"{exp}: best {what} per instance over τ × lr"))
        if exp == "pose" and not lookat:  # look-at rows' metric is the failure rate itself
            written.append(plot_heatmap(best, outdir / f"{exp}_heatmap_error.png", key="mean_metric",
                                        title="pose: mean final angular error (degrees)"))
        written.append(plot_top_histograms(best, outdir / f"{exp}_top{round(fraction * 100, 6):g}.png", fraction=fraction))
        tau_key = EXPERIMENTS[exp]
        csv = outdir / f"{exp}_best.csv"
        with open(csv, "w") as f:
            f.write(f"instance,label,{tau_key},lr,score,mean_metric,n,seconds_per_run\n")
            for inst, b in sorted(best.items(), key=lambda kv: kv[1]["score"]):
                f.write(f"{inst},{b['label']},{b[tau_key]},{b['lr']},{b['score']:.6g},{b['mean_metric']:.6g},"
                        f"{b['n']},{b['seconds']:.3f}\n")
        written.append(csv)
        written.append(write_marginals(best, outdir / f"{exp}_marginals.csv"))
    return written


def write_marginals(best: dict, path, key="score"):
    """Mean and median of the best ``key`` per distribution row (plain and squared separately) and per
    T-conorm column, over the instances that were run: the table behind the paper's qualitative claims."""
    M = score_matrix(best, key)
    dl, tl = grid_labels()[0], column_labels()
    with open(path, "w") as f:
        f.write("kind,label,variant,n,mean,median,min\n")
        for k, variant in enumerate(("plain", "squared")):
            for i, lab in enumerate(dl):
                v = M[k, i][np.isfinite(M[k, i])]
                if v.size:
                    f.write(f"distribution,{lab},{variant},{v.size},{v.mean():.4f},{np.median(v):.4f},{v.min():.4f}\n")
        for j, lab in enumerate(tl):
            v = M[:, :, j][np.isfinite(M[:, :, j])]
            if v.size:
                f.write(f"tconorm,{lab},both,{v.size},{v.mean():.4f},{np.median(v):.4f},{v.min():.4f}\n")
    return Path(path)
