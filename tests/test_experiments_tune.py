"""``images:`` targets (silhouettes + cameras from a .npz), ``gendr experiment tune`` within a budget,
and the cost model's features."""
import json

import numpy as np
import pytest
import torch

from gendr.cli import main as gendr_main
from gendr.errors import InputValueError, ParameterError, ShapeError
from gendr_experiments.common import file_digest
from gendr_experiments.shape import run_shape, shape_config, shape_target_views
from gendr_experiments.sweep import load_rows
from gendr_experiments.targets import load_image_target, save_image_target
from gendr_experiments.tune import default_candidates, spread_order, tune

TINY = dict(target="tetrahedron", steps=3, image_size=12, views=2, subdivisions=1)


def _mesh_target_as_images(path, cfg):
    cam, sil, _ = shape_target_views(cfg)
    return save_image_target(path, sil, azimuth=cam.eye.azimuth, elevation=cam.eye.elevation,
                             distance=cam.eye.distance, fov_y=cam.fov_y)


def test_images_target_reproduces_the_mesh_target_bit_for_bit(tmp_path):
    cfg = shape_config(TINY, instance=271, tau=0.05)
    target = _mesh_target_as_images(tmp_path / "t.npz", cfg)
    a = run_shape(cfg)
    b = run_shape(dict(cfg, target=target, image_size=99, views=7))  # size and views come from the file
    for k in ("metric", "hard_iou_loss_initial", "soft_loss_first", "soft_loss_last"):
        assert a[k] == b[k], k
    assert b["data"] == {"target": file_digest(tmp_path / "t.npz")}


def test_images_target_with_eye_and_intrinsics(tmp_path):
    sil = np.zeros((2, 10, 12), dtype=np.uint8)
    sil[:, 3:7, 4:8] = 255
    np.savez(tmp_path / "e.npz", images=sil, eye=[[0, 0, 4], [4, 0, 0]], up=[0, 1, 0], fx=12.0, fy=12.0, cx=6.0,
             cy=5.0)
    cam, s = load_image_target(f"images:{tmp_path / 'e.npz'}")
    assert s.shape == (2, 10, 12) and s.dtype == torch.float32 and float(s.max()) == 1.0
    res = run_shape(dict(TINY, target=f"images:{tmp_path / 'e.npz'}", steps=2))
    assert np.isfinite(res["metric"]) and res["steps_done"] == 2


@pytest.mark.parametrize("arrays, error, words", [
    (dict(images=np.zeros((4, 4)), azimuth=0.0, elevation=0.0, distance=3.0, fov_y=30.0), ShapeError, "[N, H, W]"),
    (dict(images=np.full((2, 4, 4), 1.5), azimuth=0.0, elevation=0.0, distance=3.0, fov_y=30.0), InputValueError,
     "[0, 1]"),
    (dict(images=np.zeros((2, 4, 4)), azimuth=[0.0, 1.0, 2.0], elevation=0.0, distance=3.0, fov_y=30.0), ShapeError,
     "azimuth"),
    (dict(images=np.zeros((2, 4, 4)), azimuth=0.0, elevation=0.0, distance=3.0), InputValueError, "lens"),
    (dict(images=np.zeros((2, 4, 4)), azimuth=0.0, elevation=0.0, fov_y=30.0), InputValueError, "distance"),
    (dict(images=np.zeros((2, 4, 4)), eye=[0.0, 0.0, 3.0], fov_y=30.0), ShapeError, "eye"),
    (dict(images=np.zeros((2, 4, 4)), azimuth=0.0, elevation=0.0, distance=3.0, fov_y=300.0), InputValueError,
     "fov_y"),
    (dict(pictures=np.zeros((2, 4, 4))), InputValueError, "'images'"),
    # (a raw TypeError / ValueError before)
    (dict(images=np.zeros((2, 4, 4)), azimuth=0.0, elevation=0.0, distance=3.0, fov_y=30.0, near=[0.1, 0.1]),
     InputValueError, "near must be one real number, got [0.1, 0.1]"),
    (dict(images=np.zeros((2, 4, 4)), azimuth=0.0, elevation=0.0, distance=3.0, fov_y=30.0, far="x"),
     InputValueError, "far must be one real number"),
])
def test_bad_images_files_raise_typed_errors_naming_the_value(tmp_path, arrays, error, words):
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(error, match=None) as info:
        load_image_target(f"images:{tmp_path / 'bad.npz'}")
    assert words in str(info.value) and "bad.npz" in str(info.value)


