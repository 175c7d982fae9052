"""``gendr experiment shape|pose|sweep|verify|cost|tune|figures|recon`` (also ``python -m gendr_experiments.cli``)."""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

PROG = "gendr experiment"


def _stored_lines(path) -> int:
    """Rows appended to a results file so far (every run appends one, reruns included)."""
    try:
        with open(path) as f:
            return sum(1 for line in f if line.strip())
    except FileNotFoundError:
        return 0


class UsageError(ValueError):
    """A bad option value found after parsing: one line naming it, exit status 2 (:func:`main`)."""


def _floats(text, option="a list option", empty_ok=False):
    try:
        out = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise UsageError(f"{option} expects comma-separated numbers, got {text!r}") from None
    return out if empty_ok else _some(out, text, option)


def _some(values, text, option):
    if not values:  # an empty grid axis would mean zero runs, reported as success
        raise UsageError(f"{option} lists no values: got {text!r}")
    return values


def _ints(text, option="a list option"):
    out = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part[1:]:
                a, b = part.split("-", 1) if not part.startswith("-") else (part, part)
                if int(b) < int(a):
                    raise UsageError(f"{option}: the range {part!r} runs backwards")
                out += list(range(int(a), int(b) + 1))
            else:
                out.append(int(part))
        except ValueError as exc:
            if isinstance(exc, UsageError):
                raise
            raise UsageError(f"{option} expects integers and ranges like 0-26,54, got {part!r}") from None
    return _some(out, text, option)


def _bins(text):
    """--bins "15-35,35-55": [(15.0, 35.0), (35.0, 55.0)] (angle ranges in degrees, low < high)."""
    out = []
    for b in text.split(","):
        if not b.strip():
            continue
        parts = b.strip().split("-")
        try:
            lo, hi = (float(x) for x in parts)
        except ValueError:
            raise UsageError(f"--bins expects ranges LOW-HIGH in degrees like 15-35,35-55, got {b.strip()!r}") from None
        if not lo < hi:
            raise UsageError(f"--bins {b.strip()!r} runs backwards or is empty")
        out.append((lo, hi))
    return out


def _kv(items, option="--set"):
    out = {}
    for it in items or []:
        k, _, v = it.partition("=")
        if not _:
            raise UsageError(f"{option} expects NAME=VALUE, got {it!r}")
        try:
            out[k.strip().replace("-", "_")] = json.loads(v)
        except json.JSONDecodeError:
            out[k.strip().replace("-", "_")] = v
    return out


def _base_settings(a, **own):
    """The --set settings plus those of the command's own options (``own``: name -> value, None
    where not given); a setting given both ways is an error, not a silent choice of one."""
    base = _kv(a.set)
    for k, v in own.items():
        if v is not None:
            if k in base:
                raise UsageError(f"--set {k}={base[k]!r} and --{k} {v!r} both set {k}: give --{k} only")
            base[k] = v
    return base


def _instance_options(p):
    g = p.add_argument_group("renderer instance (default: logistic + probabilistic)")
    g.add_argument("--instance", type=int, default=None, metavar="K", help="instance K of `gendr list grid`")
    g.add_argument("--distribution", default="logistic", metavar="NAME")
    g.add_argument("--dist-param", action="append", metavar="NAME=VALUE", help="e.g. shape=0.5 (repeatable)")
    g.add_argument("--reversed", action="store_true")
    g.add_argument("--squared", action="store_true")
    g.add_argument("--tconorm", default="probabilistic", metavar="NAME")
    g.add_argument("--tconorm-param", action="append", metavar="NAME=VALUE", help="e.g. p=2 (repeatable)")
    g.add_argument("--backend", default=None, help="gendr backend (default: the protocol's: quick torch, paper drjit)")
    g.add_argument("--eps", type=float, default=None, help="coverage culling threshold (default: the protocol's)")
    g.add_argument("--cutoff", type=float, default=None,
                   help="the reference implementation's distance cut-off dist_eps (default: the protocol's: "
                        "quick none, paper 100)")
    g.add_argument("--threads", type=int, default=None,
                   help="compute threads of the backend (default: its own; with drjit torch keeps 1)")


def _device_option(p):
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="cuda: the soft renders on Dr.Jit's CUDA variant (drjit backend, a CUDA build of "
                        "torch; the model, losses, target and hard metric stay on the CPU); rows keep the CPU "
                        "run's key and record the device. Checked here, not on Dask workers (default: %(default)s)")


def _check_device(a, backends):
    """--device cuda: every run uses the drjit backend and Dr.Jit has CUDA here."""
    if a.device != "cuda":
        return
    if set(backends) != {"drjit"}:
        raise UsageError(f"--device cuda needs the drjit backend (these runs use {sorted(set(backends))})")
    import drjit as dr
    import torch
    if not dr.has_backend(dr.JitBackend.CUDA):
        raise UsageError("--device cuda: Dr.Jit's CUDA backend is not available on this machine")
    if not torch.cuda.is_available():  # (the runs' torch tensors are copied to the GPU)
        raise UsageError("--device cuda: this torch build or machine has no CUDA (install a CUDA build of torch)")


def _protocol_options(p):
    p.add_argument("--protocol", choices=("quick", "paper"), default="quick",
                   help="named settings (docs/experiments.md, `gendr experiment protocols`); options given "
                        "here override them")
    p.add_argument("--data", default=None, metavar="DIR",
                   help="directory of the paper's user-supplied files for 'paper:FILE' targets "
                        "(default: $GENDR_PAPER_DATA or ~/.cache/gendr/paper_data)")


