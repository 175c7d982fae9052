"""The paper's qualitative findings (§5.1, §5.2) checked against sweep results.

Each finding is a comparison of mean best scores (lower is better: shape = best hard IoU loss, pose =
failure rate) between groups of instances, always over the cells both groups have (the same T-conorm
columns, the same variants), so a partial sweep compares like with like. A verdict needs the
difference to exceed a noise margin: ``noise / sqrt(n)`` with ``n`` the number of paired cells and
``noise`` the drift of a single run under floating-point reordering (0.03 for shape, from
docs/experiments.md "Provenance and drift"; one pair of a batch for pose). Verdicts: ``reproduced``,
``contradicted``, ``within noise`` (the difference is smaller than the margin) or ``not testable``
(no cells to compare).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .figures import column_labels, grid_labels, score_matrix
from .sweep import summarize_best

__all__ = ["BLOCKS", "Finding", "shape_findings", "pose_similarity", "noise_control", "findings_markdown"]

#: the paper's blocks of distributions (rows of its heatmaps), by grid row label
BLOCKS = {
    "finite support": ("uniform", "cubic_hermite", "wigner_semicircle"),
    "exponential decay": ("gaussian", "laplace", "logistic", "hyperbolic_secant"),
    "linear decay": ("cauchy", "reciprocal"),
    "levy": ("levy", "levy rev"),
}
PLAIN, SQUARED = 0, 1


@dataclass
class Finding:
    claim: str
    verdict: str
    detail: str


def _rows(labels):
    dl, _ = grid_labels()
    return [dl.index(x) for x in labels]


def _cols(labels):
    tl = column_labels()
    return [tl.index(x) for x in labels]


def _compare(claim, a, b, noise, what_a, what_b):
    """``a`` should be lower (better) than ``b``: both arrays of the same cells (NaN where not run)."""
    ok = np.isfinite(a) & np.isfinite(b)
    n = int(ok.sum())
    if n == 0:
        return Finding(claim, "not testable", f"no cells with both {what_a} and {what_b}")
    ma, mb = float(a[ok].mean()), float(b[ok].mean())
    margin = noise / math.sqrt(n)
    diff = mb - ma
    verdict = "reproduced" if diff > margin else "contradicted" if diff < -margin else "within noise"
    return Finding(claim, verdict, f"{what_a} {ma:.3f} vs {what_b} {mb:.3f} over {n} paired cells "
                                   f"(difference {diff:+.3f}, margin {margin:.3f})")


def _row_extreme(claim, M, dl, group, rivals, noise, worst=False):
    """Is one of the rows ``group`` the best (lowest scores; ``worst``: the highest) against every
    row of ``rivals``? Each pair of rows is compared over the cells (variant, T-conorm column) both
    have run, with the margin ``noise / sqrt(paired cells)``: row means over different cells are not
    like with like while the sweep is partial (a row run in the poor columns looks worse).
    reproduced: some group row is ahead of every rival beyond the margin; contradicted: every group
    row has some rival ahead of it beyond the margin; else within noise (a rival that shares no cell
    with a group row keeps that row from "reproduced"). Differences are signed so that positive
    supports the claim."""
    sign = -1.0 if worst else 1.0
    pairs = {}
    for x in group:
        for s in rivals:
            ok = np.isfinite(M[:, x]) & np.isfinite(M[:, s])
            if ok.any():
                mx, ms = float(M[:, x][ok].mean()), float(M[:, s][ok].mean())
                pairs[x, s] = (sign * (ms - mx), noise / math.sqrt(int(ok.sum())), mx, ms, int(ok.sum()))
    xs = sorted({x for x, _ in pairs})
    ss = sorted({s for s in rivals if np.isfinite(M[:, s]).any()})
    if not pairs:
        return Finding(claim, "not testable", "no cells with both a claimed row and another row")

    def text(x, s):
        gain, margin, mx, ms, n = pairs[x, s]
        return f"{dl[x]} {mx:.3f} vs {dl[s]} {ms:.3f} over {n} paired cells (difference {gain:+.3f}, margin {margin:.3f})"
    # each group row's closest rival among those it shares cells with
    closest = {x: min((s for s in ss if (x, s) in pairs), key=lambda s: pairs[x, s][0]) for x in xs}

    def ahead(x, s):  # x ahead of s beyond the margin (+1), behind it beyond the margin (−1), else 0
        gain, margin = pairs[x, s][:2]
        return 1 if gain > margin else -1 if gain < -margin else 0
    winners = [x for x in xs if all((x, s) in pairs and ahead(x, s) == 1 for s in ss)]
    if winners:
        x = max(winners, key=lambda x: pairs[x, closest[x]][0])
        return Finding(claim, "reproduced", f"{text(x, closest[x])}: the closest rival; each pair over the cells "
                                            f"both rows have run")
    beaten = {x: [s for s in ss if (x, s) in pairs and ahead(x, s) == -1] for x in xs}
    lead = max(xs, key=lambda x: pairs[x, closest[x]][0])
    if all(beaten.values()):  # every claimed row has a rival clearly ahead of it: none is the extreme
        s = min(beaten[lead], key=lambda s: pairs[lead, s][0])
        return Finding(claim, "contradicted", f"every claimed row has a rival {'worse' if worst else 'better'} than "
                                              f"it beyond the margin ({len(beaten[lead])} for {dl[lead]}, the claimed "
                                              f"row closest to the claim; the clearest: {text(lead, s)})")
    unpaired = [dl[s] for s in ss if (lead, s) not in pairs]
    return Finding(claim, "within noise", f"{text(lead, closest[lead])}: the closest rival of the leading claimed "
                                          f"row; each pair over the cells both rows have run"
                                          + (f"; not compared (no shared cells): {', '.join(unpaired)}" if unpaired else ""))


def shape_findings(rows, noise: float = 0.03) -> list[Finding]:
    """The paper's §5.1 findings, each with its verdict on ``rows`` (shape sweep rows)."""
    best = summarize_best(rows, "shape")
    dl, tl = grid_labels()[0], column_labels()
    ngrid = len(grid_labels()[1])
    M_all = score_matrix(best)  # [2, 23, 27 T-conorms + extra columns (average)]
    # the paper's findings are about its grid: every comparison but "average poor" reads only the
    # grid's T-conorm columns (row means over cells that include "average", a column outside the
    # grid that only some rows have yet, are not like with like)
    M = M_all[:, :, :ngrid]
    out = []
    allrows = range(M.shape[1])

    # squared worse, except Cauchy / reciprocal
    light = [i for i, lab in enumerate(dl) if lab not in ("cauchy", "reciprocal")]
    out.append(_compare("squared worse than plain (all but Cauchy, reciprocal)",
                        M[PLAIN, light], M[SQUARED, light], noise, "plain", "squared"))
    heavy = _rows(("cauchy", "reciprocal"))
    out.append(_compare("... but squared better for Cauchy and reciprocal",
                        M[SQUARED, heavy], M[PLAIN, heavy], noise, "squared", "plain"))

    def block_vs_rest(name, better):
        inb = _rows(BLOCKS[name])
        rest = [i for i in allrows if i not in inb]
        a = np.nanmean(M[:, inb], axis=1)        # [2, 27] block mean per cell column
        b = np.nanmean(M[:, rest], axis=1)
        a = np.where(np.isfinite(M[:, inb]).all(axis=1), a, np.nan)
        b = np.where(np.isfinite(M[:, rest]).any(axis=1), b, np.nan)
        if better:
            return _compare(f"{name} block good (better than the other distributions)", a, b, noise,
                            name, "others")
        return _compare(f"{name} block weak (worse than the other distributions)", b, a, noise, "others", name)

    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # nanmean of all-NaN columns: NaN, as wanted
        out.append(block_vs_rest("finite support", better=False))
        out.append(block_vs_rest("exponential decay", better=True))
        out.append(block_vs_rest("linear decay", better=False))
        # Lévy worst: a Lévy row worse than every other row, each pair over the cells both have run
        lev = _rows(BLOCKS["levy"])
        out.append(_row_extreme("Lévy worst", M, dl, lev, [i for i in allrows if i not in lev], noise,
                                worst=True))
        # competitive: gumbel_min, exponential rev, gamma rev rows vs the exponential block
        comp = _rows(("gumbel_min", "exponential rev", "gamma(0.5) rev", "gamma(2) rev", "gamma(3) rev", "gamma(5) rev"))
        expo = _rows(BLOCKS["exponential decay"])
        a = np.where(np.isfinite(M[:, comp]).all(axis=1), np.nanmean(M[:, comp], axis=1), np.nan)
        b = np.where(np.isfinite(M[:, expo]).all(axis=1), np.nanmean(M[:, expo], axis=1), np.nan)
        f = _compare("Gumbel-min, reversed exponential, reversed gamma competitive (vs the exponential block)",
                     a, b, noise, "these", "exponential block")
        # competitive = not clearly worse: better or within the margin both count
        f.verdict = {"within noise": "reproduced", "not testable": "not testable"}.get(f.verdict, f.verdict)
        out.append(f)
        # gamma best among the asymmetric distributions: a gamma row better than every other
        # asymmetric row (a claim about gamma needs gamma rows: else not testable, not contradicted)
        asym = [i for i, lab in enumerate(dl) if lab.startswith(("gumbel", "exponential", "gamma", "levy"))]
        gamma = [i for i in asym if dl[i].startswith("gamma")]
        out.append(_row_extreme("gamma best among the asymmetric distributions", M, dl, gamma,
                                [i for i in asym if i not in gamma], noise))

        # T-conorm columns: each against the median of the other columns over the same cells
        def column_vs_median(labels, claim, good):
            """``labels``' columns (of the grid, or "average") against the median of the other grid
            columns that have run in every compared cell: one set for all cells (columns a partial
            sweep has run for some rows only must not shift the median there), without the
            compared columns (seven poor columns among twelve would otherwise be the median)."""
            cols = [j for j in (tl.index(x) for x in labels if x in tl) if np.isfinite(M_all[:, :, j]).any()]
            a = np.nanmean(M_all[:, :, cols], axis=2) if cols else np.full(M.shape[:2], np.nan)
            cells = np.isfinite(a)
            common = [j for j in range(ngrid) if j not in cols and np.isfinite(M[:, :, j][cells]).all()]
            if not cells.any() or len(common) < 3:
                return Finding(claim, "not testable", "too few T-conorm columns run in the compared cells")
            med = np.nanmedian(M[:, :, common], axis=2)  # [2, 23] median column per cell row
            if good:
                return _compare(claim, a, med, noise, "/".join(labels), "median of the other columns")
            return _compare(claim, med, a, noise, "median of the other columns", "/".join(labels))

        out.append(column_vs_median(["max"], "max poor", good=False))
        out.append(column_vs_median(["average"], "average poor", good=False))
        out.append(column_vs_median(["yager(4)", "aczel_alsina(2)", "aczel_alsina(4)", "dombi(2)", "dombi(4)",
                                     "schweizer_sklar(-2)", "schweizer_sklar(-4)"],
                                    "Y4, A2, A4, D2, D4, SS-2, SS-4 poor", good=False))
        out.append(column_vs_median(["yager(2)", "dombi(0.5)"], "Y2 and D0.5 best T-conorms", good=True))
        pe = M[:, :, _cols(["probabilistic", "einstein"])]
        ok = np.isfinite(pe).all(axis=-1)
        if ok.any():
            d = np.abs(pe[..., 0] - pe[..., 1])[ok]
            n = int(ok.sum())
            margin = noise / math.sqrt(n)
            out.append(Finding("probabilistic ≈ Einstein", "reproduced" if d.mean() <= noise else "contradicted",
                               f"mean |difference| {d.mean():.3f} over {n} cells (single-run noise {noise}; "
                               f"signed mean {float((pe[..., 0] - pe[..., 1])[ok].mean()):+.3f}, margin {margin:.3f})"))
        else:
            out.append(Finding("probabilistic ≈ Einstein", "not testable", "no cells with both"))
        # gamma(0.5) reversed best overall: better than every other row
        g = dl.index("gamma(0.5) rev")
        f = _row_extreme("gamma(0.5) reversed best overall", M, dl, [g], [i for i in allrows if i != g], noise)
        if best:
            top = min(best.values(), key=lambda b: b["score"])
            f.detail += f"; best single instance {top['label']} {top['score']:.3f}"
        out.append(f)
    return out