def test_missing_images_file():
    with pytest.raises(InputValueError, match="no_such.npz"):
        load_image_target("images:/no/where/no_such.npz")


def test_spread_order_prefixes_cover_the_families():
    order = spread_order(default_candidates())
    assert sorted(order) == sorted(default_candidates()) and len(order) == 120
    from gendr_experiments.figures import _position
    first = [_position(i) for i in order[:24]]
    assert len({d for d, _, _ in first}) == 12 and {sq for _, sq, _ in first} == {0, 1}
    assert len({t for _, _, t in first}) == 5


def test_tune_within_budget_ranks_instances(tmp_path):
    store = tmp_path / "tune.jsonl"
    budget = 12.0
    res = tune("tetrahedron", budget=budget, store=store, base=dict(TINY, steps=2), workers=0,
               taus=(0.1, 0.02), fine_steps=(-0.25, 0.25))
    assert res.seconds <= budget + 5.0  # a run in flight at the deadline finishes (tiny runs: well under 1 s)
    assert 1 <= len(res.best) <= 5 and res.best == res.ranking[:len(res.best)]
    scores = [b["score"] for b in res.ranking]
    assert scores == sorted(scores) and all(0 <= s <= 1 for s in scores)
    assert {"instance", "label", "tau", "lr", "score", "refined"} <= set(res.best[0])
    rows = load_rows(store)
    assert len(rows) == res.runs >= 2 and all(r["status"] == "ok" for r in rows)
    assert res.plan["coarse_instances"] >= 1
    # "tried" = the whole coarse grid finished (a stage cut by the deadline does not count)
    coarse_taus = {}
    for r in rows:
        coarse_taus.setdefault(r["instance"], set()).add(r["tau"])
    assert res.plan["coarse_instances"] == sum({0.1, 0.02} <= t for t in coarse_taus.values())
    # resume: finished runs are not run again (every key once in the file)
    n = len(store.read_text().splitlines())
    again = tune("tetrahedron", budget=3.0, store=store, base=dict(TINY, steps=2), workers=0,
                 taus=(0.1, 0.02), fine_steps=(-0.25, 0.25))
    assert len(store.read_text().splitlines()) == len(load_rows(store)) == n + again.runs


def test_tune_says_so_when_not_even_the_probe_finishes(tmp_path, monkeypatch):
    """Runs of ~1 s and a 2 s budget: the probe's first runs finish, its third does not start.
    Before, this fell through the rounds loop to an UnboundLocalError."""
    import time
    import gendr_experiments.sweep as sweep
    real = sweep.run_config

    def slow(*args, **kw):
        time.sleep(1.0)
        return real(*args, **kw)
    monkeypatch.setattr(sweep, "run_config", slow)
    with pytest.raises(ParameterError, match=r"no candidate's coarse grid \(3 runs\) finished within budget=2.0"):
        tune("tetrahedron", budget=2.0, store=tmp_path / "t.jsonl", base=dict(TINY, steps=2), workers=0,
             taus=(0.1, 0.03, 0.01))
    assert 1 <= len(load_rows(tmp_path / "t.jsonl")) < 3  # what finished is kept (a resume skips it)


def test_a_slower_machine_than_predicted_still_leaves_time_to_refine(tmp_path, monkeypatch):
    """Runs after the probe take 1 s more than it predicts (~0.3 s): the coarse stage stops at its
    share of the budget (before, it ran to the deadline and nothing was refined). Then the coarse
    grid alone with fine_steps=() (CLI --fine-steps ''): nothing refined, no fine runs."""
    import time
    import gendr_experiments.sweep as sweep
    real, calls = sweep.run_config, []

    def slower_after_the_probe(*args, **kw):
        calls.append(1)
        if len(calls) > 2:
            time.sleep(1.0)
        return real(*args, **kw)
    monkeypatch.setattr(sweep, "run_config", slower_after_the_probe)
    res = tune("tetrahedron", budget=16.0, store=tmp_path / "t.jsonl", base=dict(TINY, steps=2), workers=0,
               taus=(0.1, 0.02), fine_steps=(-0.25, 0.25))
    assert any(b["refined"] for b in res.ranking) and res.plan["fine_instances"] >= 1
    coarse_only = tune("tetrahedron", budget=3.0, store=tmp_path / "c.jsonl", base=dict(TINY, steps=2), workers=0,
                       taus=(0.1, 0.02), fine_steps=())
    assert not any(b["refined"] for b in coarse_only.ranking)
    assert {r["tau"] for r in load_rows(tmp_path / "c.jsonl")} == {0.1, 0.02}