def _given(a, names) -> dict:
    """The options of ``names`` (argparse dest -> config key) the user gave (not None)."""
    return {key: getattr(a, dest) for dest, key in names.items() if getattr(a, dest) is not None}


def _apply_data(a):
    if getattr(a, "data", None):
        from .common import PAPER_DATA_ENV
        os.environ[PAPER_DATA_ENV] = a.data


def _instance_config(a) -> dict:
    cfg = _given(a, {"backend": "backend", "eps": "eps", "cutoff": "cutoff"})
    if getattr(a, "protocol", None):
        cfg["protocol"] = a.protocol
    if a.instance is not None:
        given = [o for o, v in (("--distribution", a.distribution != "logistic"), ("--dist-param", a.dist_param),
                                ("--reversed", a.reversed), ("--squared", a.squared),
                                ("--tconorm", a.tconorm != "probabilistic"), ("--tconorm-param", a.tconorm_param)) if v]
        if given:
            raise UsageError(f"--instance {a.instance} picks the distribution and T-conorm; do not combine it with "
                             f"{', '.join(given)}")
        cfg["instance"] = a.instance
    else:
        cfg["distribution"] = {"name": a.distribution, "reversed": a.reversed, "squared": a.squared,
                               **_kv(a.dist_param, "--dist-param")}
        cfg["tconorm"] = {"name": a.tconorm, **_kv(a.tconorm_param, "--tconorm-param")}
    return cfg


def _print_result(res, a):
    res = {k: v for k, v in res.items() if k not in ("final_vertices", "faces")}
    print(json.dumps(res, indent=2, default=str))


# ------------------------------------------------------------------------------------------------

SHAPE_OPTIONS = {"target": "target", "tau": "tau", "lr": "lr", "steps": "steps", "size": "image_size",
                 "views": "views", "elevation": "elevation", "distance": "distance", "fov": "fov_y",
                 "subdivisions": "subdivisions", "template": "template", "lambda_lap": "lambda_lap",
                 "lambda_flat": "lambda_flat", "metric": "metric", "seed": "seed"}
POSE_OPTIONS = {"target": "target", "tau_start": "tau_start", "tau_end": "tau_end", "lr": "lr", "steps": "steps",
                "size": "image_size", "angle_min": "angle_min", "angle_max": "angle_max", "loss": "loss",
                "pairs": "pairs"}


def cmd_shape(a) -> int:
    from .common import set_threads
    from .shape import run_shape, shape_config, shape_target_views
    from .figures import silhouette_frame, write_gif
    _apply_data(a)
    if a.gif_views < 1 or a.gif_every < 1:
        raise UsageError(f"--gif-views and --gif-every must be >= 1, got {a.gif_views} and {a.gif_every}")
    for path, option in ((a.gif, "--gif"), (a.output_mesh, "--output-mesh")):  # (their folders are made)
        if path is not None and Path(path).is_dir():
            raise UsageError(f"{option} {str(path)!r} is a directory; name the file to write")
    cfg = shape_config(_instance_config(a), **_given(a, SHAPE_OPTIONS))
    set_threads(cfg["backend"], a.threads)
    frames = []

    def keep_frame(step, v, sil, loss):
        if step % a.gif_every == 0:
            frames.append(sil.numpy())
    res = run_shape(cfg, callback=keep_frame if a.gif else None)
    if a.gif:
        tgt = shape_target_views(cfg)[1].numpy()
        write_gif([silhouette_frame(f, tgt, a.gif_views) for f in frames], a.gif)
        print(f"wrote {a.gif} ({len(frames)} frames)", file=sys.stderr)
    if a.output_mesh:
        _write_obj(a.output_mesh, res["final_vertices"], res["faces"])
        print(f"wrote {a.output_mesh}", file=sys.stderr)
    _print_result(res, a)
    return 0


def _write_obj(path, v, f):
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as fh:
        for x in v:
            fh.write(f"v {x[0]:.6f} {x[1]:.6f} {x[2]:.6f}\n")
        for t in f:
            fh.write(f"f {t[0] + 1} {t[1] + 1} {t[2] + 1}\n")


def cmd_pose(a) -> int:
    import numpy as np
    from .common import set_threads
    from .pose import pose_config, run_pose
    _apply_data(a)
    if a.runs < 1:
        raise UsageError(f"--runs must be >= 1, got {a.runs}")
    cfg = pose_config(_instance_config(a), **_given(a, POSE_OPTIONS))
    set_threads(cfg["backend"], a.threads)
    results = []
    for s in range(a.seed, a.seed + a.runs):
        r = run_pose(cfg, seed=s)
        results.append(r)
        if "success_rate" in r:
            print(f"seed {s}: {r['successes']}/{r['pairs']} pairs within {cfg['success_degrees']:g} deg "
                  f"(median residual {r['residual_deg_median']:.2f} deg) in {r['seconds']:.1f} s", file=sys.stderr)
        else:
            print(f"seed {s}: initial {r['initial_error']:.1f} deg -> final {r['metric']:.2f} deg "
                  f"({'success' if r['success'] else 'fail'}) in {r['seconds']:.1f} s", file=sys.stderr)
    if "success_rate" in results[0]:
        n = sum(r["pairs"] for r in results)
        summary = {"runs": len(results), "pairs": n, "success_rate": sum(r["successes"] for r in results) / n,
                   "success_degrees": cfg["success_degrees"]}
    else:
        summary = {"runs": len(results), "success_rate": float(np.mean([r["success"] for r in results])),
                   "mean_error_deg": float(np.mean([r["metric"] for r in results])),
                   "median_error_deg": float(np.median([r["metric"] for r in results]))}
    summary.update(seconds_per_run=float(np.mean([r["seconds"] for r in results])),
                   instance=results[0]["instance_label"], protocol=cfg["protocol"])
    print(json.dumps(summary, indent=2))
    return 0


