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
import re
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from gendr.errors import GendrError, InputValueError, ParameterError

from .common import _is_int, config_hash, provenance, read_source_hash, source_hash

__all__ = ["EXPERIMENTS", "OtherCodeError", "SchedulerUnreachableError", "ResultsFileError", "full_config",
           "expand", "run_config", "ResultStore", "execute", "load_rows", "check_row", "aggregate",
           "best_setting_search", "fine_grid", "check_fine_steps", "summarize_best", "write_csv", "verify_rows",
           "DRIFT_TOLERANCE", "AVERAGED_KEYS"]

#: experiment name -> (defaults, runner path, the config key the τ grid sets, lower_is_better aggregate)
EXPERIMENTS = {"shape": "tau", "pose": "tau_start"}

#: where a run's soft renders run (:func:`run_config`)
DEVICES = ("cpu", "cuda")


def full_config(experiment: str, overrides: dict) -> dict:
    """The full config of one run: the preset named by ``overrides["protocol"]`` (default ``quick``)
    of ``experiment`` with ``overrides`` applied (unknown keys are an error)."""
    if experiment == "shape":
        from .shape import shape_config as make
    elif experiment == "pose":
        from .pose import pose_config as make
    else:
        raise ParameterError(f"unknown experiment {experiment!r}; expected one of {sorted(EXPERIMENTS)}")
    cfg = make(overrides)
    cfg["experiment"] = experiment
    return cfg


def expand(experiment: str, base: dict | None = None, *, instances=(None,), axes: dict | None = None) -> list[dict]:
    """Full configs of the Cartesian product ``instances × axes`` (``instances``: grid indices, or dicts
    of config keys for runs outside the grid such as ``{"distribution": {...}, "tconorm": "average"}``;
    ``axes``: key -> list of values,
    e.g. ``{"tau": [1e-1, 1e-2], "lr": [0.05], "seed": [0, 1]}``; a tuple of keys takes tuples of
    values, ``{("angle_min", "angle_max"): [(15, 35), (35, 55)]}``), over ``base``."""
    axes = dict(axes or {})
    keys = list(axes)
    out = []
    for inst in instances:
        for values in itertools.product(*(axes[k] for k in keys)):
            ov = dict(base or {})
            if isinstance(inst, dict):  # outside the grid: {"distribution": {...}, "tconorm": ...}
                ov.update(inst)
            elif inst is not None:
                ov["instance"] = int(inst)
            for k, v in zip(keys, values):  # a tuple of keys takes a tuple of values (e.g. a pose bin)
                ov.update(zip(k, v) if isinstance(k, tuple) else [(k, v)])
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


def _single_thread():
    """One thread in torch and Dr.Jit: a run gives the same numbers wherever it runs (Dr.Jit's
    multi-threaded scatter-adds sum in a varying order)."""
    import torch
    torch.set_num_threads(1)
    try:
        import drjit
        drjit.set_thread_count(1)
    except ImportError:  # pragma: no cover - drjit is optional
        pass