def test_tune_does_not_rerun_a_coarse_tau(tmp_path):
    """Fine steps of a decade around squared-style widths sqrt(0.1), sqrt(0.001): the step onto the
    other coarse width is that run, not a rerun at the 6-digit rounding 0.0316228 / 0.316228."""
    import math
    store = tmp_path / "tune.jsonl"
    taus = (math.sqrt(0.1), math.sqrt(0.001))
    res = tune("tetrahedron", budget=10.0, store=store, base=dict(TINY, steps=2), workers=0, taus=taus,
               fine_steps=(-1.0, 1.0))
    assert any(b["refined"] for b in res.ranking)  # a fine stage ran
    rows = load_rows(store)
    assert not {0.0316228, 0.316228} & {r["tau"] for r in rows}


@pytest.mark.parametrize("kwargs, error, words", [
    (dict(budget=0), ParameterError, "budget=0"),
    (dict(budget=-3.0), ParameterError, "budget=-3.0"),
    (dict(budget=float("nan")), ParameterError, "budget=nan"),
    (dict(budget=5, taus=()), ParameterError, "taus"),
])
def test_tune_rejects_bad_settings(tmp_path, kwargs, error, words):
    with pytest.raises(error) as info:
        tune("tetrahedron", store=tmp_path / "t.jsonl", base=TINY, workers=0, **kwargs)
    assert words in str(info.value)
    assert not (tmp_path / "t.jsonl").exists()


def test_tune_rejects_missing_targets(tmp_path):
    settings = dict(steps=3, subdivisions=1)  # (TINY's target, image size and views: the target's)
    with pytest.raises(InputValueError, match="nowhere.obj"):
        tune("nowhere.obj", budget=5, store=tmp_path / "t.jsonl", base=settings, workers=0)
    np.savez(tmp_path / "flat.npz", images=np.zeros((2, 4)), azimuth=0.0, elevation=0.0, distance=3.0, fov_y=30.0)
    with pytest.raises(ShapeError, match="flat.npz"):
        tune(f"images:{tmp_path / 'flat.npz'}", budget=5, store=tmp_path / "t.jsonl", base=settings, workers=0)


def test_tune_refuses_base_settings_it_sets_itself(tmp_path):
    """(a base target or image size other than the images file's was overwritten without a word)"""
    with pytest.raises(ParameterError, match="setting target='tetrahedron' .* is set by tune's target"):
        tune("cube", budget=5, store=tmp_path / "t.jsonl", base=TINY, workers=0)
    with pytest.raises(ParameterError, match="setting tau=0.1 .* is set by tune's taus"):
        tune("tetrahedron", budget=5, store=tmp_path / "t.jsonl", base=dict(TINY, tau=0.1), workers=0)
    target = _mesh_target_as_images(tmp_path / "t.npz", shape_config(TINY))
    with pytest.raises(ParameterError, match="setting image_size=12 .* is set by the images file"):
        tune(target, budget=5, store=tmp_path / "t.jsonl", base=dict(image_size=12), workers=0)
    assert not (tmp_path / "t.jsonl").exists()


def test_cli_tune_prints_the_ranking(tmp_path, capsys):
    cfg = shape_config(TINY)
    target = _mesh_target_as_images(tmp_path / "t.npz", cfg)
    out = tmp_path / "tune.jsonl"
    args = ["experiment", "tune", "--target", target, "--budget", "6", "--workers", "0", "--taus", "0.1,0.02",
            "--fine-steps=-0.25,0.25", "--top", "3", "-o", str(out), "--json", str(tmp_path / "best.json"),
            "--set", "steps=2", "--set", "subdivisions=1"]
    assert gendr_main(args) == 0
    text = capsys.readouterr().out
    assert "instance" in text and "tau" in text and "lr" in text
    best = json.loads((tmp_path / "best.json").read_text())
    assert 1 <= len(best["best"]) <= 3 and len(load_rows(out)) >= 2
    assert gendr_main(["experiment", "tune", "--target", "tetrahedron", "--budget", "0", "-o", str(out)]) == 2
    assert "budget=0" in capsys.readouterr().err