def cmd_protocols(a) -> int:
    """Print the presets side by side (keys where they differ first)."""
    from .pose import POSE_PRESETS
    from .shape import SHAPE_PRESETS
    for name, presets in (("shape", SHAPE_PRESETS), ("pose", POSE_PRESETS)):
        names = list(presets)
        keys = sorted(presets[names[0]], key=lambda k: (len({repr(p[k]) for p in presets.values()}) == 1, k))
        print(f"{name}:")
        print(f"  {'setting':20s}" + "".join(f"{n:>24s}" for n in names))
        for k in keys:
            print(f"  {k:20s}" + "".join(f"{str(presets[n][k]):>24s}" for n in names))
        print()
    return 0


def select_instances(a) -> list:
    """Grid indices from --instances and/or --dists × --variants × --tconorms (labels of
    `gendr experiment sweep --list-labels`); the T-conorm label "average" (not in the grid) gives
    config dicts ``{"distribution": {...}, "tconorm": "average"}`` instead."""
    from gendr.grid import DISTRIBUTION_SETTINGS, TCONORM_SETTINGS
    from .figures import EXTRA_COLUMNS, grid_labels
    dl, tl = grid_labels()
    out = []
    unknown = [v.strip() for v in a.variants.split(",") if v.strip() not in ("plain", "squared")]
    if unknown:
        raise UsageError(f"--variants {unknown[0]!r} is not a variant; known: plain, squared")
    if a.instances:
        n = len(dl) * 2 * len(tl)
        picked = list(range(n)) if a.instances == "all" else _ints(a.instances, "--instances")
        bad = [i for i in picked if not 0 <= i < n]
        if bad:
            raise UsageError(f"--instances {bad[0]} is not an instance: the grid has 0 ... {n - 1} (gendr list grid)")
        out += picked
    if a.dists or a.tconorms:
        def pick(spec, labels, what, extra=()):
            if not spec or spec == "all":
                return list(range(len(labels)))
            idx = []
            for s in spec.split(","):
                s = s.strip()
                if s not in labels and s not in extra:
                    raise UsageError(f"unknown {what} label {s!r}; known: {', '.join(list(labels) + list(extra))}")
                idx.append(labels.index(s) if s in labels else s)
            return idx
        variants = {"plain": 0, "squared": 1}
        vs = [variants[v.strip()] for v in a.variants.split(",")]
        for d in pick(a.dists, dl, "distribution"):
            for v in vs:
                for t in pick(a.tconorms, tl, "T-conorm", EXTRA_COLUMNS):
                    if isinstance(t, str):
                        name, params, rev = DISTRIBUTION_SETTINGS[d]
                        out.append({"distribution": {"name": name, "reversed": rev, "squared": bool(v), **params},
                                    "tconorm": t})
                    else:
                        out.append((d * 2 + v) * len(TCONORM_SETTINGS) + t)
    seen, uniq = set(), []
    for i in out:
        k = json.dumps(i, sort_keys=True)
        if k not in seen:
            seen.add(k)
            uniq.append(i)
    return uniq


def search_plan(a, instances) -> dict:
    """The arguments of :func:`~gendr_experiments.sweep.best_setting_search` (but experiment and the
    run options) that a parsed ``sweep`` command line asks for."""
    from .sweep import EXPERIMENTS, full_config
    base = _base_settings(a, protocol=a.protocol, backend=a.backend)
    preset = full_config(a.experiment, base)
    extra = {}
    if a.elevations:
        extra["elevation"] = _floats(a.elevations, "--elevations")
    if a.bins:
        extra[("angle_min", "angle_max")] = _bins(a.bins)
    tau_key = EXPERIMENTS[a.experiment]
    taus = _floats(a.taus, "--taus") if a.taus else ([1e-1, 1e-2, 1e-3] if a.experiment == "shape" else [preset[tau_key]])
    lrs = _floats(a.lrs, "--lrs") if a.lrs else [preset["lr"]]
    # without --lrs (pose: --taus) the axis is the preset's value, which --set may give: taken from there
    for key, derived in (("lr", not a.lrs), (tau_key, not a.taus and a.experiment != "shape")):
        if derived:
            base.pop(key, None)
    for option, values in (("--taus", taus), ("--lrs", lrs)):
        if not all(v > 0 and v != float("inf") for v in values):
            raise UsageError(f"{option} must be numbers > 0, got {values}")
    return dict(instances=instances, taus=taus, lrs=lrs, seeds=_ints(a.seeds, "--seeds"), base=base,
                extra_axes=extra, refine=not a.no_refine, fine_steps=tuple(_floats(a.fine_steps, "--fine-steps", empty_ok=True)))