def _average_ranks(values) -> np.ndarray:
    """Ranks 0..n-1, tied values sharing their mean rank (Spearman's convention: the order of ties
    in the input must not matter)."""
    v = np.asarray(values, dtype=float)
    order = np.argsort(v, kind="stable")
    ranks = np.empty(len(v))
    ranks[order] = np.arange(len(v), dtype=float)
    for value in np.unique(v[np.isfinite(v)]):
        tied = v == value
        ranks[tied] = ranks[tied].mean()
    return ranks


def pose_similarity(shape_rows, pose_rows) -> Finding:
    """'pose similar to shape': Spearman rank correlation of the best scores of the instances both
    sweeps ran."""
    s = summarize_best(shape_rows, "shape")
    p = summarize_best(pose_rows, "pose")
    common = sorted(set(s) & set(p))
    claim = "pose optimisation behaves like shape optimisation"
    if len(common) < 10:  # a rank correlation over fewer instances says little
        return Finding(claim, "not testable", f"{len(common)} instances in both sweeps")
    rho = float(np.corrcoef(_average_ranks([s[i]["score"] for i in common]),
                            _average_ranks([p[i]["score"] for i in common]))[0, 1])
    verdict = "reproduced" if rho > 0.5 else "contradicted" if rho < 0.2 else "partly"
    return Finding(claim, verdict, f"Spearman rank correlation {rho:.2f} over {len(common)} instances")


