"""gendr_experiments.sweep: rows on disk, resume, the best-setting search, pool == Dask LocalCluster."""
import json
import math

import pytest
import torch

from gendr_experiments.common import source_hash
from gendr_experiments.sweep import (OtherCodeError, best_setting_search, drift_tolerance, execute, expand, fine_grid,
                                     load_rows, run_config, summarize_best, verify_rows, write_csv)

# a tiny shape problem: ~0.1 s per run
TINY = dict(target="tetrahedron", steps=3, image_size=12, views=2, subdivisions=1)


def _configs():
    return expand("shape", TINY, instances=[5, 59], axes={"tau": [0.1, 0.02], "lr": [0.05]})


def test_expand_and_keys():
    cfgs = _configs()
    assert len(cfgs) == 4
    assert {c["instance"] for c in cfgs} == {5, 59}
    assert all(c["experiment"] == "shape" and c["steps"] == 3 for c in cfgs)
    with pytest.raises(ValueError, match="unknown shape config keys"):
        expand("shape", {"stepz": 3})


def test_run_config_row_fields():
    row = run_config(_configs()[0])
    assert row["status"] == "ok", row.get("error")
    for k in ("key", "label", "distribution", "squared", "tconorm", "tau", "lr", "seed", "metric", "seconds",
              "provenance", "code_hash", "config", "finished_at", "protocol"):
        assert k in row
    prov = row["provenance"]
    assert prov["code_hash"] == row["code_hash"] == source_hash("torch")
    assert prov["backend"] == "torch" and prov["device"] == "cpu" and prov["dtype"] == "float32"
    assert prov["torch_threads"] == 1 and prov["versions"]["gendr"]
    # instance 5 of the grid: uniform (plain) with hamacher(4), named from the grid, not the config
    assert (row["instance"], row["label"]) == (5, "uniform|hamacher(p=4)")
    assert (row["distribution"], row["squared"], row["tconorm"]) == ("uniform", False, "hamacher(p=4)")
    assert 0.0 <= row["metric"] <= 1.0
    json.dumps(row, allow_nan=False)


def test_errors_become_rows(tmp_path):
    cfg = expand("shape", dict(TINY, target="no_such_mesh.obj"), instances=[5])
    rows = execute(cfg, tmp_path / "r.jsonl", workers=0, progress=False)
    assert rows[0]["status"] == "error" and rows[0]["metric"] is None


def test_sweep_writes_rows_and_resumes(tmp_path, capsys):
    path = tmp_path / "sweep.jsonl"
    cfgs = _configs()
    rows = execute(cfgs[:3], path, workers=0)  # "interrupted" after 3 of 4
    assert len(rows) == 3 and len(path.read_text().splitlines()) == 3
    assert "3/3" in capsys.readouterr().err  # the progress bar
    # a torn last line (killed while writing) is ignored and does not break the next append
    with open(path, "a") as f:
        f.write('{"key": "torn", "metr')
    rows = execute(cfgs, path, workers=0)
    assert len(rows) == 4
    assert len(load_rows(path)) == 4
    err = capsys.readouterr().err
    assert "skipped 3 finished" in err and "1/1" in err
    n = len(path.read_text().splitlines())
    again = execute(cfgs, path, workers=0)  # nothing left to do
    assert len(path.read_text().splitlines()) == n
    assert [r["metric"] for r in again] == [r["metric"] for r in rows]
    write_csv(again, tmp_path / "sweep.csv")
    assert (tmp_path / "sweep.csv").read_text().count("\n") == 5


def test_best_setting_search_refines_tau(tmp_path):
    store = tmp_path / "s.jsonl"
    best = best_setting_search("shape", [5], taus=[0.1, 0.01], lrs=[0.05], base=TINY, store=store,
                               workers=0, progress=False, fine_steps=(-0.25, 0.25))
    rows = load_rows(store)
    assert len(rows) == 4  # 2 coarse + 2 fine
    taus = sorted(r["tau"] for r in rows)
    coarse_best = min((r for r in rows if r["tau"] in (0.1, 0.01)), key=lambda r: r["metric"])["tau"]
    assert set(fine_grid(coarse_best, (-0.25, 0.25))) <= set(taus)
    assert best[5]["score"] == min(r["metric"] for r in rows)
    assert summarize_best(rows) == best


