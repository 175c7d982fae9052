"""Sweeps over renderer instances × τ × learning rates × seeds (× elevations), resumable, local or on
a Dask cluster, with the paper's best-setting search.

Results go to a JSON-lines file, one row per finished run (a tidy table)::

    {"key": "3f2a...", "experiment": "shape", "instance": 17, "label": "uniform|hamacher(p=0.5)",
     "distribution": "uniform", "squared": false, "tconorm": "hamacher(p=0.5)", "tau": 0.01, "lr": 0.05,
     "seed": 0, "metric": 0.21, "seconds": 3.2, "status": "ok", "config": {...}, "versions": {...}, ...}

``key`` is a stable hash of the full config (defaults merged in), so rerunning the same sweep skips
finished runs: interrupt it at any time and start it again. Non-finite numbers are stored as null.

Execution: :func:`execute` runs the configs in a local process pool (``workers`` processes, each with
one torch thread) or, given ``scheduler`` (an address ``tcp://host:8786`` or a ``distributed.Client``),
on a Dask cluster. Both paths call the same :func:`run_config`, with one torch thread, so the metrics
are identical.
"""
from __future__ import annotations

import itertools
import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from .common import config_hash, versions

__all__ = ["EXPERIMENTS", "full_config", "expand", "run_config", "ResultStore", "execute", "load_rows",
           "aggregate", "best_setting_search", "fine_grid", "summarize_best", "write_csv"]

#: experiment name -> (defaults, runner path, the config key the τ grid sets, lower_is_better aggregate)
EXPERIMENTS = {"shape": "tau", "pose": "tau_start"}


def _defaults(experiment: str) -> dict:
    if experiment == "shape":
        from .shape import SHAPE_DEFAULTS
        return SHAPE_DEFAULTS
    if experiment == "pose":
        from .pose import POSE_DEFAULTS
        return POSE_DEFAULTS
    raise ValueError(f"unknown experiment {experiment!r}; expected one of {sorted(EXPERIMENTS)}")


def full_config(experiment: str, overrides: dict) -> dict:
    """The defaults of ``experiment`` with ``overrides`` applied (unknown keys are an error)."""
    d = dict(_defaults(experiment))
    bad = sorted(set(overrides) - set(d))
    if bad:
        raise ValueError(f"unknown {experiment} config keys {bad}; known: {sorted(d)}")
    d.update(overrides)
    d["experiment"] = experiment
    return d


def expand(experiment: str, base: dict | None = None, *, instances=(None,), axes: dict | None = None) -> list[dict]:
    """Full configs of the Cartesian product ``instances × axes`` (``axes``: key -> list of values,
    e.g. ``{"tau": [1e-1, 1e-2], "lr": [0.05], "seed": [0, 1]}``), over ``base``."""
    axes = dict(axes or {})
    keys = list(axes)
    out = []
    for inst in instances:
        for values in itertools.product(*(axes[k] for k in keys)):
            ov = dict(base or {})
            if inst is not None:
                ov["instance"] = int(inst)
            ov.update(zip(keys, values))
            out.append(full_config(experiment, ov))
    return out


def _clean(x):
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, (np.floating,)):
        return _clean(float(x))
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    return x


