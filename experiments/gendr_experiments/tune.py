"""Pick the renderer instance for YOUR shape task within a time budget (``gendr experiment tune``).

The paper's conclusion is that the best distribution and T-conorm depend on the task and the data.
:func:`tune` runs the paper's search (:func:`~gendr_experiments.sweep.best_setting_search`: a coarse
τ grid × learning rates per instance, then a finer τ grid around each good instance's best τ) on a
user's own target — a mesh file, a built-in scene, or silhouette images with their cameras
(``images:PATH.npz``, :mod:`gendr_experiments.targets`) — and stops when the budget is spent:

1. probe: the first candidate's coarse runs, which also time this machine and problem;
2. coarse: as many further candidates (in an order whose every prefix spreads over distributions,
   T-conorms and plain/squared) as the cost model predicts to fit in 60 % of what is left (the
   stage also stops there, so a slower machine than predicted still leaves time to refine); a
   candidate counts as tried once its whole coarse grid has finished;
3. fine: the finer τ grid for the best instances not refined yet (the top quarter of the coarse
   ranking, at least ``top``), best first, as many as fit in the rest;

and 2-3 again while time and candidates are left.

Predictions use :func:`gendr_experiments.cost.run_features` (pixel-face pairs from the geometry and
τ) with ``seconds = a + b·k·gpairs`` fitted to the runs finished so far (wall seconds, ``workers`` in
parallel). No run starts after the deadline; a run in flight then finishes, so the budget can be
exceeded by about one run. Rows go to a JSON-lines store like a sweep's: run the same command again
(with more budget) and it skips what is done.
"""
from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from gendr.errors import InputValueError, ParameterError

__all__ = ["TUNE_DISTRIBUTIONS", "TUNE_TCONORMS", "default_candidates", "spread_order", "tune", "TuneResult"]

#: the default candidates: a dozen distributions (the paper's competitive families and the common
#: baselines) × the five T-conorms of the paper's pose study, plain and squared: 120 instances
TUNE_DISTRIBUTIONS = ("uniform", "cubic_hermite", "gaussian", "laplace", "logistic", "hyperbolic_secant", "cauchy",
                      "reciprocal", "gumbel_min", "exponential rev", "gamma(0.5) rev", "gamma(2) rev")
TUNE_TCONORMS = ("max", "probabilistic", "einstein", "yager(2)", "dombi(0.5)")
COARSE_SHARE = 0.6
#: the fine grid is spent on the best instances: this share of the coarse ranking (at least ``top``)
REFINE_SHARE = 0.25


def _coords(spec):
    """(distribution without the squared transform, squared, T-conorm) labels of a candidate: a grid
    index or a config dict outside the grid (``{"distribution": {...}, "tconorm": "average"}``)."""
    from .common import instance_from_config
    dist, tcn, _ = instance_from_config({"instance": spec} if isinstance(spec, int) else spec)
    return dist.label().replace("+sq", ""), bool(dist.squared), tcn.label()


def _spec_key(spec):
    """How :func:`~gendr_experiments.sweep.summarize_best` keys a candidate: its grid index, else its label."""
    from .common import instance_from_config
    return int(spec) if not isinstance(spec, dict) else instance_from_config(spec)[2]


def default_candidates() -> list[int]:
    """Grid indices of :data:`TUNE_DISTRIBUTIONS` × {plain, squared} × :data:`TUNE_TCONORMS`."""
    from .figures import grid_labels
    dl, tl = grid_labels()
    nt = len(tl)
    return [(dl.index(d) * 2 + sq) * nt + tl.index(t) for d in TUNE_DISTRIBUTIONS for sq in (0, 1)
            for t in TUNE_TCONORMS]