#: one T-conorm under three names in the grid (docs/grid.md): the Hamacher sum, generator x/(1 − x)
IDENTICAL_TCONORMS = ("hamacher(p=0)", "schweizer_sklar(p=-1)", "dombi(p=1)")


def noise_control(rows, noise: float = 0.03) -> dict | None:
    """The single-run noise measured inside the grid: runs that differ only in which name of
    :data:`IDENTICAL_TCONORMS` they use compute the same function, so their metrics differ by
    floating-point rounding amplified by the optimisation alone. Pairs every such run with its
    twins (same distribution row and every other setting); returns ``{"pairs", "median", "p90",
    "p95", "max", "over"}`` of |Δ metric| (``over``: the fraction of pairs beyond ``noise``), or None
    without pairs."""
    import json
    last = {}
    for r in rows:
        if r.get("status") == "ok" and r.get("metric") is not None and "|" in (r.get("label") or ""):
            last[r.get("key", id(r))] = r
    groups = {}
    for r in last.values():
        dist, tcn = r["label"].split("|", 1)
        if tcn in IDENTICAL_TCONORMS:
            rest = {k: v for k, v in r["config"].items() if k not in ("instance", "tconorm", "distribution")}
            groups.setdefault((dist, json.dumps(rest, sort_keys=True)), []).append(float(r["metric"]))
    d = [abs(a - b) for ms in groups.values() for i, a in enumerate(ms) for b in ms[i + 1:]]
    if not d:
        return None
    return {"pairs": len(d), "median": float(np.median(d)), "p90": float(np.percentile(d, 90)),
            "p95": float(np.percentile(d, 95)), "max": float(max(d)), "over": float(np.mean(np.array(d) > noise))}


def findings_markdown(findings) -> str:
    lines = ["| finding (paper §5) | verdict | numbers |", "|---|---|---|"]
    for f in findings:
        lines.append(f"| {f.claim} | **{f.verdict}** | {f.detail} |")
    return "\n".join(lines) + "\n"
