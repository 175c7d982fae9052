"""``gendr experiment shape|pose|sweep|figures|recon`` (also ``python -m gendr_experiments.cli``)."""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

PROG = "gendr experiment"


def _floats(text):
    return [float(x) for x in text.split(",") if x.strip()]


def _ints(text):
    out = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        if "-" in part[1:]:
            a, b = part.split("-", 1) if not part.startswith("-") else (part, part)
            out += list(range(int(a), int(b) + 1))
        else:
            out.append(int(part))
    return out


def _kv(items):
    out = {}
    for it in items or []:
        k, _, v = it.partition("=")
        if not _:
            raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {it!r}")
        try:
            out[k.strip().replace("-", "_")] = json.loads(v)
        except json.JSONDecodeError:
            out[k.strip().replace("-", "_")] = v
    return out


def _instance_options(p):
    g = p.add_argument_group("renderer instance (default: logistic + probabilistic)")
    g.add_argument("--instance", type=int, default=None, metavar="K", help="instance K of `gendr list grid`")
    g.add_argument("--distribution", default="logistic", metavar="NAME")
    g.add_argument("--dist-param", action="append", metavar="NAME=VALUE", help="e.g. shape=0.5 (repeatable)")
    g.add_argument("--reversed", action="store_true")
    g.add_argument("--squared", action="store_true")
    g.add_argument("--tconorm", default="probabilistic", metavar="NAME")
    g.add_argument("--tconorm-param", action="append", metavar="NAME=VALUE", help="e.g. p=2 (repeatable)")
    g.add_argument("--backend", default="torch", help="gendr backend (default: %(default)s)")
    g.add_argument("--eps", type=float, default=1e-4, help="coverage culling threshold (default: %(default)s)")
    g.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")


def _instance_config(a) -> dict:
    cfg = {"backend": a.backend, "eps": a.eps}
    if a.instance is not None:
        cfg["instance"] = a.instance
    else:
        cfg["distribution"] = {"name": a.distribution, "reversed": a.reversed, "squared": a.squared,
                               **_kv(a.dist_param)}
        cfg["tconorm"] = {"name": a.tconorm, **_kv(a.tconorm_param)}
    return cfg


def _print_result(res, a):
    res = {k: v for k, v in res.items() if k not in ("final_vertices", "faces")}
    print(json.dumps(res, indent=2, default=str))


# ------------------------------------------------------------------------------------------------

def cmd_shape(a) -> int:
    import numpy as np
    from .shape import run_shape
    from .figures import silhouette_frame, write_gif
    if a.threads:
        import torch
        torch.set_num_threads(a.threads)
    cfg = _instance_config(a)
    cfg.update(target=a.target, tau=a.tau, lr=a.lr, steps=a.steps, image_size=a.size, views=a.views,
               elevation=a.elevation, distance=a.distance, fov_y=a.fov, subdivisions=a.subdivisions,
               lambda_lap=a.lambda_lap, lambda_flat=a.lambda_flat, seed=a.seed)
    frames, cb = [], None
    if a.gif:
        from .shape import hard_silhouettes, shape_cameras  # target silhouettes for the overlay
        def cb(step, v, sil, loss):
            if step % max(1, a.gif_every) == 0:
                frames.append(sil.numpy())
    res = run_shape(cfg, callback=cb)
    if a.gif:
        from .common import load_target_mesh
        import torch
        from .shape import SHAPE_DEFAULTS
        full = dict(SHAPE_DEFAULTS, **cfg)
        m = load_target_mesh(a.target)
        tgt = hard_silhouettes(torch.tensor(m.vertices, dtype=torch.float32), torch.tensor(m.faces),
                               shape_cameras(full), a.size, a.backend).numpy()
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
    from .pose import run_pose
    if a.threads:
        import torch
        torch.set_num_threads(a.threads)
    cfg = _instance_config(a)
    cfg.update(target=a.target, tau_start=a.tau_start, tau_end=a.tau_end, lr=a.lr, steps=a.steps,
               image_size=a.size, angle_min=a.angle_min, angle_max=a.angle_max, loss=a.loss)
    results = []
    for s in range(a.seed, a.seed + a.runs):
        r = run_pose(cfg, seed=s)
        results.append(r)
        print(f"seed {s}: initial {r['initial_error']:.1f} deg -> final {r['metric']:.2f} deg "
              f"({'success' if r['success'] else 'fail'}) in {r['seconds']:.1f} s", file=sys.stderr)
    summary = {"runs": len(results), "success_rate": float(np.mean([r["success"] for r in results])),
               "mean_error_deg": float(np.mean([r["metric"] for r in results])),
               "median_error_deg": float(np.median([r["metric"] for r in results])),
               "seconds_per_run": float(np.mean([r["seconds"] for r in results])),
               "instance": results[0]["instance_label"]}
    print(json.dumps(summary, indent=2))
    return 0