def run_config(cfg: dict) -> dict:
    """Run one config (in any process) and return its result row. One torch thread, so a run gives
    the same numbers wherever it runs. Exceptions become rows with ``status="error"``."""
    import torch
    torch.set_num_threads(1)
    from .common import instance_from_config
    t0 = time.perf_counter()
    row = {"key": config_hash(cfg), "experiment": cfg["experiment"], "instance": cfg.get("instance")}
    try:
        dist, tcn, label = instance_from_config(cfg)
        row.update(label=label, distribution=dist.label().replace("+sq", ""), squared=bool(dist.squared),
                   tconorm=tcn.label())
        if cfg["experiment"] == "shape":
            from .shape import run_shape
            res = run_shape(cfg)
        else:
            from .pose import run_pose
            res = run_pose(cfg)
        res.pop("final_vertices", None)
        res.pop("faces", None)
        row.update(res)
        row["status"] = "ok"
    except Exception as exc:  # recorded, not raised: one bad instance must not kill a 1,242-run sweep
        row.update(status="error", error=f"{type(exc).__name__}: {exc}", metric=None)
    for k in ("tau", "tau_start", "lr", "seed", "elevation", "target", "image_size", "steps"):
        if k in cfg:
            row[k] = cfg[k]
    row["seconds"] = time.perf_counter() - t0
    row["config"] = cfg
    row["versions"] = versions()
    row["finished_at"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    return _clean(row)


class ResultStore:
    """Append-only JSON-lines table of result rows keyed by ``key``. A torn last line (the process
    was killed while writing) is ignored when reading."""

    def __init__(self, path):
        self.path = Path(path)

    def rows(self) -> list[dict]:
        return load_rows(self.path)

    def done_keys(self, *, retry_errors: bool = False) -> set[str]:
        return {r["key"] for r in self.rows() if not (retry_errors and r.get("status") == "error")}

    def append(self, row: dict):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        line = json.dumps(row, sort_keys=True, allow_nan=False)
        with open(self.path, "a") as f:
            # a torn line from an interrupted run has no newline: start ours on a fresh line
            if f.tell() > 0:
                with open(self.path, "rb") as r:
                    r.seek(-1, os.SEEK_END)
                    if r.read(1) != b"\n":
                        f.write("\n")
            f.write(line + "\n")
            f.flush()
            os.fsync(f.fileno())


def load_rows(path) -> list[dict]:
    """Rows of a results file; the last row per key wins (a retried error replaces the error)."""
    path = Path(path)
    if not path.exists():
        return []
    by_key = {}
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line:
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        by_key[row["key"]] = row
    return list(by_key.values())


def write_csv(rows, path, columns=("key", "experiment", "instance", "label", "distribution", "squared", "tconorm",
                                   "tau", "tau_start", "lr", "seed", "elevation", "target", "metric", "success",
                                   "seconds", "status")):
    """The main columns of ``rows`` as CSV (the JSONL file keeps everything)."""
    import csv
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(columns), extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k) for k in columns})


class _Progress:
    def __init__(self, total, skipped, stream=None, width=30):
        self.total, self.skipped, self.done, self.width = total, skipped, 0, width
        self.stream = stream if stream is not None else sys.stderr
        self.t0 = time.perf_counter()

    def update(self, row=None):
        self.done += 1
        el = time.perf_counter() - self.t0
        eta = el / self.done * (self.total - self.done) if self.done else 0.0
        fill = int(self.width * self.done / max(self.total, 1))
        m = "" if row is None else f" last: {row.get('label')} metric={row.get('metric')}"
        self.stream.write(f"\r[{'#' * fill}{'-' * (self.width - fill)}] {self.done}/{self.total} "
                          f"(skipped {self.skipped} finished) {el:6.0f}s eta {eta:6.0f}s{m[:60]:60s}")
        if self.done == self.total:
            self.stream.write("\n")
        self.stream.flush()


def execute(configs, store: ResultStore | str, *, workers: int | None = None, scheduler=None,
            progress: bool = True, retry_errors: bool = False, stream=None) -> list[dict]:
    """Run every config whose key is not yet in ``store``; append each row as it finishes.

    ``scheduler``: None (a local process pool with ``workers`` processes, default ``os.cpu_count()``;
    ``workers=0`` runs in this process), a Dask scheduler address, or a ``distributed.Client``.
    Returns the rows of all ``configs`` (finished earlier or now).
    """
    store = store if isinstance(store, ResultStore) else ResultStore(store)
    done = store.done_keys(retry_errors=retry_errors)
    keyed = {}
    for c in configs:
        keyed.setdefault(config_hash(c), c)
    todo = [(k, c) for k, c in keyed.items() if k not in done]
    bar = _Progress(len(todo), len(keyed) - len(todo), stream) if progress and todo else None

    def finish(row):
        store.append(row)
        if bar:
            bar.update(row)

    if todo:
        if scheduler is not None:
            from distributed import Client, as_completed as dask_completed
            client = scheduler if isinstance(scheduler, Client) else Client(scheduler)
            try:
                futs = [client.submit(run_config, c, key=f"gendr-run-{k}", pure=False) for k, c in todo]
                for fut in dask_completed(futs):
                    finish(fut.result())
            finally:
                if client is not scheduler:
                    client.close()
        elif workers == 0:
            for _, c in todo:
                finish(run_config(c))
        else:
            import multiprocessing as mp
            n = workers or os.cpu_count() or 1
            with ProcessPoolExecutor(max_workers=min(n, len(todo)), mp_context=mp.get_context("spawn")) as ex:
                futs = [ex.submit(run_config, c) for _, c in todo]
                for fut in as_completed(futs):
                    finish(fut.result())
    rows = {r["key"]: r for r in store.rows()}
    return [rows[k] for k in keyed if k in rows]