def spread_order(instances) -> list:
    """``instances`` (grid indices, or config dicts outside the grid) reordered so that every prefix
    spreads over distributions, T-conorms and plain/squared: each next one has the fewest predecessors
    sharing its distribution, T-conorm and variant (ties: the given order). A budget that fits k
    candidates tries a varied k."""
    rest, seen = [], set()
    for i in instances:
        i = i if isinstance(i, dict) else int(i)
        if _spec_key(i) not in seen:
            seen.add(_spec_key(i))
            rest.append(i)
    coords = {_spec_key(i): _coords(i) for i in rest}
    counts = [{}, {}, {}]
    out = []

    def load(i):
        cs = coords[_spec_key(i)]
        return (sum(c.get(x, 0) for c, x in zip(counts, cs)), counts[0].get(cs[0], 0))

    while rest:
        i = rest.pop(min(range(len(rest)), key=lambda k: (load(rest[k]), k)))
        for c, x in zip(counts, coords[_spec_key(i)]):
            c[x] = c.get(x, 0) + 1
        out.append(i)
    return out


@dataclass
class TuneResult:
    """What :func:`tune` found: ``best`` (the top instances, best first: instance, label, tau, lr,
    score = mean hard IoU loss, n runs, refined), every instance's best setting in ``ranking``,
    the ``plan`` it followed, the rows' ``store``, ``seconds`` of wall time and ``runs`` done now."""

    best: list
    ranking: list
    plan: dict
    store: str
    seconds: float
    runs: int
    skipped: list = field(default_factory=list)


class _Calibration:
    """``seconds = a + b·k·gpairs`` fitted (non-negative least squares) to the finished rows. From
    runs of one work level w₀ alone (the probe of a light-tailed candidate) the split between fixed
    and per-pair cost is unknown: then ``seconds = y·max(1, w/w₀)``, never below the measured y and
    proportional beyond it, so a heavy-tailed run (100× the pairs) is not predicted to cost what
    the probe did and started just before the deadline."""

    def __init__(self):
        self.a, self.b = None, None
        self.w0 = None  # the single work level, when that is all there is

    def fit(self, rows, feats, warm=()):
        """Fit to ``rows`` except those in ``warm`` (keys of a process's first run: imports, kernel
        set-up), unless nothing else is there."""
        from scipy.optimize import nnls
        ok = [r for r in rows if r.get("status") == "ok" and r.get("seconds")]
        rows = [r for r in ok if r["key"] not in warm] or ok
        pts = [(feats(r["config"]), r["seconds"]) for r in rows]
        if not pts:
            return
        X = np.array([[1.0, _work(f)] for f, _ in pts])
        y = np.array([s for _, s in pts])
        if len({round(x[1], 12) for x in X}) < 2:  # one work level (see the class docstring)
            self.a, self.b, self.w0 = float(y.mean()), 0.0, float(X[0, 1])
            return
        (a, b), _ = nnls(X, y)
        self.a, self.b, self.w0 = float(a), float(b), None

    def predict(self, f) -> float:
        w = _work(f)
        if self.w0 is not None:
            return self.a * max(1.0, w / self.w0) if self.w0 > 0 else self.a
        return self.a + self.b * w


def _work(f):
    from .cost import DEFAULT_K_DIST, DEFAULT_K_TCONORM
    return DEFAULT_K_DIST.get(f["dist_family"], 1.0) * DEFAULT_K_TCONORM.get(f["tconorm_family"], 1.0) * f["gpairs"]


def _check_target(target, base):
    """Typed errors for a missing or malformed target, before any run (runs record errors as rows)."""
    from gendr import scenes
    from .common import resolve_data_path
    from .shape import shape_config, shape_target_views
    from .targets import images_path, is_images_target
    if not isinstance(target, str) or not target:
        raise InputValueError(f"tune target {target!r} must be a built-in scene, a mesh file or 'images:PATH.npz'")
    if target not in scenes.SCENES:
        path = images_path(target) if is_images_target(target) else resolve_data_path(target)
        if not path.is_file():
            raise InputValueError(f"tune target {target!r}: file {str(path)!r} does not exist")
    cfg = shape_config(base)
    cam, sil, (H, W) = shape_target_views(cfg)
    if float(sil.sum()) == 0:
        raise InputValueError(f"tune target {target!r}: every silhouette is empty (nothing to fit)")
    return sil.shape[0], (H, W)


