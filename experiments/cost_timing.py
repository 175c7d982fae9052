"""The small timing runs the cost model (gendr_experiments.cost) is fitted to, beside sweep rows.

    python experiments/cost_timing.py [OUT.jsonl]     # default experiments/results/cost_timing.jsonl
    python experiments/cost_timing.py --holdout [OUT.jsonl]   # default experiments/results/cost_holdout.jsonl

Paper protocols (drjit, one thread, in this process; rows record ``cpu_seconds``), shortened to a few
steps: the model is linear in steps, views and pairs, so short runs pin its coefficients without
a big sweep. Shape (elevation 30, lr 10^-1.5): logistic + probabilistic at τ = 1e-3 with 0, 5 and
20 steps (fixed and per-view costs); every distribution family + probabilistic at τ = 0.1 (dense:
the per-pair cost of each CDF), 5 steps; logistic at τ = 0.1 with 8 other T-conorm families; Cauchy
at τ 0.01, 0.001 and squared logistic at 0.1, 0.01. Pose (bin 15-35): 20 steps (τ 1e-1 -> 1e-7) with
4 and 16 pairs, logistic, Cauchy and reversed gamma(0.5). About 4 CPU-minutes (10 wall-minutes on the shared 2 cores). Resumable like sweeps.

``--holdout``: three full-length paper runs the fit never sees (``gendr experiment cost ... --holdout``
compares them with the model): shape logistic τ = 0.01 and Cauchy τ = 0.001 (100 steps), pose
logistic with 16 pairs and 200 steps.
"""
from pathlib import Path

from gendr_experiments.sweep import execute, full_config, run_config


def grid_index(dist, tconorm, squared=False):
    return (dist * 2 + int(squared)) * 27 + tconorm


def configs():
    shape = lambda inst, tau, steps: full_config(  # noqa: E731
        "shape", {"protocol": "paper", "instance": inst, "tau": tau, "steps": steps})
    pose = lambda inst, pairs: full_config(  # noqa: E731
        "pose", {"protocol": "paper", "instance": inst, "pairs": pairs, "steps": 20})
    logistic, cauchy, gamma05rev = 5, 7, 14
    out = [shape(grid_index(logistic, 1), 1e-3, s) for s in (5, 20)]
    # one distribution per family (gamma, exponential, levy: the reversed variant), probabilistic
    out += [shape(grid_index(d, 1), 0.1, 5) for d in (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 14, 22)]
    # T-conorm families: max, einstein, hamacher(0), frank(0.1), yager(2), aczel_alsina(2), dombi(0.5), ss(-2)
    out += [shape(grid_index(logistic, t), 0.1, 5) for t in (0, 2, 3, 8, 13, 17, 19, 24)]
    out += [shape(grid_index(cauchy, 1), t, 5) for t in (0.01, 0.001)]
    out += [shape(grid_index(logistic, 1, squared=True), t, 5) for t in (0.1, 0.01)]
    out += [pose(grid_index(logistic, 1), n) for n in (4, 16)]
    out += [pose(grid_index(d, 1), 16) for d in (cauchy, gamma05rev)]
    return out


def holdout():
    return [full_config("shape", {"protocol": "paper", "instance": grid_index(5, 1), "tau": 0.01}),
            full_config("shape", {"protocol": "paper", "instance": grid_index(7, 1), "tau": 0.001}),
            full_config("pose", {"protocol": "paper", "instance": grid_index(5, 1), "pairs": 16, "steps": 200})]


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--holdout", action="store_true", help="the three full-length runs the fit never sees")
    ap.add_argument("out", nargs="?", metavar="OUT.jsonl",
                    help="rows file (default experiments/results/cost_timing.jsonl, --holdout: cost_holdout.jsonl)")
    a = ap.parse_args()
    name = "cost_holdout.jsonl" if a.holdout else "cost_timing.jsonl"
    out = a.out or str(Path(__file__).parent / "results" / name)
    if not out.endswith(".jsonl") or Path(out).is_dir():
        ap.error(f"OUT {out!r} must name a .jsonl rows file")
    cfgs = holdout() if a.holdout else configs()
    run_config(dict(cfgs[0], steps=1))  # warm-up: imports and one-time set-up stay out of the rows
    rows = execute(cfgs, out, workers=0, other_code="keep")
    for r in rows:
        print(f"{r['experiment']:5s} {r['label']:32s} tau={r.get('tau', r.get('tau_start'))!s:7s} "
              f"steps={r['config']['steps']:<3d} cpu={r.get('cpu_seconds', float('nan')):7.2f}s wall={r['seconds']:7.2f}s")