def cmd_sweep(a) -> int:
    from .figures import grid_labels
    from .sweep import EXPERIMENTS, best_setting_search, full_config, load_rows, write_csv
    if a.list_labels:
        dl, tl = grid_labels()
        print("distributions (--dists):\n  " + "\n  ".join(dl))
        from .figures import EXTRA_COLUMNS
        print("T-conorms (--tconorms):\n  " + "\n  ".join(tl))
        print("not T-conorms (--tconorms; runs outside the grid):\n  " + "\n  ".join(EXTRA_COLUMNS))
        return 0
    instances = select_instances(a)
    if not instances:
        print(f"{PROG}: error: choose instances with --instances and/or --dists/--tconorms", file=sys.stderr)
        return 2
    _apply_data(a)
    plan = search_plan(a, instances)
    tau_key = EXPERIMENTS[a.experiment]
    if a.workers is not None and a.workers < 0:
        raise UsageError(f"--workers must be >= 0 (0: in this process), got {a.workers}")
    if a.scheduler is not None:
        if a.workers is not None:
            raise UsageError("--scheduler runs on the cluster's workers; --workers is for local runs: give one")
        import re
        # tcp only: inproc:// and ucx:// passed this check, then crashed in distributed with a traceback
        if not re.fullmatch(r"tcp://[^\s:/]+(:\d+)?/?", a.scheduler):
            raise UsageError(f"--scheduler {a.scheduler!r} is not a Dask address like tcp://HOST:8786 "
                             f"(TCP is the protocol supported)")
    _writable(a.csv, "--csv")
    _rows_file(a.output)
    _check_device(a, [full_config(a.experiment, plan["base"]).get("backend")])
    kw = dict(store=a.output, workers=a.workers, scheduler=a.scheduler, retry_errors=a.retry_errors,
              progress=not a.quiet, other_code=a.other_code, device=a.device)
    t0 = time.perf_counter()
    n0 = _stored_lines(a.output)
    best = best_setting_search(a.experiment, **plan, **kw)  # (errors: main)
    rows = load_rows(a.output)
    if a.csv:
        write_csv(rows, a.csv)
    # lines appended, not distinct keys: a rerun (--other-code rerun, --retry-errors) replaces a row
    new = _stored_lines(a.output) - n0
    errors = [r for r in _last_lines(a.output, new) if r.get("status") == "error"]
    print(f"{new} runs in {time.perf_counter() - t0:.1f} s; {len(rows)} rows in {a.output}", file=sys.stderr)
    print(f"{'instance':>8s}  {'label':45s} {tau_key:>10s} {'lr':>8s} {'score':>8s}")
    for inst, b in sorted(best.items(), key=lambda kv: kv[1]["score"]):
        print(f"{str(inst) if isinstance(inst, int) else '-':>8s}  {b['label']:45s} {b[tau_key]:10.3g} {b['lr']:8.3g} {b['score']:8.4f}")
    if errors:
        print(f"{PROG}: {len(errors)} of the {new} runs ended in an error (rows with status \"error\"; "
              f"--retry-errors reruns them); the first: {errors[0]['label']}: {errors[0]['error']}", file=sys.stderr)
        return 1
    return 0


def _last_lines(path, n) -> list[dict]:
    """The last ``n`` rows appended to a results file (the runs of this invocation)."""
    if n <= 0:
        return []
    with open(path) as f:
        lines = [line for line in f if line.strip()]
    out = []
    for line in lines[-n:]:
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            pass
    return out


def _results(files, experiment=None) -> list[dict]:
    """The rows of results files (of one experiment, if given); a path that is not a file, or a line
    that is not a valid row (:func:`~gendr_experiments.sweep.check_row`), is a UsageError naming it."""
    from .sweep import load_rows
    for f in files or []:
        if not Path(f).is_file():
            raise UsageError(f"results file {str(f)!r} " + ("is a directory" if Path(f).is_dir() else "does not exist"))
    try:
        rows = [r for f in files or [] for r in load_rows(f)]
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return [r for r in rows if experiment is None or r["experiment"] == experiment]


def _probe_write(path, option):
    """A real write test of ``path`` before the work (as root, os.access says yes to /proc and
    read-only mounts; the runs then ended in an error after all of them): an existing file is opened
    for appending, writing nothing; else its folder is checked as ``gendr``'s own ``-o`` folders are
    (:func:`gendr.cli.writable_dir`; the missing ones are made when the rows are written)."""
    from gendr.cli import writable_dir
    from gendr.errors import ParameterError
    p = Path(path)
    try:
        if p.is_file():
            open(p, "ab").close()
        else:
            writable_dir(p.parent, given=str(path), option=option)
    except OSError as e:
        raise UsageError(f"{option} {str(path)!r} is not writable ({e.strerror or e})") from None
    except ParameterError as e:
        raise UsageError(str(e)) from None


def _rows_file(path):
    """-o of a sweep or tune: a JSONL file of rows to append to (new, or starting with a row); not a
    directory, not some other file (rows were appended to a CSV), and writable."""
    p = Path(path)
    if p.is_dir():
        raise UsageError(f"-o {str(path)!r} is a directory; name the JSONL file of rows")
    _probe_write(p, "-o")
    if p.is_file() and p.stat().st_size:
        with open(p, "rb") as f:
            first = f.readline(1 << 20)
        try:
            ok = isinstance(json.loads(first), dict)
        except (ValueError, UnicodeDecodeError):
            ok = False
        if not ok:
            raise UsageError(f"-o {str(path)!r} exists and is not a JSONL file of result rows; refusing to append")


def _writable(path, option):
    """Check an output file's folder before the work that fills it (a missing folder or a directory
    named as the file failed only at the end)."""
    if path is None:
        return
    p = Path(path)
    if p.is_dir():
        raise UsageError(f"{option} {str(path)!r} is a directory; name the file to write")
    if not p.parent.is_dir():
        raise UsageError(f"{option} {str(path)!r}: the folder {str(p.parent)!r} does not exist")
    _probe_write(p, option)


def _no_rows(files, what="rows") -> int:
    print(f"{PROG}: error: no {what} in {files}", file=sys.stderr)
    return 2