# ------------------------------------------------------------------------------------------------
# the paper's best-setting search
# ------------------------------------------------------------------------------------------------

def aggregate(rows) -> dict:
    """Mean over seeds (and elevations) of the runs of one setting. ``score``: lower is better —
    the mean hard IoU loss (shape) or the failure rate 1 − success rate, ties broken by mean error
    (pose). Failed/non-finite runs count as the worst value (IoU loss 1, pose failure)."""
    rows = list(rows)
    exp = rows[0]["experiment"]
    vals = [r["metric"] if r.get("metric") is not None else (1.0 if exp == "shape" else 180.0) for r in rows]
    out = {"n": len(rows), "mean_metric": float(np.mean(vals)), "seconds": float(np.mean([r["seconds"] for r in rows]))}
    if exp == "pose":
        sr = float(np.mean([bool(r.get("success")) for r in rows]))
        out.update(success_rate=sr, score=(1.0 - sr) + 1e-6 * out["mean_metric"] / 180.0)
    else:
        out["score"] = out["mean_metric"]
    return out


def _group(rows, keys):
    groups = {}
    for r in rows:
        groups.setdefault(tuple(r.get(k) for k in keys), []).append(r)
    return groups


def fine_grid(best: float, steps=(-0.5, -0.25, 0.25, 0.5)) -> list[float]:
    """τ values around ``best`` at ``best·10^s`` (the finer, second stage of the search)."""
    return [float(f"{best * 10 ** s:.6g}") for s in steps]


def best_setting_search(experiment: str, instances, *, taus, lrs, seeds=(0,), base=None, extra_axes=None,
                        refine: bool = True, fine_steps=(-0.5, -0.25, 0.25, 0.5), store, **execute_kw) -> list[dict]:
    """The paper's search: for every instance run the coarse τ grid × learning rates × seeds (× extra
    axes, e.g. elevations); then a finer τ grid around each instance's best τ (at its best learning
    rate). Returns :func:`summarize_best` of all rows."""
    tau_key = EXPERIMENTS[experiment]
    axes = {tau_key: list(taus), "lr": list(lrs), "seed": list(seeds), **(extra_axes or {})}
    configs = expand(experiment, base, instances=instances, axes=axes)
    rows = execute(configs, store, **execute_kw)
    if refine:
        fine = []
        for inst, best in summarize_best(rows, experiment).items():
            ax = {tau_key: fine_grid(best[tau_key], fine_steps), "lr": [best["lr"]], "seed": list(seeds),
                  **(extra_axes or {})}
            fine += expand(experiment, base, instances=[inst], axes=ax)
        rows = rows + execute(fine, store, **execute_kw)
    return summarize_best(rows, experiment)


def summarize_best(rows, experiment: str | None = None) -> dict:
    """instance -> the best setting: ``{tau(_start), lr, score, mean_metric, (success_rate), n}``."""
    rows = [r for r in rows if experiment is None or r["experiment"] == experiment]
    if not rows:
        return {}
    tau_key = EXPERIMENTS[rows[0]["experiment"]]
    best = {}
    for (inst, tau, lr), grp in _group(rows, ("instance", tau_key, "lr")).items():
        agg = aggregate(grp)
        agg.update({tau_key: tau, "lr": lr, "label": grp[0].get("label")})
        if inst not in best or agg["score"] < best[inst]["score"]:
            best[inst] = agg
    return best