def test_tune_takes_candidates_outside_the_grid(tmp_path):
    avg = {"distribution": {"name": "logistic"}, "tconorm": "average"}
    res = tune("tetrahedron", budget=8, store=tmp_path / "t.jsonl", base=dict(TINY, steps=2), workers=0,
               taus=(0.1,), fine_steps=(0.25,), instances=[271, avg])
    got = {b["label"]: b["instance"] for b in res.ranking}
    assert got == {"logistic|probabilistic": 271, "logistic|average": None}


def test_calibration_from_one_work_level_scales_with_the_pairs():
    """Probe runs of one work level cannot split fixed from per-pair cost: a run with 100x the pairs
    (a heavy tail after a light-tailed probe) must be predicted at least 100x the probe's time, not
    the probe's time (which let tune start a 93 s run 50 s before its deadline); lighter runs not
    below the probe; with two work levels the fitted line applies."""
    from gendr_experiments import tune as T
    feats = {"a": {"dist_family": "logistic", "tconorm_family": "probabilistic", "gpairs": 0.01},
             "b": {"dist_family": "logistic", "tconorm_family": "probabilistic", "gpairs": 1.0},
             "c": {"dist_family": "logistic", "tconorm_family": "probabilistic", "gpairs": 0.001}}
    rows = [{"key": "k1", "status": "ok", "seconds": 2.0, "config": "a"},
            {"key": "k2", "status": "ok", "seconds": 2.2, "config": "a"}]
    cal = T._Calibration()
    cal.fit(rows, feats.get)
    assert cal.predict(feats["a"]) == pytest.approx(2.1)
    assert cal.predict(feats["b"]) == pytest.approx(210.0)
    assert cal.predict(feats["c"]) == pytest.approx(2.1)
    cal.fit(rows + [{"key": "k3", "status": "ok", "seconds": 12.0, "config": "b"}], feats.get)
    assert cal.w0 is None and cal.b > 0
    assert cal.predict(feats["b"]) == pytest.approx(cal.a + cal.b * T._work(feats["b"]))


def test_a_resumed_tune_with_nothing_to_run_ranks_like_the_run_it_resumes(tmp_path):
    """The ranking counted the fine runs only of the instances refined in this invocation: a first
    run whose rounds refined more instances than the resume's top (a budget-limited run's earlier
    rounds; here top=2, then top=1) got another winner and "refined: no" on resume, with no run."""
    store = tmp_path / "t.jsonl"
    kw = dict(store=store, base=dict(TINY, steps=2), workers=0, taus=(0.1, 0.02), fine_steps=(-0.25, 0.25),
              instances=[271, 379])
    first = tune("tetrahedron", budget=60.0, top=2, **kw)
    assert [b["refined"] for b in first.ranking] == [True, True] and first.plan["fine_instances"] == 2
    again = tune("tetrahedron", budget=10.0, top=1, **kw)
    assert again.runs == 0
    assert again.ranking == first.ranking and again.plan["fine_instances"] == 2


@pytest.mark.parametrize("steps", [(400.0,), (float("nan"),), (-400.0,), (0.25, float("inf"))])
def test_tune_rejects_fine_steps_without_a_finite_tau_before_running(tmp_path, steps):
    """(400 overflowed with an OverflowError after the whole coarse stage; nan and -400 (tau 0)
    failed there too)"""
    with pytest.raises(ParameterError, match=r"tune fine_steps \(CLI --fine-steps\) step .* gives no finite tau > 0"):
        tune("tetrahedron", budget=30, store=tmp_path / "t.jsonl", base=dict(TINY, steps=2), workers=0,
             taus=(0.1,), fine_steps=steps, instances=[271])
    assert not (tmp_path / "t.jsonl").exists()