def cmd_verify(a) -> int:
    from .common import cpu_info
    from .sweep import verify_rows
    _apply_data(a)
    if a.sample is not None and a.sample < 1:
        raise UsageError(f"--sample must be >= 1 (omit it to re-run every row), got {a.sample}")
    if a.tolerance is not None and not a.tolerance >= 0:
        raise UsageError(f"--tolerance must be >= 0, got {a.tolerance}")
    _writable(a.json, "--json")
    rows = _results(a.results)
    if not rows:
        return _no_rows(a.results)
    if not any(r.get("status") == "ok" for r in rows):
        return _no_rows(a.results, "finished (status ok) rows to re-run")
    _check_device(a, [r["config"].get("backend") for r in rows if r.get("status") == "ok"])
    report = verify_rows(rows, sample=a.sample, seed=a.seed, tolerance=a.tolerance, device=a.device)
    print(f"{'key':16s} {'label':40s} {'stored':>9s} {'now':>9s} {'drift':>9s} {'tol':>6s} code, cpu")
    for v in report:
        fmt = lambda x: "None" if x is None else f"{x:9.4g}"
        if v["status"].startswith("error"):  # the re-run failed: nothing to compare
            print(f"{v['key']:16s} {str(v['label'])[:40]:40s} {fmt(v['stored']):>9s} re-run failed: "
                  f"{v['status'][len('error: '):]}")
            continue
        code = "same code" if v["same_code"] else f"other code ({v['stored_code']})"
        cpu = "same cpu" if v["same_cpu"] else f"other cpu ({v['stored_simd'] or 'not recorded'})"
        cpu += "" if v["same_device"] else f", other device (now {a.device})"
        resid = (f", median error drift {v['residual_drift']:.3g} deg (tol {v['residual_tolerance']:.3g})"
                 if "residual_drift" in v else "")
        print(f"{v['key']:16s} {str(v['label'])[:40]:40s} {fmt(v['stored']):>9s} {fmt(v['now']):>9s} "
              f"{fmt(v['drift']):>9s} {v['tolerance']:6.3g} {code}, {cpu}{resid}{'' if v['ok'] else '  DRIFT'}")
    failed = [v for v in report if v["status"].startswith("error")]
    bad = [v for v in report if v["status"] == "drift"]
    print(f"{len(report)} rows re-run, {len(bad)} beyond tolerance, {len(failed)} re-runs failed (an error, not a "
          f"drift), {sum(not v['same_code'] for v in report)} "
          f"made by other code, {sum(not v['same_cpu'] for v in report)} on another CPU SIMD level "
          f"(this one: {cpu_info()['simd']})", file=sys.stderr)
    if a.json:  # (drift is None, not Infinity, where there is no number: standard JSON)
        Path(a.json).write_text(json.dumps(report, indent=1, allow_nan=False))
    return 1 if bad or failed else 0


def cmd_findings(a) -> int:
    from .findings import IDENTICAL_TCONORMS, findings_markdown, noise_control, pose_similarity, shape_findings
    if not a.noise >= 0:
        raise UsageError(f"--noise must be >= 0, got {a.noise}")
    shape, pose = _results(a.results, "shape"), _results(a.pose, "pose")
    if a.pose and not pose:
        return _no_rows(a.pose, "pose rows")
    if not shape:
        return _no_rows(a.results, "shape rows")
    found = shape_findings(shape, noise=a.noise)
    if pose:
        found.append(pose_similarity(shape, pose))
    print(f"{len(shape)} shape rows" + (f", {len(pose)} pose rows" if pose else "") + "\n")
    print(findings_markdown(found))
    control = noise_control(shape, a.noise)
    if control:
        print(f"Noise control: {' ≡ '.join(IDENTICAL_TCONORMS)} are one T-conorm; over {control['pairs']} pairs "
              f"of their runs with every other setting equal, |Δ metric| median {control['median']:.4f}, "
              f"90th percentile {control['p90']:.4f}, 95th {control['p95']:.4f}, max {control['max']:.4f}; "
              f"{100 * control['over']:.1f} % beyond the {a.noise:g} per run the margins above assume")
    return 0


def cmd_figures(a) -> int:
    from .figures import make_figures
    if not 0 < a.fraction <= 1:
        raise UsageError(f"--fraction must be in (0, 1], got {a.fraction}")
    rows = _results(a.results, a.experiment)
    if not rows:
        return _no_rows(a.results, f"{a.experiment} rows" if a.experiment else "rows")
    if not any(r.get("status") == "ok" for r in rows):
        return _no_rows(a.results, "finished rows (every run ended in an error)")
    for p in make_figures(rows, a.output, experiment=a.experiment, fraction=a.fraction):
        print(p)
    return 0


def cmd_cost(a) -> int:
    from .cost import STUDIES, cost_report, format_report
    _apply_data(a)
    if not (a.hours > 0 and 0 < a.efficiency <= 1):
        raise UsageError(f"--hours must be > 0 and --efficiency in (0, 1], got {a.hours:g} and {a.efficiency:g}")
    _writable(a.json, "--json")
    rows = _results(a.results)
    if not rows:
        return _no_rows(a.results)
    studies = [s.strip() for s in a.studies.split(",") if s.strip()]
    bad = [s for s in studies if s not in STUDIES]
    if bad:
        print(f"{PROG}: error: unknown studies {bad}; known: {', '.join(STUDIES)}", file=sys.stderr)
        return 2
    held = _results(a.holdout)
    report = cost_report(rows, studies=studies, hours=a.hours, efficiency=a.efficiency, holdout=held, left=a.left)
    print(format_report(report))
    if a.json:
        Path(a.json).write_text(json.dumps(report, indent=1))
    return 0