def select_instances(a) -> list[int]:
    """Grid indices from --instances and/or --dists × --variants × --tconorms (labels of
    `gendr experiment sweep --list-labels`)."""
    from gendr.grid import TCONORM_SETTINGS
    from .figures import grid_labels
    dl, tl = grid_labels()
    out = []
    if a.instances:
        out += list(range(len(dl) * 2 * len(tl))) if a.instances == "all" else _ints(a.instances)
    if a.dists or a.tconorms:
        def pick(spec, labels, what):
            if not spec or spec == "all":
                return list(range(len(labels)))
            idx = []
            for s in spec.split(","):
                s = s.strip()
                if s not in labels:
                    raise ValueError(f"unknown {what} label {s!r}; known: {', '.join(labels)}")
                idx.append(labels.index(s))
            return idx
        variants = {"plain": 0, "squared": 1}
        vs = [variants[v.strip()] for v in a.variants.split(",")]
        for d in pick(a.dists, dl, "distribution"):
            for v in vs:
                for t in pick(a.tconorms, tl, "T-conorm"):
                    out.append((d * 2 + v) * len(TCONORM_SETTINGS) + t)
    seen, uniq = set(), []
    for i in out:
        if i not in seen:
            seen.add(i)
            uniq.append(i)
    return uniq


def cmd_sweep(a) -> int:
    from .figures import grid_labels
    from .sweep import EXPERIMENTS, best_setting_search, load_rows, write_csv
    if a.list_labels:
        dl, tl = grid_labels()
        print("distributions (--dists):\n  " + "\n  ".join(dl))
        print("T-conorms (--tconorms):\n  " + "\n  ".join(tl))
        return 0
    try:
        instances = select_instances(a)
    except ValueError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    if not instances:
        print(f"{PROG}: error: choose instances with --instances and/or --dists/--tconorms", file=sys.stderr)
        return 2
    base = _kv(a.set)
    base.setdefault("backend", a.backend)
    extra = {}
    if a.elevations:
        extra["elevation"] = _floats(a.elevations)
    taus = _floats(a.taus) if a.taus else ([1e-1, 1e-2, 1e-3] if a.experiment == "shape" else [1e-1])
    kw = dict(store=a.output, workers=a.workers, scheduler=a.scheduler, retry_errors=a.retry_errors,
              progress=not a.quiet)
    t0 = time.perf_counter()
    n0 = len(load_rows(a.output))
    best = best_setting_search(a.experiment, instances, taus=taus, lrs=_floats(a.lrs), seeds=_ints(a.seeds),
                               base=base, extra_axes=extra, refine=not a.no_refine,
                               fine_steps=tuple(_floats(a.fine_steps)), **kw)
    rows = load_rows(a.output)
    if a.csv:
        write_csv(rows, a.csv)
    tau_key = EXPERIMENTS[a.experiment]
    print(f"{len(rows) - n0} new runs in {time.perf_counter() - t0:.1f} s; {len(rows)} rows in {a.output}",
          file=sys.stderr)
    print(f"{'instance':>8s}  {'label':45s} {tau_key:>10s} {'lr':>8s} {'score':>8s}")
    for inst, b in sorted(best.items(), key=lambda kv: kv[1]["score"]):
        print(f"{inst:8d}  {b['label']:45s} {b[tau_key]:10.3g} {b['lr']:8.3g} {b['score']:8.4f}")
    return 0