def tune(target: str, *, budget: float, store="tune.jsonl", protocol: str = "quick", instances=None,
         taus=(0.1, 0.01, 0.001), lrs=None, seeds=(0,), fine_steps=(-0.5, -0.25, 0.25, 0.5), base=None,
         workers: int | None = None, top: int = 5, other_code: str = "refuse",
         stream=None) -> TuneResult:
    """Search instances × τ × learning rates for shape optimisation of ``target`` within ``budget``
    seconds of wall time (see the module docstring); rows go to ``store`` (JSON lines, resumable).

    ``instances``: grid indices or config dicts outside the grid (``{"distribution": {...},
    "tconorm": "average"}``; default :func:`default_candidates`), tried in :func:`spread_order`;
    ``taus``: the coarse grid of blur widths; ``lrs``: learning rates (default the protocol's);
    ``base``: further config settings (``{"image_size": 32, "steps": 60}``, ...); ``workers``: local
    processes as :func:`~gendr_experiments.sweep.execute` (0: in this process; default the CPU
    count). Returns a :class:`TuneResult`.
    Raises :class:`~gendr.errors.ParameterError` (budget, grids) and
    :class:`~gendr.errors.InputValueError` / :class:`~gendr.errors.ShapeError` (target) before running.
    """
    from .cost import run_features
    from .sweep import (INSTANCE_KEYS, ResultStore, check_base, check_fine_steps, execute, expand, fine_grid,
                        full_config, summarize_best)
    t_start = time.monotonic()
    stream = stream if stream is not None else sys.stderr
    if isinstance(budget, bool) or not isinstance(budget, (int, float)) or not (math.isfinite(budget) and budget > 0):
        raise ParameterError(f"tune budget={budget!r} must be a finite number of seconds > 0")
    taus, seeds = [float(t) for t in taus], list(seeds)
    if not taus or any(not (math.isfinite(t) and t > 0) for t in taus):
        raise ParameterError(f"tune taus={taus!r} must be a non-empty list of widths > 0")
    # (a bad step failed only after the coarse stage)
    fine_steps = check_fine_steps(fine_steps, taus, "tune fine_steps (CLI --fine-steps)")
    from .targets import is_images_target
    decided = {"target": "tune's target (CLI --target)", "protocol": "tune's protocol (CLI --protocol)",
               "tau": "tune's taus (CLI --taus)", "lr": "tune's lrs (CLI --lrs)", "seed": "tune's seeds (CLI --seeds)",
               **dict.fromkeys(INSTANCE_KEYS, "tune's instances (CLI --instances, --dists, --tconorms)")}
    if is_images_target(target):
        decided.update(dict.fromkeys(("image_size", "views"), f"the images file of {target!r}"))
    check_base(base, decided, "tune", fixed={"target": target, "protocol": protocol})
    base = dict(base or {}, protocol=protocol, target=target)
    views, (H, W) = _check_target(target, base)
    if is_images_target(target):  # recorded for the reader; the file decides (targets module)
        base.update(views=int(views), image_size=H if H == W else [H, W])
    lrs = [float(x) for x in (lrs or [full_config("shape", base)["lr"]])]
    if not lrs or any(not (math.isfinite(x) and x > 0) for x in lrs):
        raise ParameterError(f"tune lrs={lrs!r} must be a non-empty list of learning rates > 0")
    specs = spread_order(default_candidates() if instances is None else instances)
    if not specs:
        raise ParameterError("tune: no candidate instances")
    spec_of = {_spec_key(i): i for i in specs}
    cands = list(spec_of)  # keys as summarize_best gives them: grid index, else label
    deadline = t_start + float(budget)
    axes = {"tau": taus, "lr": lrs, "seed": seeds}
    coarse = {k: expand("shape", base, instances=[spec_of[k]], axes=axes) for k in cands}
    kw = dict(store=store, workers=workers, progress=False, other_code=other_code)
    parallel = 1 if workers == 0 else (workers or os.cpu_count() or 1)
    st = ResultStore(store)
    feats_cache = {}

    def feats(cfg):
        from .common import config_hash
        k = config_hash(cfg)
        if k not in feats_cache:
            feats_cache[k] = run_features(cfg)
        return feats_cache[k]

    def say(msg):
        print(f"[tune {time.monotonic() - t_start:6.1f}s] {msg}", file=stream, flush=True)

    n_before = len(st.rows())
    cal = _Calibration()
    overhead = 0.0  # wall seconds a stage costs beyond its runs (pool start, first runs' warm-up)
    warm = set()    # keys of each process's first run
    plan = {"budget_s": float(budget), "candidates": len(cands), "coarse_taus": taus, "lrs": lrs,
            "seeds": seeds, "fine_steps": list(fine_steps)}

    def run_stage(configs, name, until):
        nonlocal overhead
        if not configs:
            return []
        t0 = time.monotonic()
        done0 = {r["key"] for r in st.rows()}
        typical = np.median([cal.predict(feats(c)) for c in configs]) if cal.a is not None else 0.0
        execute(configs, deadline=until - 0.5 * typical, **kw)
        new = [r for r in st.rows() if r["key"] not in done0]  # in the order they finished
        if workers != 0 or not warm:  # a new pool (or this process's first runs): its first runs warm up
            warm.update(r["key"] for r in new[:parallel])
        if new and workers != 0 and cal.a is not None:  # beyond the runs' predicted time: start-up, warm-up
            overhead = max(overhead, time.monotonic() - t0 - sum(cal.predict(feats(r["config"])) for r in new) / parallel)
        say(f"{name}: {len(new)} runs in {time.monotonic() - t0:.1f} s")
        return new

    def fits(configs, seconds_left):
        return sum(cal.predict(feats(c)) for c in configs) / parallel + overhead <= seconds_left

    def finished():  # (one read of the store per phase: it grows with every run)
        return {r["key"] for r in st.rows()}

    def pending(configs, done):
        return [c for c in configs if _key(c) not in done]

    def fine_of(i, b):  # the fine τ grid around instance i's best coarse setting b
        return expand("shape", base, instances=[spec_of[i]],
                      axes={"tau": fine_grid(b["tau"], fine_steps, taus), "lr": [b["lr"]], "seed": seeds})

    def refined_in_store(best, done):
        """The instances of ``best`` (the coarse ranking) whose fine grid the store holds complete,
        whichever run made it: a resumed tune ranks the same rows as the run it resumes, whose
        earlier rounds may have refined others than today's top."""
        if not fine_steps:
            return {}
        return {i: cfgs for i, b in best.items() for cfgs in [fine_of(i, b)] if not pending(cfgs, done)}

    # 1. probe: the first candidate's coarse runs time this machine and problem
    run_stage(coarse[cands[0]], "probe (first candidate, coarse grid)", deadline)
    cal.fit(_rows_of(st, coarse[cands[0]]), feats, warm)
    if workers != 0:
        probe = _rows_of(st, coarse[cands[0]])
        overhead = max(0.0, sum(r["seconds"] - cal.predict(feats(r["config"])) for r in probe if r["key"] in warm))
    if cal.a is None:
        raise ParameterError(f"tune: no run finished within budget={budget!r} s; raise --budget")
    model = ("one work level: proportional to the pairs beyond it" if cal.w0 is not None else
             f"a={cal.a:.2f} s, b={cal.b:.3g} s per billion pairs")
    say(f"cost: ~{cal.predict(feats(coarse[cands[0]][0])):.2f} s per run ({model})")
    # rounds until the budget or the candidates run out:
    # 2. the coarse grid for as many further candidates as fit in COARSE_SHARE of what is left (that
    #    share is also the stage's deadline: a slower machine than predicted still leaves the rest);
    # 3. the fine τ grid for the best coarse instances not refined yet (the top ``refine_share`` of the
    #    ranking, at least ``top``), best first, as many as fit in the rest.
    # A candidate counts as tried once its whole coarse grid has finished (a stage cut by its
    # deadline leaves some halfway: the next round, or a resumed tune, completes them).
    refined = {}
    rounds = 0
    while time.monotonic() < deadline:
        rounds += 1
        ran = 0
        left = deadline - time.monotonic()
        todo, new = [], []
        done = finished()
        for i in cands:
            missing = pending(coarse[i], done)
            if missing and fits(todo + missing, COARSE_SHARE * left):
                todo += missing
                new.append(i)
        if new:
            say(f"round {rounds}, coarse: {len(new)} more candidates × {len(taus)} τ × {len(lrs)} lr × {len(seeds)} seed")
            ran += len(run_stage(todo, "coarse", time.monotonic() + COARSE_SHARE * left))
        done = finished()
        tried = [i for i in cands if not pending(coarse[i], done)]
        all_coarse = [c for i in tried for c in coarse[i]]
        best = summarize_best(_rows_of(st, all_coarse), "shape")
        refined.update(refined_in_store(best, done))
        cal.fit(_rows_of(st, all_coarse + [c for cfgs in refined.values() for c in cfgs]), feats, warm)
        order = sorted(best, key=lambda i: best[i]["score"])
        order = [i for i in order[:max(int(top), math.ceil(REFINE_SHARE * len(order)))] if i not in refined
                 ] if fine_steps else []  # (no fine steps: the coarse grid only)
        left = deadline - time.monotonic()
        fine, picked = [], {}
        for i in order:
            cfgs = fine_of(i, best[i])
            missing = pending(cfgs, done)
            if left > 0 and fits(fine + missing, left):
                fine += missing
                picked[i] = cfgs
        if picked:
            say(f"round {rounds}, fine: {len(picked)} instances × {len(fine_steps)} τ around their best")
            ran += len(run_stage(fine, "fine", deadline))
            done = finished()
            refined.update((i, c) for i, c in picked.items() if not pending(c, done))
        if not ran:
            break
    done = finished()
    tried = [i for i in cands if not pending(coarse[i], done)]
    if not tried:
        raise ParameterError(f"tune: no candidate's coarse grid ({len(coarse[cands[0]])} runs) finished within "
                             f"budget={budget!r} s; raise --budget (finished runs resume)")
    skipped = [i for i in cands if i not in tried]
    # the ranking counts every complete fine grid in the store: the same rows however many rounds or runs made them
    coarse_best = summarize_best(_rows_of(st, [c for i in tried for c in coarse[i]]), "shape")
    refined.update(refined_in_store(coarse_best, done))
    if skipped:
        say(f"{len(skipped)} of {len(cands)} candidates not tried: raise --budget to try them (resumes)")
    mine = [c for i in tried for c in coarse[i]] + [c for cfgs in refined.values() for c in cfgs]
    plan.update(rounds=rounds, coarse_instances=len(tried), fine_instances=len(refined), runs=len(_rows_of(st, mine)))
    final = summarize_best(_rows_of(st, mine), "shape")
    refined_set = set(refined)
    ranking = [dict(instance=i if isinstance(i, int) else None, label=b["label"], tau=b["tau"], lr=b["lr"],
                    score=b["score"], n=b["n"],
                    refined=i in refined_set) for i, b in sorted(final.items(), key=lambda kv: kv[1]["score"])]
    return TuneResult(best=ranking[:max(1, int(top))], ranking=ranking, plan=plan, store=str(st.path),
                      seconds=time.monotonic() - t_start, runs=len(st.rows()) - n_before, skipped=skipped)


def _key(cfg):
    from .common import config_hash
    return config_hash(cfg)


def _rows_of(store, configs):
    keys = {_key(c) for c in configs}
    return [r for r in store.rows() if r["key"] in keys]