def test_lookat_pose_ties_are_broken_by_the_mean_final_error():
    """Two settings with the same failure rate: the one whose pairs ended nearer wins (the docs'
    "ties broken by mean error"; before, the first in the file did). A pair without a finite error
    counts as 180°."""
    def row(lr, residuals, successes):
        return {"experiment": "pose", "instance": 7, "label": "x", "tau_start": 0.1, "lr": lr, "status": "ok",
                "metric": 1 - successes / 2, "pairs": 2, "successes": successes, "residual_deg": residuals,
                "seconds": 1.0, "config": {"pairs": 2}}
    far, near = row(0.1, [40.0, 1.0], 1), row(0.3, [4.0, 2.0], 1)
    assert summarize_best([far, near])[7]["lr"] == 0.3 and summarize_best([near, far])[7]["lr"] == 0.3
    unknown = row(0.3, [None, 2.0], 1)  # a diverged pair: worse than 40° of the other setting
    assert summarize_best([unknown, far])[7]["lr"] == 0.1
    better = row(0.5, [90.0, 90.0], 2)  # more successes beat any error
    assert summarize_best([far, near, better])[7]["lr"] == 0.5
    # an error row beside a finished one: its pairs count as failed at 180°, whatever fields it has
    failed = dict(row(0.5, [1.0, 1.0], 2), status="error", metric=None)
    (best,) = summarize_best([better, failed]).values()
    assert best["success_rate"] == 0.5 and best["errors"] == 1
    assert best["score"] == pytest.approx(0.5 + 1e-6 * (90 + 90 + 180 + 180) / 4 / 180, abs=1e-12)


def test_fine_grid_names_coarse_tau_exactly():
    """A fine τ that is the best or a coarse τ (step 0 of the paper's 21 steps; a squared width's
    ±0.5-decade neighbours) must be that τ exactly, not a 6-digit rounding of it (a new key: a rerun)."""
    width = math.sqrt(0.1)
    assert fine_grid(width, (-0.05, 0.0, 0.05)) == [0.281838, width, 0.354813]
    assert fine_grid(10 ** -1.9, (0.0,)) == [10 ** -1.9]                     # rounding moves it 4e-6
    assert fine_grid(0.01, (0.1, 0.2), [10 ** -1.9]) == [10 ** -1.9, 0.0158489]
    assert fine_grid(width, (-0.5, 0.5), [math.sqrt(0.01), 1.0]) == [math.sqrt(0.01), 1.0]


def test_best_setting_search_does_not_rerun_a_coarse_tau(tmp_path):
    """Squared widths sqrt(0.1), sqrt(0.001) with fine steps of a decade: one fine τ is the other
    coarse width, so the search adds one run, not two."""
    store = tmp_path / "s.jsonl"
    taus = [math.sqrt(0.1), math.sqrt(0.001)]
    best_setting_search("shape", [5], taus=taus, lrs=[0.05], base=TINY, store=store, workers=0, progress=False,
                        fine_steps=(-1.0, 1.0))
    rows = load_rows(store)
    assert len(rows) == 3 and sum(r["tau"] in taus for r in rows) == 2