def cmd_tune(a) -> int:
    from .tune import tune
    _apply_data(a)
    if a.top < 1:
        raise UsageError(f"--top must be >= 1, got {a.top}")
    _writable(a.json, "--json")
    _rows_file(a.output)
    instances = select_instances(a) if (a.instances or a.dists or a.tconorms) else None
    base = _base_settings(a, backend=a.backend)
    res = tune(a.target, budget=a.budget, store=a.output, protocol=a.protocol, instances=instances,
               taus=_floats(a.taus, "--taus"), lrs=_floats(a.lrs, "--lrs") if a.lrs else None,
               seeds=_ints(a.seeds, "--seeds"), fine_steps=tuple(_floats(a.fine_steps, "--fine-steps", empty_ok=True)),
               base=base, workers=a.workers, top=a.top, other_code=a.other_code)  # (errors: main)
    p = res.plan
    print(f"{res.runs} new runs in {res.seconds:.1f} s (budget {p['budget_s']:g} s): coarse grid for "
          f"{p['coarse_instances']} of {p['candidates']} candidates, fine grid for {p['fine_instances']}; rows in "
          f"{res.store}", file=sys.stderr)
    print(f"{'rank':>4s} {'instance':>8s}  {'label':40s} {'tau':>9s} {'lr':>8s} {'score':>8s} {'runs':>4s}  refined")
    for k, b in enumerate(res.best, 1):
        inst = "-" if b["instance"] is None else str(b["instance"])
        print(f"{k:4d} {inst:>8s}  {b['label']:40s} {b['tau']:9.3g} {b['lr']:8.3g} {b['score']:8.4f} "
              f"{b['n']:4d}  {'yes' if b['refined'] else 'no'}")
    if a.json:
        Path(a.json).write_text(json.dumps({"best": res.best, "ranking": res.ranking, "plan": p, "runs": res.runs,
                                            "seconds": res.seconds, "store": res.store}, indent=1))
    return 0


def cmd_recon(a) -> int:
    from . import recon
    return recon.main_cli(a)


# ------------------------------------------------------------------------------------------------