def run_config(cfg: dict, device: str = "cpu", code_hash: str | None = None) -> dict:
    """Run one config (in any process) and return its result row: the metrics, the config, and the
    provenance (:func:`~gendr_experiments.common.provenance`: versions, source hash, backend,
    device, dtype, threads). One thread, so a run gives the same numbers wherever it runs.
    Exceptions become rows with ``status="error"``.

    The row's ``code_hash`` is this process's (:func:`~gendr_experiments.common.source_hash`, read
    when it first ran). The run is an error row (``CodeChangedError``) if the source on disk differs
    from it when the run ends, or from ``code_hash``, the hash the calling sweep checked its
    finished rows against: a file edited while a sweep runs would otherwise be recorded under a hash
    of code that did not run.

    ``device="cuda"`` (drjit backend only) runs the soft renders of the optimisation on Dr.Jit's
    CUDA variant; the model, losses, Adam, the target silhouettes and the hard IoU metric stay on
    the CPU, as in a CPU run. The device is a run-time option, not part of the config: the row's
    key is the CPU run's, and its provenance records the device."""
    if device not in DEVICES:
        raise ParameterError(f"device={device!r} must be one of {DEVICES}")
    _single_thread()
    from .common import instance_from_config
    backend = cfg.get("backend", "torch")
    ran_with = source_hash(backend)  # before this run's lazy imports (backend, shape / pose)
    t0, c0 = time.perf_counter(), time.process_time()
    row = {"key": config_hash(cfg), "experiment": cfg["experiment"], "instance": cfg.get("instance"),
           "protocol": cfg.get("protocol")}
    res = {}
    try:
        dist, tcn, label = instance_from_config(cfg)
        row.update(label=label, distribution=dist.label().replace("+sq", ""), squared=bool(dist.squared),
                   tconorm=tcn.label())
        if device == "cuda" and cfg.get("backend") != "drjit":
            raise ParameterError(f"device='cuda' needs the drjit backend, this config has {cfg.get('backend')!r}")
        options = {"device": "cuda"} if device == "cuda" else None
        if cfg["experiment"] == "shape":
            from .shape import run_shape
            res = run_shape(cfg, backend_options=options)
        else:
            from .pose import run_pose
            res = run_pose(cfg, backend_options=options)
        res.pop("final_vertices", None)
        res.pop("faces", None)
        row.update(res)
        row["status"] = "ok"
    except Exception as exc:  # recorded, not raised: one bad instance must not kill a 1,242-run sweep
        row.update(status="error", error=f"{type(exc).__name__}: {exc}", metric=None)
    for k in ("tau", "tau_start", "lr", "seed", "elevation", "target", "image_size", "steps", "bin"):
        if k in cfg:
            row[k] = cfg[k]
    row["seconds"] = time.perf_counter() - t0
    row["cpu_seconds"] = time.process_time() - c0  # beside wall seconds: what a run costs on a shared machine
    row["config"] = cfg
    row["provenance"] = provenance(backend, device, ran_with)
    row["code_hash"] = ran_with
    on_disk = read_source_hash(backend)
    if on_disk != ran_with or (code_hash is not None and code_hash != ran_with):
        for k in set(res) - {"seconds"}:  # no results of unknown code (successes, errors, ...: aggregate
            row.pop(k, None)             # would read them); the wall seconds are this runner's, kept
        started = f", {code_hash} when the sweep started" if code_hash is not None else ""
        row.update(status="error", metric=None,
                   error=f"CodeChangedError: the source changed while this run ran: code_hash {ran_with} in this "
                         f"process{started}, {on_disk} on disk now; which code ran is unknown: run it again")
    row["finished_at"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    return _clean(row)


class OtherCodeError(GendrError, RuntimeError):
    """A results file holds finished rows of the requested configs that other code made."""


class SchedulerUnreachableError(GendrError, ConnectionError):
    """Nothing answers at the Dask scheduler address (refused, unknown host, unreachable)."""


def _reach_scheduler(address: str, timeout: float = 5.0):
    """Raise :class:`SchedulerUnreachableError` naming ``address`` when no TCP listener answers there
    within ``timeout`` s: ``distributed`` retries a refused connection for its whole connect
    timeout (30 s) before saying so. Only tcp:// and tls:// addresses are probed."""
    import socket
    from urllib.parse import urlsplit
    u = urlsplit(address)
    if u.scheme not in ("tcp", "tls") or not u.hostname:
        return
    try:
        port = u.port or 8786
    except ValueError as exc:  # urlsplit checks the port only when asked: "Port out of range 0-65535"
        raise SchedulerUnreachableError(f"Dask scheduler address {address!r}: {exc}") from None
    try:
        socket.create_connection((u.hostname, port), timeout=timeout).close()
    except OSError as exc:
        why = exc.strerror or type(exc).__name__
        raise SchedulerUnreachableError(f"no Dask scheduler answers at {address} ({why}); start one there with "
                                        f"`dask scheduler` and its workers with `dask worker {address}`") from None


def check_base(base, decided: dict, who: str, fixed=None):
    """A :class:`~gendr.errors.ParameterError` for a setting of ``base`` that ``who`` sets itself
    (``decided``: its name -> what sets it): it would be overwritten without a word. ``fixed``: name
    -> the one value ``who`` sets (a base setting equal to it is no conflict)."""
    fixed = fixed or {}
    for k in base or {}:
        if k in decided and not (k in fixed and base[k] == fixed[k]):
            raise ParameterError(f"{who}: setting {k}={base[k]!r} (base, CLI --set) is set by {decided[k]}; "
                                 f"give it there")


class ResultStore:
    """Append-only JSON-lines table of result rows keyed by ``key``. A torn line (the process was
    killed while writing) is ignored when reading (:func:`load_rows`)."""

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


class ResultsFileError(InputValueError):
    """A results file with a line that is not a result row: not JSON (and not a row cut short by a
    kill), or a row missing a field or with a field of the wrong type. Names the file and line."""


def _number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


#: field -> (test, what it must be): every row has these (run_config writes them, errors included),
#: and a finished (status ok) row its ``seconds``
ROW_FIELDS = {
    "key": (lambda v: isinstance(v, str) and v != "", "a non-empty string"),
    "experiment": (lambda v: v in EXPERIMENTS, f"one of {sorted(EXPERIMENTS)}"),
    "status": (lambda v: v in ("ok", "error"), "'ok' or 'error'"),
    "config": (lambda v: isinstance(v, dict), "an object, the run's full config"),
    "metric": (lambda v: v is None or _number(v), "a number or null"),
}
#: field -> (test, what it must be) where a row has it (older rows lack some; error rows of code
#: changed during the run lack ``seconds``)
OPTIONAL_ROW_FIELDS = {
    "seconds": (lambda v: _number(v) and v >= 0, "a number of seconds >= 0"),
    **{k: (lambda v: v is None or _number(v), "a number or null") for k in ("cpu_seconds",)},
    **{k: (_number, "a number") for k in ("tau", "tau_start", "lr", "elevation")},
    **{k: (_is_int, "an integer") for k in ("seed", "pairs")},
    "instance": (lambda v: v is None or _is_int(v), "an integer or null"),
    "successes": (lambda v: v is None or _is_int(v), "an integer or null"),
    "label": (lambda v: isinstance(v, str), "a string"),
    "residual_deg": (lambda v: v is None or (isinstance(v, list) and all(x is None or _number(x) for x in v)),
                     "a list of numbers or null"),
}


def check_row(row, where: str = "a row") -> None:
    """:class:`ResultsFileError` naming ``where`` (file and line) and the first missing or
    ill-typed field of ``row`` (:data:`ROW_FIELDS`, :data:`OPTIONAL_ROW_FIELDS`): readers index
    these fields, so a bad row is reported here, not as a KeyError or TypeError later."""
    if not isinstance(row, dict) or "key" not in row:
        raise ResultsFileError(f"{where} is not a result row (a JSON object with a 'key'): {json.dumps(row)[:60]}")
    fields = {**ROW_FIELDS, **OPTIONAL_ROW_FIELDS}
    for k in [*ROW_FIELDS, *(["seconds"] if row.get("status") == "ok" else [])]:
        if k not in row:
            raise ResultsFileError(f"{where}: the row lacks the field {k!r}, which must be {fields[k][1]}")
    for k, (ok, want) in fields.items():
        if k in row and not ok(row[k]):
            raise ResultsFileError(f"{where}: field {k}={row[k]!r} must be {want}")


#: what may follow the point where a row cut short by a kill stops parsing: the rest of an open
#: string, of a \u escape, or of a number or literal (json reports those errors at their start)
_TORN_TAIL = re.compile(r'(?:"(?:[^"\\]|\\.)*\\?|\\u[0-9a-fA-F]{0,3}|[-+.0-9eEtruefalsn]*)')


def _torn(line: str, err: json.JSONDecodeError) -> bool:
    """Is ``line`` the start of a row whose writer was killed (a prefix of a JSON object)? Such a
    line stays where it is when the resumed sweep appends after it, so it is not always the last."""
    return line.startswith("{") and _TORN_TAIL.fullmatch(line[err.pos:]) is not None


def load_rows(path) -> list[dict]:
    """Rows of a results file; the last row per key wins (a retried error replaces the error).
    A row cut short by a kill (a prefix of a JSON object) is skipped: its key reruns. Any other line
    that is not a valid row (:func:`check_row`) is a :class:`ResultsFileError` naming file and line."""
    path = Path(path)
    if not path.exists():
        return []
    by_key = {}
    for i, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError as err:
            if _torn(line, err):
                continue  # a torn line (a run killed while writing); its key reruns
            raise ResultsFileError(f"{path}: line {i} is not JSON ({err.msg}, column {err.pos + 1}) and not a row "
                                   f"cut short by a kill: {line[:60]!r}; repair or delete that line") from None
        check_row(row, f"{path}: line {i}")
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


def _progress_bar(total, skipped, stream=None):
    """A tqdm bar over the runs still to do (the finished ones are counted in its description)."""
    from tqdm import tqdm
    return tqdm(total=total, desc=f"runs (skipped {skipped} finished)", unit="run", file=stream or sys.stderr,
                dynamic_ncols=True, mininterval=0.5)


OTHER_CODE = ("refuse", "keep", "rerun")


def execute(configs, store: ResultStore | str, *, workers: int | None = None, scheduler=None,
            progress: bool = True, retry_errors: bool = False, other_code: str = "refuse",
            stream=None, deadline: float | None = None, device: str = "cpu") -> list[dict]:
    """Run every config whose key is not yet in ``store``; append each row as it finishes.
    ``device``: :func:`run_config`'s.

    ``scheduler``: None (a local process pool with ``workers`` processes, default ``os.cpu_count()``;
    ``workers=0`` runs in this process), a Dask scheduler address, or a ``distributed.Client``.
    ``other_code``: what to do with finished rows of these configs whose ``code_hash`` differs from
    the code here (:func:`~gendr_experiments.common.source_hash`; rows without one count as other
    code): ``"refuse"`` (default) raises :class:`OtherCodeError` before running anything, ``"keep"``
    counts them as done (each row still records the code that made it), ``"rerun"`` runs them again
    (the new row replaces the old one when read).
    ``deadline``: a :func:`time.monotonic` value after which no further run is started (runs
    already started finish and are stored; the rest stay to do, as after an interruption).
    On a Dask cluster every connected worker must run this code (same
    :func:`~gendr_experiments.common.source_hash`), else :class:`OtherCodeError` before anything runs.
    Returns the rows of all ``configs`` (finished earlier or now).
    """
    if other_code not in OTHER_CODE:
        raise ParameterError(f"other_code={other_code!r} must be one of {OTHER_CODE}")
    store = store if isinstance(store, ResultStore) else ResultStore(store)
    keyed = {}
    for c in configs:
        keyed.setdefault(config_hash(c), c)
    finished = {r["key"]: r for r in store.rows()
                if r["key"] in keyed and not (retry_errors and r.get("status") == "error")}
    def sweep_hash(c):  # what the finished rows are checked against; each run checks it again
        return source_hash(c.get("backend", "torch"))
    stale = {k: r.get("code_hash") for k, r in finished.items() if r.get("code_hash") != sweep_hash(keyed[k])}
    if stale and other_code == "refuse":
        here = sorted({source_hash(keyed[k].get("backend", "torch")) for k in stale})
        raise OtherCodeError(
            f"{len(stale)} of the {len(finished)} finished rows of these runs in {store.path} were made by "
            f"other code (code_hash {sorted(map(str, set(stale.values())))}; this code: {here}). Pass "
            f"other_code='keep' (CLI --other-code keep) to count them as done, or 'rerun' to run them again")
    done = set(finished) - (set(stale) if other_code == "rerun" else set())
    todo = [(k, c) for k, c in keyed.items() if k not in done]
    if todo and isinstance(scheduler, str):  # before the progress bar: an address error is one line
        _reach_scheduler(scheduler)
    bar = _progress_bar(len(todo), len(keyed) - len(todo), stream) if progress and todo else None

    def finish(row):
        store.append(row)
        if bar:
            bar.set_postfix_str(f"last: {row.get('label')} metric={row.get('metric')}"[:70], refresh=False)
            bar.update(1)

    def late():
        return deadline is not None and time.monotonic() >= deadline

    if todo and not late():
        if scheduler is not None:
            from distributed import Client, as_completed as dask_completed
            if isinstance(scheduler, Client):
                client = scheduler
            else:
                client = Client(scheduler)
            try:
                _check_cluster_code(client, {c.get("backend", "torch") for _, c in todo})
                futs = [client.submit(run_config, c, device, sweep_hash(c), key=f"gendr-run-{k}", pure=False)
                        for k, c in todo]
                for fut in dask_completed(futs):
                    if not fut.cancelled():
                        finish(fut.result())
                    if late():
                        client.cancel([f for f in futs if not f.done()])
            finally:
                if client is not scheduler:
                    client.close()
        elif workers == 0:
            for _, c in todo:
                if late():
                    break
                finish(run_config(c, device, sweep_hash(c)))
        else:
            import multiprocessing as mp
            n = workers or os.cpu_count() or 1
            with ProcessPoolExecutor(max_workers=min(n, len(todo)), mp_context=mp.get_context("spawn")) as ex:
                futs = [ex.submit(run_config, c, device, sweep_hash(c)) for _, c in todo]
                for fut in as_completed(futs):
                    if not fut.cancelled():
                        finish(fut.result())
                    if late():
                        for f in futs:
                            f.cancel()  # queued runs only; started ones finish
    if bar:
        bar.close()
    rows = {r["key"]: r for r in store.rows()}
    return [rows[k] for k in keyed if k in rows]


def _worker_code_hashes(backends) -> dict:
    return {b: source_hash(b) for b in backends}


def _check_cluster_code(client, backends):
    """Every worker connected to ``client`` computes the source hash of ``backends`` and must agree
    with this process: a node with other code would write rows that resume then refuses."""
    backends = sorted(backends)
    here = _worker_code_hashes(backends)
    there = client.run(_worker_code_hashes, backends)
    other = {w: h for w, h in there.items() if h != here}
    if other:
        raise OtherCodeError(f"{len(other)} of {len(there)} Dask workers run other code than this client "
                             f"(code_hash {here}): {other}. Give every node the same checkout")


# ------------------------------------------------------------------------------------------------
# the paper's best-setting search
# ------------------------------------------------------------------------------------------------

def aggregate(rows) -> dict:
    """Mean over seeds (and elevations, bins) of the runs of one setting. ``score``: lower is better —
    the mean hard IoU loss (shape) or the failure rate 1 − success rate over all pairs, ties broken
    by the mean final error over all pairs (pose). Failed/non-finite runs count as the worst value
    (IoU loss 1, every pair failed, an error of 180°)."""
    rows = list(rows)
    exp = rows[0]["experiment"]
    vals = [r["metric"] if r.get("metric") is not None else (1.0 if exp == "shape" else 180.0) for r in rows]
    secs = [r["seconds"] for r in rows if r.get("seconds") is not None]  # (error rows may have none)
    out = {"n": len(rows), "mean_metric": float(np.mean(vals)), "seconds": float(np.mean(secs)) if secs else math.nan,
           "errors": sum(r.get("status") == "error" for r in rows)}
    if exp == "pose":
        if any("pairs" in r for r in rows):  # lookat rows: a batch of pairs each
            def n_pairs(r):
                return int(r.get("pairs") or r["config"].get("pairs", 1))
            ok = [r.get("status") == "ok" for r in rows]  # an error row's pairs all failed, at 180°
            pairs = sum(n_pairs(r) for r in rows)
            sr = sum(int(r.get("successes") or 0) for r, o in zip(rows, ok) if o) / pairs
            err = [_finite_or(e, 180.0) for r, o in zip(rows, ok)
                   for e in ((r.get("residual_deg") if o else None) or [None] * n_pairs(r))]
            out.update(pairs=pairs, success_rate=sr, score=(1.0 - sr) + 1e-6 * float(np.mean(err)) / 180.0)
        else:
            sr = float(np.mean([r.get("status") == "ok" and bool(r.get("success")) for r in rows]))
            out.update(success_rate=sr, score=(1.0 - sr) + 1e-6 * out["mean_metric"] / 180.0)
    else:
        out["score"] = out["mean_metric"]
    return out


def _finite_or(x, worst):
    return float(x) if x is not None and math.isfinite(x) else worst


def fine_grid(best: float, steps=(-0.5, -0.25, 0.25, 0.5), coarse=()) -> list[float]:
    """τ values around ``best`` at ``best·10^s`` (the finer, second stage of the search), rounded to 6
    digits, except where ``best·10^s`` is (to 1e-9, relative) ``best`` or a ``coarse`` τ: then that
    τ exactly, the same run (key) rather than a rerun at a rounded τ (squared widths such as
    sqrt(0.1) are not 6-digit numbers)."""
    known = (best, *coarse)
    out = []
    for s in steps:
        x = best * 10 ** s
        out.append(next((c for c in known if abs(x - c) <= 1e-9 * abs(c)), float(f"{x:.6g}")))
    return out


def check_fine_steps(fine_steps, taus, who: str = "fine_steps") -> list[float]:
    """``fine_steps`` as floats, or a :class:`~gendr.errors.ParameterError` naming the first step
    that is not finite or gives no finite τ > 0 around some coarse τ of ``taus`` (the best τ is
    one of them): 10**400 overflowed, 10**-400 is a τ of 0, both after the whole coarse stage."""
    steps = []
    for s in fine_steps:
        try:
            s = float(s)
            ok = math.isfinite(s) and all(math.isfinite(t) and t > 0 for b in taus for t in fine_grid(float(b), [s]))
        except (TypeError, ValueError, OverflowError):
            ok = False
        if not ok:
            raise ParameterError(f"{who} step {s!r} gives no finite tau > 0 around the coarse taus {list(taus)} "
                                 f"(tau = best_tau * 10**step)")
        steps.append(s)
    return steps


#: config keys that name the renderer instance (set by a search's instance list, never by its base)
INSTANCE_KEYS = ("instance", "distribution", "tconorm")
#: the CLI options that set a search axis (for error messages)
AXIS_OPTIONS = {"tau": "--taus", "tau_start": "--taus", "lr": "--lrs", "seed": "--seeds", "elevation": "--elevations",
                "angle_min": "--bins", "angle_max": "--bins"}


def best_setting_search(experiment: str, instances, *, taus, lrs, seeds=(0,), base=None, extra_axes=None,
                        refine: bool = True, fine_steps=(-0.5, -0.25, 0.25, 0.5), store, **execute_kw) -> list[dict]:
    """The paper's search: for every instance run the coarse τ grid × learning rates × seeds (× extra
    axes, e.g. elevations); then a finer τ grid around each instance's best τ (at its best learning
    rate). Returns :func:`summarize_best` of all rows."""
    tau_key = EXPERIMENTS[experiment]
    axes = {tau_key: list(taus), "lr": list(lrs), "seed": list(seeds), **(extra_axes or {})}
    decided = dict.fromkeys(INSTANCE_KEYS, "the instances (CLI --instances, --dists, --tconorms)")
    for k in axes:
        for name in (k if isinstance(k, tuple) else (k,)):
            decided[name] = f"the search axis {name} (CLI {AXIS_OPTIONS.get(name, '--' + name)})"
    check_base(base, decided, f"the {experiment} search")
    if refine:  # (a bad step failed only after the whole coarse stage)
        fine_steps = check_fine_steps(fine_steps, taus, f"the {experiment} search's fine_steps (CLI --fine-steps)")
    configs = expand(experiment, base, instances=instances, axes=axes)
    rows = execute(configs, store, **execute_kw)
    if refine:
        fine = []
        from .common import instance_from_config
        by_label = {instance_from_config(c)[2]: c for c in instances if isinstance(c, dict)}
        for inst, best in summarize_best(rows, experiment).items():
            ax = {tau_key: fine_grid(best[tau_key], fine_steps, taus), "lr": [best["lr"]], "seed": list(seeds),
                  **(extra_axes or {})}
            if isinstance(inst, str):
                if inst not in by_label:
                    continue  # a row of the store that this search did not ask for
                inst = by_label[inst]
            fine += expand(experiment, base, instances=[inst], axes=ax)
        rows = rows + execute(fine, store, **execute_kw)
    return summarize_best(rows, experiment)


#: config keys a setting's runs are averaged over (:func:`aggregate`): seeds, shape elevations
#: (``--elevations``), pose bins (``--bins``); every other config key makes another setting
AVERAGED_KEYS = ("seed", "elevation", "angle_min", "angle_max")


def _setting(row, tau_key) -> str:
    """The config of ``row`` but the averaged axes (and the instance, τ and lr, which
    :func:`summarize_best` groups by): rows of one setting agree on it."""
    skip = {*AVERAGED_KEYS, *INSTANCE_KEYS, tau_key, "lr"}
    return json.dumps({k: v for k, v in (row.get("config") or {}).items() if k not in skip}, sort_keys=True)


def summarize_best(rows, experiment: str | None = None) -> dict:
    """instance -> the best setting: ``{tau(_start), lr, score, mean_metric, (success_rate), n, errors, label}``.
    Runs outside the grid (no instance index, e.g. the "average" aggregation) are keyed by label.
    A setting is an instance, τ, lr and every other config key but :data:`AVERAGED_KEYS`: its runs
    (seeds, elevations, bins) are averaged; rows that differ in another key (steps, image size,
    target, ...) are other settings, never averaged together. Settings whose runs all ended in an
    error have no result and are left out."""
    rows = [r for r in rows if experiment is None or r["experiment"] == experiment]
    if not rows:
        return {}
    tau_key = EXPERIMENTS[rows[0]["experiment"]]
    best = {}
    groups = {}
    for r in rows:
        groups.setdefault((r.get("instance"), r.get("label"), r.get(tau_key), r.get("lr"), _setting(r, tau_key)),
                          []).append(r)
    for (inst, label, tau, lr, _), grp in groups.items():
        if all(r.get("status") == "error" for r in grp):
            continue  # no result (a bad target, a crash): not a score of 1, and no finer grid around it
        agg = aggregate(grp)
        agg.update({tau_key: tau, "lr": lr, "label": label})
        key = inst if inst is not None else label  # runs outside the grid (e.g. "average") by label
        if key not in best or agg["score"] < best[key]["score"]:
            best[key] = agg
    return best


# ------------------------------------------------------------------------------------------------
# drift: re-run finished rows
# ------------------------------------------------------------------------------------------------

#: how far a re-run's metric may move from the stored one before ``verify`` calls it drift, when the
#: code differs (same code on one thread must reproduce a row exactly: drift 0). Shape: absolute hard
#: IoU loss; 0.03 because reordering floating-point sums alone (the torch vs the drjit backend on
#: the same quick configs) moved single runs by up to 0.022 (docs/experiments.md, "Provenance and
#: drift"). Pose: one pair of a batch changing sides of the success threshold (lookat, failure rate
#: ``1/pairs``) or 1 degree of final error (rotation). A look-at row's failure rate can sit at 1 (no
#: pair succeeds), where no regression moves it: its median final error is compared too, to 1
#: degree ("pose_residual"; code changes moved the committed row's by 0.46).
DRIFT_TOLERANCE = {"shape": 0.03, "pose_rotation": 1.0, "pose_residual": 1.0}


def drift_tolerance(row: dict) -> float:
    """The tolerance :func:`verify_rows` applies to ``row`` when the code differs (see :data:`DRIFT_TOLERANCE`)."""
    if row["experiment"] == "shape":
        return DRIFT_TOLERANCE["shape"]
    if row.get("pairs"):
        return 1.0 / int(row["pairs"]) + 1e-9
    return DRIFT_TOLERANCE["pose_rotation"]


def verify_rows(rows, *, sample: int | None = None, seed: int = 0, tolerance: float | None = None,
                device: str = "cpu") -> list[dict]:
    """Re-run ``sample`` rows (all when None; a seeded random choice otherwise) from their stored
    configs and compare the metrics. The tolerance is 0 when the row's code hash is this code's and it
    ran on this CPU's SIMD level (one thread then reproduces a run exactly; rows that do not record
    their CPU count as another), else :func:`drift_tolerance`, unless ``tolerance`` is given.
    Returns one dict per row: ``key``, ``label``, ``stored``, ``now``, ``drift`` (absolute),
    ``tolerance``, ``ok``, ``same_code``, ``stored_code``, ``code``, ``same_cpu``, ``stored_simd``,
    ``simd``, ``seconds``, ``status`` ("ok", "drift", or "error: MESSAGE" when the re-run itself
    failed: a missing data file is not a drift, and its ``drift`` is None); for look-at pose rows also
    ``residual_drift`` (of the median final error,
    degrees) and ``residual_tolerance`` (0 when exact, else DRIFT_TOLERANCE["pose_residual"];
    ``tolerance`` given applies to the metric only). ``drift`` is None where only one of the stored
    and the new metric is a number (a run that became non-finite: beyond any tolerance). Rows that
    ended in an error are skipped.
    ``device``: where the re-runs render (:func:`run_config`); a row made on another device (its
    provenance's ``device``, "cpu" when absent), or any re-run on a GPU, is never exact."""
    rows = [r for r in rows if r.get("status") == "ok"]
    if sample is not None and sample < len(rows):
        pick = np.random.default_rng(seed).choice(len(rows), size=sample, replace=False)
        rows = [rows[i] for i in sorted(pick)]
    out = []
    for r in rows:
        now = run_config(r["config"], device)
        same = r.get("code_hash") == now["code_hash"]
        stored_simd = r.get("provenance", {}).get("cpu", {}).get("simd")
        simd = now["provenance"]["cpu"]["simd"]
        same_device = r.get("provenance", {}).get("device", "cpu") == device
        # (never exact on a GPU: Dr.Jit's CUDA backward sums with atomics, in a varying order)
        exact = same and stored_simd == simd and same_device and device == "cpu"
        tol = (0.0 if exact else drift_tolerance(r)) if tolerance is None else float(tolerance)
        a, b = r.get("metric"), now.get("metric")
        failed = now.get("status") == "error"
        if failed:  # no new metric to compare: the re-run's error, not a drift
            drift, ok = None, False
        elif a is not None and b is not None:
            drift = abs(a - b)
            ok = drift <= tol
        else:  # both non-finite (null): the same; one of them: beyond any tolerance (None: valid JSON)
            drift = 0.0 if a is None and b is None else None
            ok = drift is not None
        v = {"key": r["key"], "label": r.get("label"), "stored": a, "now": b, "drift": drift, "tolerance": tol}
        ra, rb = r.get("residual_deg_median"), now.get("residual_deg_median")
        if ra is not None and rb is not None and not failed:  # (a failure rate of 1 moves with no regression)
            v["residual_drift"] = abs(ra - rb)
            v["residual_tolerance"] = 0.0 if exact else DRIFT_TOLERANCE["pose_residual"]
            ok = ok and v["residual_drift"] <= v["residual_tolerance"]
        status = f"error: {now.get('error')}" if failed else "ok" if ok else "drift"
        out.append({**v, "ok": ok, "status": status, "same_code": same,
                    "stored_code": r.get("code_hash"), "code": now["code_hash"], "same_cpu": stored_simd == simd,
                    "stored_simd": stored_simd, "simd": simd, "same_device": same_device,
                    "seconds": now["seconds"]})
    return out