def test_pool_and_dask_localcluster_give_identical_metrics(tmp_path):
    distributed = pytest.importorskip("distributed")
    cfgs = _configs() + expand("pose", dict(steps=3, image_size=12), instances=[5], axes={"seed": [0, 1]})
    pool = execute(cfgs, tmp_path / "pool.jsonl", workers=2, progress=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        dask = execute(cfgs, tmp_path / "dask.jsonl", scheduler=client, progress=False)
    assert all(r["status"] == "ok" for r in pool + dask)
    assert [r["key"] for r in pool] == [r["key"] for r in dask]
    assert [r["metric"] for r in pool] == [r["metric"] for r in dask]
    assert {r["experiment"] for r in pool} == {"shape", "pose"}


def test_resume_refuses_rows_of_other_code(tmp_path):
    path = tmp_path / "r.jsonl"
    cfgs = _configs()[:2]
    rows = execute(cfgs, path, workers=0, progress=False)
    # the same rows as if another version of the code had made them (and one row without a hash)
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    lines[0]["code_hash"] = "0" * 16
    del lines[1]["code_hash"]
    path.write_text("".join(json.dumps(x) + "\n" for x in lines))
    with pytest.raises(OtherCodeError, match="2 of the 2 finished rows"):
        execute(cfgs, path, workers=0, progress=False)
    assert len(path.read_text().splitlines()) == 2  # refused before running anything
    kept = execute(cfgs, path, workers=0, progress=False, other_code="keep")
    assert [r.get("code_hash") for r in kept] == ["0" * 16, None]
    rerun = execute(cfgs, path, workers=0, progress=False, other_code="rerun")
    assert [r["code_hash"] for r in rerun] == [source_hash("torch")] * 2
    assert [r["metric"] for r in rerun] == [r["metric"] for r in rows]
    with pytest.raises(ValueError, match="other_code"):
        execute(cfgs, path, workers=0, progress=False, other_code="maybe")


def test_a_run_during_which_the_source_changed_is_an_error_row(tmp_path, monkeypatch):
    """A row records the hash of the code its process imported; if the files on disk differ when
    the run ends (an edit during a sweep), or the sweep started with another hash than this process
    runs, which code ran is unknown: the row is an error (rerun by --retry-errors), not a result
    under the wrong hash. (Before, the hash was read once, at the end of a worker's first run.)"""
    import gendr_experiments.sweep as sweep
    here = source_hash("torch")
    cfgs = _configs()[:2]
    assert run_config(cfgs[0], code_hash=here)["status"] == "ok"
    (other,) = [run_config(cfgs[0], code_hash="e" * 16)]
    assert other["status"] == "error" and other["metric"] is None
    assert "CodeChangedError" in other["error"] and "e" * 16 in other["error"] and other["code_hash"] == here
    assert "hard_iou_loss_best" not in other and "best_step" not in other  # no results of unknown code
    assert other["seconds"] > 0  # (the runner's wall seconds are kept: readers need them)
    monkeypatch.setattr(sweep, "read_source_hash", lambda backend="torch": "d" * 16)  # edited mid-run
    rows = execute(cfgs, tmp_path / "r.jsonl", workers=0, progress=False)
    assert [r["status"] for r in rows] == ["error", "error"]
    assert all("d" * 16 in r["error"] and r["code_hash"] == here for r in rows)
    monkeypatch.undo()
    rows = execute(cfgs, tmp_path / "r.jsonl", workers=0, progress=False, retry_errors=True)
    assert [r["status"] for r in rows] == ["ok", "ok"]


def test_verify_rows_reports_drift(tmp_path):
    path = tmp_path / "r.jsonl"
    rows = execute(_configs()[:2], path, workers=0, progress=False)
    report = verify_rows(rows)
    assert [v["drift"] for v in report] == [0.0, 0.0] and all(v["ok"] and v["same_code"] for v in report)
    moved = dict(rows[0], metric=rows[0]["metric"] + 0.5, code_hash="f" * 16)
    (v,) = verify_rows([moved])
    assert not v["ok"] and not v["same_code"] and v["drift"] == pytest.approx(0.5)
    assert len(verify_rows(rows, sample=1, seed=3)) == 1


def test_verify_rows_asks_exactness_only_on_the_same_simd_level(tmp_path):
    """Another SIMD level (Dr.Jit's vector width, torch's kernels) reorders float32 sums, so a row of
    the same code from such a CPU, or one that does not say, gets the other-code tolerance, not 0."""
    (row,) = execute(_configs()[:1], tmp_path / "r.jsonl", workers=0, progress=False)
    assert row["provenance"]["cpu"]["simd"] == torch.backends.cpu.get_cpu_capability()
    prov = row["provenance"]
    elsewhere = dict(row, metric=row["metric"] + 0.01, provenance=dict(prov, cpu=dict(prov["cpu"], simd="OTHER")))
    unrecorded = dict(row, metric=row["metric"] + 0.01, provenance={k: v for k, v in prov.items() if k != "cpu"})
    on_gpu = dict(row, metric=row["metric"] + 0.01, provenance=dict(prov, device="cuda"))
    same, other, unknown, gpu = verify_rows([row, elsewhere, unrecorded, on_gpu])
    assert same["same_cpu"] and same["same_device"] and same["tolerance"] == 0.0 and same["ok"]
    for v, simd in ((other, "OTHER"), (unknown, None)):
        assert v["same_code"] and not v["same_cpu"] and v["stored_simd"] == simd
        assert v["tolerance"] == drift_tolerance(row) > 0.01 and v["ok"]
        assert v["drift"] == pytest.approx(0.01)
    # a row whose renders ran on a GPU (sweep --device cuda): FMAs and another summation order
    assert gpu["same_cpu"] and not gpu["same_device"] and gpu["tolerance"] == drift_tolerance(row)


def test_run_config_device(tmp_path, monkeypatch):
    """device="cuda" is a run-time option of drjit runs: it reaches the renderer's backend options
    (shape and pose), every execute path passes it on, and the provenance records it."""
    import gendr_experiments.pose as pose
    import gendr_experiments.shape as shape
    seen = []

    def fake(cfg, *, backend_options=None, **kw):
        seen.append((cfg["experiment"], backend_options))
        return {"metric": 0.5}
    monkeypatch.setattr(shape, "run_shape", fake)
    monkeypatch.setattr(pose, "run_pose", fake)
    drjit_cfgs = [dict(c, backend="drjit") for c in _configs()[:2]]
    rows = execute(drjit_cfgs, tmp_path / "r.jsonl", workers=0, progress=False, device="cuda")
    assert [r["provenance"]["device"] for r in rows] == ["cuda", "cuda"] and all(r["status"] == "ok" for r in rows)
    pose_cfg = expand("pose", dict(steps=1, image_size=8, backend="drjit"), instances=[5], axes={})[0]
    assert run_config(pose_cfg, "cuda")["status"] == "ok" and run_config(pose_cfg)["status"] == "ok"
    assert seen == [("shape", {"device": "cuda"})] * 2 + [("pose", {"device": "cuda"}), ("pose", None)]
    row = run_config(_configs()[0], "cuda")  # a torch config
    assert row["status"] == "error" and "needs the drjit backend" in row["error"]
    with pytest.raises(ValueError, match="device='tpu'"):
        run_config(_configs()[0], "tpu")


def test_verify_is_never_exact_on_a_gpu(monkeypatch, tmp_path):
    """A GPU re-run (Dr.Jit's CUDA backward sums with atomics) gets the other-code tolerance, also
    for a row that was made on a GPU by the same code."""
    import gendr_experiments.sweep as sweep
    (row,) = execute(_configs()[:1], tmp_path / "r.jsonl", workers=0, progress=False)
    gpu_row = dict(row, provenance=dict(row["provenance"], device="cuda"))
    monkeypatch.setattr(sweep, "run_config", lambda cfg, device="cpu": dict(
        row, metric=row["metric"] + 0.001, provenance=dict(row["provenance"], device=device)))
    (v,) = verify_rows([gpu_row], device="cuda")
    assert v["same_code"] and v["same_cpu"] and v["same_device"]
    assert v["tolerance"] == drift_tolerance(row) > 0.001 and v["ok"]


def test_execute_starts_nothing_after_the_deadline(tmp_path):
    import time
    path = tmp_path / "r.jsonl"
    assert execute(_configs(), path, workers=0, progress=False, deadline=time.monotonic() - 1) == []
    assert not path.exists()
    rows = execute(_configs()[:1], path, workers=0, progress=False, deadline=time.monotonic() + 600)
    assert len(rows) == 1 and rows[0]["cpu_seconds"] > 0


def test_tuple_axes_zip_keys():
    cfgs = expand("pose", {"steps": 2}, axes={("angle_min", "angle_max"): [(15, 35), (55, 75)], "seed": [0]})
    assert [(c["angle_min"], c["angle_max"]) for c in cfgs] == [(15, 35), (55, 75)]


def test_sweep_cli_counts_reruns_as_runs(tmp_path, capsys):
    from gendr.cli import main as gendr_main
    path = tmp_path / "r.jsonl"
    args = ["experiment", "sweep", "--instances", "5", "--taus", "0.1,0.02", "--no-refine", "--workers", "0", "-q",
            "--set", "target=tetrahedron", "--set", "steps=2", "--set", "image_size=12", "--set", "views=2",
            "--set", "subdivisions=1", "-o", str(path)]
    assert gendr_main(args) == 0
    assert "2 runs in" in capsys.readouterr().err
    assert gendr_main(args) == 0
    assert "0 runs in" in capsys.readouterr().err
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    for row in lines:
        row["code_hash"] = "0" * 16
    path.write_text("".join(json.dumps(x) + "\n" for x in lines))
    assert gendr_main(args + ["--other-code", "rerun"]) == 0
    err = capsys.readouterr().err
    assert "2 runs in" in err and "; 2 rows in" in err  # two runs replaced two rows


def test_rows_of_other_settings_are_not_averaged_as_seeds():
    """(rows of one instance, τ and lr were averaged whatever their other settings: a file holding
    a 30-step and a 40-step run scored their mean as two seeds of one setting)"""
    def row(metric, **cfg):
        config = {**TINY, "instance": 5, "tau": 0.1, "lr": 0.05, "seed": 0, "elevation": 30.0, "experiment": "shape",
                  **cfg}
        return {"key": json.dumps(config, sort_keys=True), "experiment": "shape", "status": "ok", "instance": 5,
                "label": "uniform|hamacher(p=4)", "tau": 0.1, "lr": 0.05, "seed": config["seed"], "metric": metric,
                "seconds": 1.0, "config": config}
    # seeds and elevations of one setting: averaged (by design, --seeds and --elevations)
    averaged = summarize_best([row(0.2, seed=0), row(0.4, seed=1), row(0.6, seed=1, elevation=-30.0)])
    assert averaged[5]["n"] == 3 and averaged[5]["score"] == pytest.approx(0.4)
    # another step count or image size is another setting: the best of them, never a mean
    mixed = summarize_best([row(0.6, seed=0, steps=30), row(0.2, seed=1, steps=40), row(0.1, image_size=16)])
    assert mixed[5]["n"] == 1 and mixed[5]["score"] == 0.1
    mixed = summarize_best([row(0.6, seed=0, steps=30), row(0.2, seed=1, steps=40)])
    assert mixed[5]["n"] == 1 and mixed[5]["score"] == 0.2