class _DefaultsFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Defaults in --help, except where the help already says it (``(default: the protocol's)``)
    or there is none to show."""

    def _get_help_string(self, action):
        text = action.help or ""
        return text if "(default" in text or action.default is None else super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    F = _DefaultsFormatter
    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="The experiments of the GenDR paper (§5) on gendr. See docs/experiments.md.",
        epilog="examples:\n"
               "  gendr experiment shape --target airplane --gif airplane.gif\n"
               "  gendr experiment pose --runs 10 --steps 300\n"
               "  gendr experiment sweep --experiment shape --dists logistic,cauchy --tconorms max,probabilistic \\\n"
               "      --taus 0.1,0.01 --lrs 0.05 -o sweep.jsonl\n"
               "  gendr experiment figures sweep.jsonl -o figs/\n"
               "  gendr experiment cost experiments/results/cost_timing.jsonl\n"
               "  gendr experiment tune --target my_model.obj --budget 600 --set image_size=32 --set views=8\n"
               "  gendr experiment recon --synthetic --steps 50 -o recon_out/")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    D = "(default: the protocol's)"
    p = sub.add_parser("shape", formatter_class=F, help="shape optimisation from 24 silhouettes (paper §5.1)",
                       description="Deform a sphere to match the hard silhouettes of a target from VIEWS azimuths. "
                                   "Settings come from --protocol (see `gendr experiment protocols`); options "
                                   "given override them.")
    _protocol_options(p)
    p.add_argument("--target", default=None, help=f"built-in scene, mesh file or paper:FILE {D}")
    p.add_argument("--tau", type=float, default=None, help=f"blur width in screen units (squared instances: tau**2) {D}")
    p.add_argument("--lr", type=float, default=None, help=D)
    p.add_argument("--steps", type=int, default=None, help=D)
    p.add_argument("--size", type=int, default=None, help=f"image size (square) {D}")
    p.add_argument("--views", type=int, default=None, help=D)
    p.add_argument("--elevation", type=float, default=None, help=D)
    p.add_argument("--distance", type=float, default=None, help=D)
    p.add_argument("--fov", type=float, default=None, help=f"vertical field of view, degrees {D}")
    p.add_argument("--template", default=None, help=f"'icosphere' (with --subdivisions) or a mesh file {D}")
    p.add_argument("--subdivisions", type=int, default=None, help=f"icosphere template level {D}")
    p.add_argument("--lambda-lap", type=float, default=None, help=D)
    p.add_argument("--lambda-flat", type=float, default=None, help=D)
    p.add_argument("--metric", choices=("final", "best"), default=None, help=f"hard IoU loss of the final mesh or best over the steps {D}")
    p.add_argument("--seed", type=int, default=None, help=D)
    p.add_argument("--gif", default=None, metavar="OUT.gif", help="write a GIF of the silhouettes during optimisation")
    p.add_argument("--gif-every", type=int, default=2, help="record every k-th step")
    p.add_argument("--gif-views", type=int, default=6, help="views shown in the GIF")
    p.add_argument("--output-mesh", default=None, metavar="OUT.obj", help="write the final mesh")
    _instance_options(p)
    p.set_defaults(func=cmd_shape)

    p = sub.add_parser("pose", formatter_class=F, help="camera-pose optimisation with decaying tau (paper §5.2)",
                       description="Recover a camera pose from a silhouette. quick: a rotation after a random "
                                   "perturbation of 15..75 degrees, success < 3 degrees; paper: the paper's look-at "
                                   "pose (distance, elevation, azimuth, view angle) for a batch of pairs in one "
                                   "perturbation bin, success < 5 degrees (see docs/experiments.md).")
    _protocol_options(p)
    p.add_argument("--target", default=None, help=D)
    p.add_argument("--tau-start", type=float, default=None, help=D)
    p.add_argument("--tau-end", type=float, default=None, help=D)
    p.add_argument("--lr", type=float, default=None, help=D)
    p.add_argument("--steps", type=int, default=None, help=D)
    p.add_argument("--size", type=int, default=None, help=D)
    p.add_argument("--angle-min", type=float, default=None, help=f"perturbation bin, degrees {D}")
    p.add_argument("--angle-max", type=float, default=None, help=D)
    p.add_argument("--pairs", type=int, default=None, help=f"paper: pairs per run (one batch) {D}")
    p.add_argument("--loss", choices=("iou", "mse"), default=None, help=D)
    p.add_argument("--seed", type=int, default=0, help="first seed")
    p.add_argument("--runs", type=int, default=1, help="number of runs (seeds seed..seed+runs-1)")
    _instance_options(p)
    p.set_defaults(func=cmd_pose)

    p = sub.add_parser("protocols", help="print the named protocols (quick, paper) side by side")
    p.set_defaults(func=cmd_protocols)

    p = sub.add_parser("sweep", formatter_class=F, help="resumable sweep over instances x tau x lr x seeds",
                       description="Run an experiment over a subset of the paper's grid with the paper's search: "
                                   "the coarse tau grid x learning rates x seeds, then a finer tau grid around each "
                                   "instance's best. Rows go to a JSONL file keyed by a config hash; rerun the same "
                                   "command to resume.")
    p.add_argument("--experiment", choices=("shape", "pose"), default="shape")
    p.add_argument("-o", "--output", default="sweep.jsonl", help="results file (JSON lines, appended)")
    p.add_argument("--csv", default=None, help="also write the main columns as CSV")
    p.add_argument("--instances", default=None, help="grid indices: 'all', '0-26,54', ...")
    p.add_argument("--dists", default=None, help="distribution labels (see --list-labels) or 'all'")
    p.add_argument("--tconorms", default=None, help="T-conorm labels (see --list-labels) or 'all'")
    p.add_argument("--variants", default="plain,squared", help="plain and/or squared")
    p.add_argument("--list-labels", action="store_true", help="print the labels for --dists/--tconorms")
    p.add_argument("--taus", default=None, help="coarse tau grid (shape: tau width; pose: tau_start). "
                                               "Default shape 0.1,0.01,0.001; pose 0.1")
    p.add_argument("--fine-steps", default="-0.5,-0.25,0.25,0.5", help="fine grid: best_tau * 10**s")
    p.add_argument("--no-refine", action="store_true", help="skip the fine tau stage")
    p.add_argument("--lrs", default=None, help="learning rates (default: the protocol's lr)")
    p.add_argument("--seeds", default="0")
    p.add_argument("--elevations", default=None, help="shape: elevations (averaged like seeds)")
    p.add_argument("--bins", default=None, metavar="A-B,...",
                   help="pose: perturbation bins in degrees (averaged like seeds), e.g. 15-35,35-55,55-75")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override an experiment setting, e.g. --set image_size=32 --set steps=50 --set target=chair")
    p.add_argument("--backend", default=None, help="gendr backend (default: the protocol's)")
    p.add_argument("--other-code", choices=("refuse", "keep", "rerun"), default="refuse",
                   help="finished rows of these runs made by other code (another source hash): refuse to "
                        "resume, keep them as done, or rerun them")
    _protocol_options(p)
    p.add_argument("--workers", type=int, default=None, help="local processes (default: CPU count; 0 = in-process)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS", help="run on a Dask cluster, e.g. tcp://host:8786")
    p.add_argument("--retry-errors", action="store_true", help="rerun rows that ended in an error")
    _device_option(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("verify", formatter_class=F, help="re-run finished rows and report drift",
                       description="Re-run rows of results files from their stored configs and compare the metrics; "
                                   "exit 1 when one moved beyond its tolerance (gendr_experiments.sweep.DRIFT_TOLERANCE).")
    p.add_argument("results", nargs="+", help="JSONL results file(s)")
    p.add_argument("--sample", type=int, default=None, help="re-run this many rows, chosen at random (default: all)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random choice")
    p.add_argument("--tolerance", type=float, default=None, help="absolute metric tolerance (default: per experiment)")
    p.add_argument("--data", default=None, metavar="DIR", help="directory of the paper's files (paper:FILE)")
    p.add_argument("--json", default=None, metavar="OUT.json", help="also write the report as JSON")
    _device_option(p)
    p.set_defaults(func=cmd_verify)

    p = sub.add_parser("findings", formatter_class=F, help="the paper's §5 findings checked against sweep rows",
                       description="For each qualitative finding of the paper's §5.1/§5.2: reproduced, contradicted, "
                                   "within noise or not testable, with the numbers (a Markdown table).")
    p.add_argument("results", nargs="+", help="shape sweep JSONL file(s)")
    p.add_argument("--pose", nargs="*", default=None, help="pose sweep JSONL file(s) (for 'pose similar to shape')")
    p.add_argument("--noise", type=float, default=0.03, help="single-run noise of the shape metric (see docs)")
    p.set_defaults(func=cmd_findings)

    p = sub.add_parser("cost", formatter_class=F, help="cost model: seconds per run, CPU-hours of the paper's studies",
                       description="Fit seconds = c0 + c1*view_steps + c2*k_dist*k_tconorm*gpairs (pixel-face pairs "
                                   "from each run's geometry and tau) to result rows, one model per (experiment, "
                                   "protocol), using cpu_seconds where rows have it; print the predicted seconds per "
                                   "run of the paper protocol by distribution and tau, and the CPU-hours and cluster "
                                   "size of the paper's studies (docs/experiments.md, 'Scale').")
    p.add_argument("results", nargs="+", help="JSONL results files (sweeps, experiments/cost_timing.py)")
    p.add_argument("--studies", default="shape-paper,shape-reduced,pose-paper,pose-reduced",
                   help="shape-paper (1,242 instances x 5 elevations x (3 lr x 7 tau + 18 new fine tau, 19 around a best at "
                        "the grid's edge)), shape-reduced "
                        "(experiments/paper_grid.sh shape), pose-paper (1,242 x 3 bins x 200 pairs x 2 lr), "
                        "pose-reduced (paper_grid.sh pose)")
    p.add_argument("--holdout", nargs="+", default=None, metavar="FILE",
                   help="rows NOT to fit: printed as measured vs predicted (experiments/cost_timing.py --holdout)")
    p.add_argument("--left", action="store_true",
                   help="a sweep's progress (pass its rows): per study, also the runs the rows hold (measured "
                        "hours) and those they lack (predicted); a fine stage centres on its search's best coarse "
                        "row once those all have rows, else on tau 0.01")
    p.add_argument("--hours", type=float, default=24.0, help="wall-clock time the cluster size is given for")
    p.add_argument("--efficiency", type=float, default=0.9, help="fraction of the cores kept busy")
    p.add_argument("--data", default=None, metavar="DIR", help="directory of the paper's files (paper:FILE)")
    p.add_argument("--json", default=None, metavar="OUT.json", help="also write the report as JSON")
    p.set_defaults(func=cmd_cost)

    p = sub.add_parser("tune", formatter_class=F, help="pick the best instance for your own target within a budget",
                       description="Run the paper's search (instances x tau x lr, then a finer tau grid around the best) "
                                   "for shape optimisation of YOUR target -- a built-in scene, a mesh file, or "
                                   "silhouettes + cameras as images:PATH.npz (docs/experiments.md, 'Tune') -- within "
                                   "--budget seconds, and print the best instances with their tau and lr. Rows go to "
                                   "a resumable JSONL file: rerun (with more budget) to go on.")
    p.add_argument("--target", required=True, help="built-in scene, mesh file, paper:FILE or images:PATH.npz")
    p.add_argument("--budget", type=float, required=True, help="wall-clock seconds")
    p.add_argument("-o", "--output", default="tune.jsonl", help="results file (JSON lines, appended)")
    p.add_argument("--instances", default=None, help="candidates by grid index (default: 12 distributions x 5 "
                                                     "T-conorms x plain/squared)")
    p.add_argument("--dists", default=None, help="candidate distribution labels (see sweep --list-labels)")
    p.add_argument("--tconorms", default=None, help="candidate T-conorm labels")
    p.add_argument("--variants", default="plain,squared", help="with --dists/--tconorms: plain and/or squared")
    p.add_argument("--taus", default="0.1,0.01,0.001", help="coarse grid of blur widths")
    p.add_argument("--fine-steps", default="-0.5,-0.25,0.25,0.5", help="fine grid: best_tau * 10**s")
    p.add_argument("--lrs", default=None, help="learning rates (default: the protocol's lr)")
    p.add_argument("--seeds", default="0")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="a shape setting, e.g. --set image_size=32 --set views=8 --set steps=60")
    p.add_argument("--backend", default=None, help="gendr backend (default: the protocol's)")
    p.add_argument("--workers", type=int, default=None, help="local processes (default: CPU count; 0 = in-process)")
    p.add_argument("--top", type=int, default=5, help="how many instances to print")
    p.add_argument("--other-code", choices=("refuse", "keep", "rerun"), default="refuse",
                   help="finished rows made by other code: refuse, keep them, or rerun them")
    p.add_argument("--json", default=None, metavar="OUT.json", help="also write the ranking as JSON")
    _protocol_options(p)
    p.set_defaults(func=cmd_tune)

    p = sub.add_parser("figures", formatter_class=F, help="heatmaps and top-10%% histograms of sweep results")
    p.add_argument("results", nargs="+", help="JSONL results file(s) of `sweep`")
    p.add_argument("-o", "--output", default="figures", help="output directory")
    p.add_argument("--experiment", choices=("shape", "pose"), default=None)
    p.add_argument("--fraction", type=float, default=0.1, help="top fraction for the histograms")
    p.set_defaults(func=cmd_figures)

    p = sub.add_parser("recon", formatter_class=F, help="single-view 3D reconstruction (paper §5.3)")
    try:
        from .recon import add_arguments
        add_arguments(p)
    except ImportError:  # pragma: no cover
        pass
    p.set_defaults(func=cmd_recon)
    return parser


def main(argv=None) -> int:
    """Run the paper's experiments: shape and pose optimisation, sweeps, findings, verify, figures."""
    from gendr.errors import GendrError
    parser = build_parser()
    try:
        a = parser.parse_args(argv)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    try:
        return a.func(a)
    except (UsageError, GendrError) as exc:  # bad input: one line, no traceback
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