def cmd_figures(a) -> int:
    from .figures import make_figures
    from .sweep import load_rows
    rows = [r for f in a.results for r in load_rows(f)]
    if not rows:
        print(f"{PROG}: error: no rows in {a.results}", file=sys.stderr)
        return 2
    for p in make_figures(rows, a.output, experiment=a.experiment, fraction=a.fraction):
        print(p)
    return 0


def cmd_recon(a) -> int:
    from . import recon
    return recon.main_cli(a)


# ------------------------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    F = argparse.ArgumentDefaultsHelpFormatter
    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="The experiments of the GenDR paper (§5) on gendr. See docs/experiments.md.",
        epilog="examples:\n"
               "  gendr experiment shape --target airplane --gif airplane.gif\n"
               "  gendr experiment pose --runs 10 --steps 300\n"
               "  gendr experiment sweep --experiment shape --dists logistic,cauchy --tconorms max,probabilistic \\\n"
               "      --taus 0.1,0.01 --lrs 0.05 -o sweep.jsonl\n"
               "  gendr experiment figures sweep.jsonl -o figs/\n"
               "  gendr experiment recon --synthetic --steps 50 -o recon_out/")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("shape", formatter_class=F, help="shape optimisation from 24 silhouettes (paper §5.1)",
                       description="Deform an icosphere to match the hard silhouettes of a target from VIEWS azimuths.")
    p.add_argument("--target", default="airplane", help="built-in scene or mesh file")
    p.add_argument("--tau", type=float, default=0.01, help="blur width in screen units (squared instances: tau**2)")
    p.add_argument("--lr", type=float, default=0.05)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--size", type=int, default=64, help="image size (square)")
    p.add_argument("--views", type=int, default=24)
    p.add_argument("--elevation", type=float, default=30.0)
    p.add_argument("--distance", type=float, default=4.0)
    p.add_argument("--fov", type=float, default=35.0)
    p.add_argument("--subdivisions", type=int, default=2, help="icosphere template level")
    p.add_argument("--lambda-lap", type=float, default=0.03)
    p.add_argument("--lambda-flat", type=float, default=0.0003)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--gif", default=None, metavar="OUT.gif", help="write a GIF of the silhouettes during optimisation")
    p.add_argument("--gif-every", type=int, default=2, help="record every k-th step")
    p.add_argument("--gif-views", type=int, default=6, help="views shown in the GIF")
    p.add_argument("--output-mesh", default=None, metavar="OUT.obj", help="write the final mesh")
    _instance_options(p)
    p.set_defaults(func=cmd_shape)

    p = sub.add_parser("pose", formatter_class=F, help="camera-pose optimisation with decaying tau (paper §5.2)",
                       description="Recover the rotation of an object from its silhouette after a random "
                                   "perturbation of 15..75 degrees; success = final error < 3 degrees.")
    p.add_argument("--target", default="teapot_like")
    p.add_argument("--tau-start", type=float, default=1e-1)
    p.add_argument("--tau-end", type=float, default=1e-7)
    p.add_argument("--lr", type=float, default=0.01)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--angle-min", type=float, default=15.0)
    p.add_argument("--angle-max", type=float, default=75.0)
    p.add_argument("--loss", choices=("iou", "mse"), default="iou")
    p.add_argument("--seed", type=int, default=0, help="first seed")
    p.add_argument("--runs", type=int, default=1, help="number of runs (seeds seed..seed+runs-1)")
    _instance_options(p)
    p.set_defaults(func=cmd_pose)

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
    p.add_argument("--lrs", default="0.05")
    p.add_argument("--seeds", default="0")
    p.add_argument("--elevations", default=None, help="shape: elevations (averaged like seeds)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override an experiment setting, e.g. --set image_size=32 --set steps=50 --set target=chair")
    p.add_argument("--backend", default="torch")
    p.add_argument("--workers", type=int, default=None, help="local processes (default: CPU count; 0 = in-process)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS", help="run on a Dask cluster, e.g. tcp://host:8786")
    p.add_argument("--retry-errors", action="store_true", help="rerun rows that ended in an error")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)

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
    parser = build_parser()
    try:
        a = parser.parse_args(argv)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    return a.func(a)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
