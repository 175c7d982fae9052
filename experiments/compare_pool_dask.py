"""Run a subset of a finished pool sweep again on a local Dask cluster and compare the metrics by key.

    python experiments/compare_pool_dask.py POOL.jsonl OUT.jsonl

The subset and settings below are those of the shape sweep in docs/experiments.md (results section).
"""
import sys
import time

from distributed import Client, LocalCluster

from gendr_experiments.figures import grid_labels
from gendr_experiments.sweep import execute, expand, load_rows

BASE = dict(target="airplane", image_size=32, views=6, steps=60, subdivisions=1, backend="torch")


def subset():
    dl, tl = grid_labels()
    insts = [(dl.index(d) * 2 + 0) * len(tl) + tl.index(t)
             for d in ("uniform", "logistic", "exponential rev", "gamma(2) rev") for t in ("probabilistic", "yager(2)")]
    return expand("shape", BASE, instances=insts, axes={"tau": [0.1, 0.03, 0.01], "lr": [0.05], "seed": [0]})


if __name__ == "__main__":
    pool_path, out = sys.argv[1], sys.argv[2]
    cfgs = subset()
    t0 = time.perf_counter()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as lc, Client(lc) as c:
        rows = execute(cfgs, out, scheduler=c)
    print(f"dask: {len(rows)} runs in {time.perf_counter() - t0:.1f} s")
    pool = {r["key"]: r for r in load_rows(pool_path)}
    same = [pool[r["key"]]["metric"] == r["metric"] for r in rows if r["key"] in pool]
    missing = sum(r["key"] not in pool for r in rows)
    print(f"compared {len(same)} runs by key: {sum(same)} identical metrics, {len(same) - sum(same)} different, "
          f"{missing} not in the pool results")
    for r in rows:
        p = pool.get(r["key"])
        print(f"  {r['label']:40s} tau={r['tau']:<6g} dask={r['metric']!r:24s} pool={p and p['metric']!r}")
    sys.exit(0 if same and all(same) and not missing else 1)
