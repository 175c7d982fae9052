"""The cost model: pair counts from the geometry, the fit, the study counts, the CLI."""
import json
from pathlib import Path

import numpy as np
import pytest

import gendr
from gendr.cli import main as gendr_main
from gendr_experiments.common import paper_data_dir
from gendr_experiments.cost import CostModel, fit_cost_model, protocol_runs, run_features
from gendr_experiments.sweep import full_config

TINY = dict(target="tetrahedron", steps=4, image_size=16, views=2, subdivisions=1)
LOGISTIC_PROB, CAUCHY_PROB, UNIFORM_MAX = 271, 379, 0
RESULTS = Path(__file__).resolve().parents[1] / "experiments" / "results"
HAVE_PAPER_DATA = all((paper_data_dir() / f).is_file() for f in ("sphere_642.obj", "teapot.obj", "airplane.obj"))


def _cfg(inst, tau, **kw):
    return full_config("shape", dict(TINY, instance=inst, tau=tau, **kw))


def test_pairs_grow_with_tau_and_heavy_tails_cover_the_image():
    taus = (1e-4, 1e-3, 1e-2, 1e-1, 1.0)
    logistic = [run_features(_cfg(LOGISTIC_PROB, t))["gpairs"] for t in taus]
    assert logistic == sorted(logistic) and logistic[0] < logistic[-1]
    # Cauchy: its eps radius (3,183·τ at eps 1e-4) covers the image, every face meets every pixel
    dense = run_features(_cfg(CAUCHY_PROB, 1e-2))
    faces = 80  # icosphere level 1
    assert dense["gpairs"] * 1e9 == pytest.approx(TINY["steps"] * TINY["views"] * faces * 16 * 16)
    # the reference cut-off bounds it: sqrt(cutoff·τ)
    cut = run_features(_cfg(CAUCHY_PROB, 1e-2, cutoff=100.0))
    assert cut["gpairs"] < dense["gpairs"]
    f = run_features(_cfg(UNIFORM_MAX, 0.1))
    assert f["view_steps"] == 8 and f["dist_family"] == "uniform" and f["tconorm_family"] == "max"


def test_fit_recovers_a_known_model():
    truth = CostModel("shape", "quick", 0.3, 0.01, 40.0, {"logistic": 0.8, "cauchy": 1.25},
                      {"probabilistic": 0.9, "max": 1 / 0.9})
    rows = []
    for inst in (LOGISTIC_PROB, CAUCHY_PROB, LOGISTIC_PROB - 1, CAUCHY_PROB - 1):  # - 1: max
        for tau in (1e-3, 1e-2, 1e-1):
            for steps in (2, 8):
                cfg = _cfg(inst, tau, steps=steps)
                rows.append({"experiment": "shape", "protocol": "quick", "status": "ok", "config": cfg,
                             "seconds": 2 * truth.predict(cfg), "cpu_seconds": truth.predict(cfg)})
    gpu = [dict(r, cpu_seconds=r["cpu_seconds"] / 50, provenance={"device": "cuda"}) for r in rows]
    m = fit_cost_model(rows + gpu, prior_weight=1e-3)  # (a model of CPU runs: GPU rows are left out)
    assert m.timer == "cpu_seconds" and m.n_rows == len(rows)
    # The rows are exact (noise-free) predictions of `truth`, whose k factors have geometric mean 1 as
    # the fit normalises them, so the fit recovers its parameters up to the small pull of the weak
    # prior (1e-3) on log k toward 0, which c2 absorbs. Measured (scipy least_squares, trf): c0 off by
    # 3e-11 relative, c1 by 5e-6, c2 by 2.1e-4, every k by at most 1.9e-4; a fit whose prior is 300×
    # stronger (0.3) lands at k ≈ 1.005 / 0.995 and c2 48.3. Tolerances ~10× the measured errors.
    assert m.c0 == pytest.approx(truth.c0, rel=1e-4)
    assert m.c1 == pytest.approx(truth.c1, rel=1e-4)
    assert m.c2 == pytest.approx(truth.c2, rel=2e-3)
    assert set(m.k_dist) == set(truth.k_dist) and set(m.k_tconorm) == set(truth.k_tconorm)
    for fitted, known in ((m.k_dist, truth.k_dist), (m.k_tconorm, truth.k_tconorm)):
        for family, k in known.items():
            assert fitted[family] == pytest.approx(k, rel=2e-3), family
    # measured: median |log error| 6.3e-7, the largest relative prediction error 5.7e-6 (the prior's
    # pull again); the 0.3-prior fit is off by up to 1 %. Bounds ~15× the measured values.
    assert m.median_abs_log_error < 1e-5
    for r in rows:
        assert m.predict(r["config"]) == pytest.approx(r["cpu_seconds"], rel=1e-4)
    with pytest.raises(ValueError, match="no finished rows"):
        fit_cost_model([])


def test_study_run_counts():
    def count(name, insts):
        return len(list(protocol_runs(name, instances=insts)))
    assert count("shape-reduced", [0]) == 3 + 2               # 3 coarse τ, best·10^±0.5
    assert count("shape-paper", [0]) == 5 * (3 * 7 + 18)      # 5 elevations × (3 lr × 7 τ + 18 new fine τ:
    #                                                           21 around 0.01 but 1e-3, 1e-2, 1e-1)
    assert count("pose-paper", [0]) == 3 * 2                  # 3 bins × 2 lr, 200 pairs each
    with pytest.raises(ValueError, match="unknown study"):
        next(protocol_runs("shape-everything"))


@pytest.mark.skipif(not HAVE_PAPER_DATA, reason="the paper's meshes are user-supplied (docs/experiments.md)")
def test_cli_cost_on_the_committed_timing_rows(tmp_path, capsys):
    out = tmp_path / "cost.json"
    assert gendr_main(["experiment", "cost", str(RESULTS / "cost_timing.jsonl"), "--studies", "pose-reduced",
                       "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "shape/paper" in text and "pose-reduced" in text and "CPU-hours" in text and "cores for 24 h" in text
    assert gendr_main(["experiment", "cost", str(RESULTS / "cost_timing.jsonl"), "--studies", "nope"]) == 2


def test_the_full_protocol_commands_are_the_studies_the_model_counts():
    """experiments/paper_grid.sh shape-full / pose-full (printed, shell-quoted, by a stand-in for
    gendr) ask for the grids the cost model prices (PAPER_TAUS, PAPER_LRS, PAPER_ELEVATIONS,
    PAPER_FINE_STEPS; pose: 2 lr × 3 bins)."""
    from gendr_experiments.cli import _floats, build_parser, select_instances
    from gendr_experiments.cost import (PAPER_ELEVATIONS, PAPER_FINE_STEPS, PAPER_FINE_STEPS_SQUARED, PAPER_LRS,
                                        PAPER_TAUS, PAPER_TAUS_SQUARED, REDUCED_FINE_STEPS, REDUCED_TAUS)

    def parsed(case):
        commands = []
        for args in _paper_grid_commands(case):
            assert args[:2] == ["experiment", "sweep"] and "--scheduler" in args
            commands.append(build_parser().parse_args(args[1:]))
        return commands

    plain, squared = parsed("shape-full")
    for a, variant, taus, steps in ((plain, "plain", PAPER_TAUS, PAPER_FINE_STEPS),
                                    (squared, "squared", PAPER_TAUS_SQUARED, PAPER_FINE_STEPS_SQUARED)):
        assert (a.protocol, a.dists, a.tconorms, a.variants, a.no_refine) == ("paper", "all", "all", variant, False)
        assert tuple(_floats(a.taus)) == taus and tuple(_floats(a.lrs)) == PAPER_LRS  # exact: keys hash floats
        assert tuple(_floats(a.elevations)) == PAPER_ELEVATIONS and tuple(_floats(a.fine_steps)) == steps
    # squared: widths sqrt(tau) at half the decade steps = the paper's renderer tau grid
    assert np.allclose(np.square(_floats(squared.taus)), PAPER_TAUS)
    selected = set()
    for a in parsed("shape"):  # the reduced study the cost model prices as "shape-reduced"
        assert tuple(_floats(a.taus)) == REDUCED_TAUS and tuple(_floats(a.fine_steps)) == REDUCED_FINE_STEPS
        selected |= {json.dumps(i, sort_keys=True) for i in select_instances(a)}
    assert len(selected) == len(gendr.paper_grid()) + 46  # every instance, and "average" per distribution
    (p,) = parsed("pose-full")
    assert (p.experiment, p.instances, p.no_refine, p.set) == ("pose", "all", True, ["pairs=200"])
    assert _floats(p.lrs) == [0.1, 0.3] and len(p.bins.split(",")) == 3


def _row(cfg, metric, status="ok"):
    from gendr_experiments.common import instance_from_config
    from gendr_experiments.sweep import config_hash
    return {"key": config_hash(cfg), "status": status, "experiment": cfg["experiment"], "instance": cfg.get("instance"),
            "label": instance_from_config(cfg)[2], "tau": cfg.get("tau"), "lr": cfg["lr"], "metric": metric,
            "seconds": 1.0, "config": cfg}


def test_runs_left_follows_the_sweeps_search():
    """The runs a study still lacks: coarse runs without a finished row (an error is rerun); once a
    search's coarse runs all have rows, the fine stage around their best τ (an error scoring worst),
    before that around 0.01."""
    from gendr_experiments.cost import runs_left
    insts = [0, 5, 7]
    coarse = [c for c in protocol_runs("shape-reduced", instances=insts) if c["tau"] in (0.003, 0.01, 0.03)]
    assert len(coarse) == 9
    metric = {0.003: 0.2, 0.01: 0.3, 0.03: 0.4}
    rows = [_row(c, metric[c["tau"]]) for c in coarse if c["instance"] == 0 or (c["instance"], c["tau"]) in
            ((5, 0.003), (5, 0.01), (7, 0.03), (7, 0.01))]
    rows.append(_row(next(c for c in coarse if (c["instance"], c["tau"]) == (5, 0.03)), None, status="error"))
    left = sorted((c["instance"], c["tau"]) for c in runs_left("shape-reduced", rows, instances=insts))
    assert left == [(0, 0.00168702), (0, 0.00533484),              # around 0.003
                    (5, 0.00168702), (5, 0.00533484), (5, 0.03),   # around 0.003; the error reruns
                    (7, 0.003), (7, 0.00562341), (7, 0.0177828)]   # a coarse run missing: around 0.01
    # a finished fine run is not left; every run is left without rows
    fine = next(c for c in runs_left("shape-reduced", rows, instances=insts) if c["instance"] == 0)
    assert len(list(runs_left("shape-reduced", rows + [_row(fine, 0.1)], instances=insts))) == 7
    assert len(list(runs_left("shape-reduced", [], instances=insts))) == 15
    # the report's figures: runs the rows hold (measured), runs they lack (predicted)
    from gendr_experiments.cost import protocol_cost
    flat = CostModel("shape", "paper", 10.0, 0.0, 0.0)  # 10 s per run
    res = protocol_cost(flat, "shape-reduced", rows=rows, instances=insts)
    assert (res["runs"], res["done"]["runs"], res["left"]["runs"]) == (15, 7, 8)
    assert res["left"]["cpu_hours"] == pytest.approx(80 / 3600) and res["done"]["wall_hours"] == pytest.approx(7 / 3600)
    assert len(list(runs_left("pose-paper", [], instances=[3]))) == 6


def test_runs_left_of_the_paper_search_averages_the_elevations():
    """shape-paper: the fine stage's centre is the (τ, lr) of the lowest mean over the 5 elevations, not
    of one elevation; fine τ that are coarse τ (0.01 ± 1 decade) are not new runs; no run twice."""
    from gendr_experiments.cost import PAPER_FINE_STEPS, PAPER_LRS, PAPER_TAUS, runs_left
    from gendr_experiments.sweep import config_hash, expand, fine_grid
    coarse = [c for c in protocol_runs("shape-paper", instances=[0]) if c["tau"] in PAPER_TAUS]
    assert len(coarse) == 5 * 3 * 7

    def metric(c):  # elevation 60 alone prefers 1e-4; the mean over the five prefers 1e-3 at lr 10^-1.25
        if c["elevation"] == 60.0:
            return 0.0 if c["tau"] == 1e-4 else 0.9
        return 0.1 if (c["tau"], c["lr"]) == (1e-3, PAPER_LRS[0]) else 0.5
    rows = [_row(c, metric(c)) for c in coarse]
    left = list(runs_left("shape-paper", rows, instances=[0]))
    assert len({config_hash(c) for c in left}) == len(left) == 5 * 18  # 21 fine τ: 1e-3 and 1e-2, 1e-4 ran
    want = expand("shape", {"protocol": "paper"}, instances=[0], axes={
        "tau": [t for t in fine_grid(1e-3, PAPER_FINE_STEPS) if t not in (1e-2, 1e-3, 1e-4)],
        "lr": [PAPER_LRS[0]], "seed": [0], "elevation": [-60.0, -30.0, 0.0, 30.0, 60.0]})
    assert {config_hash(c) for c in left} == {config_hash(c) for c in want}
    every = [config_hash(c) for c in protocol_runs("shape-paper", instances=[0, 27])]
    # 27 is squared: widths sqrt(tau), whose ±0.5-decade neighbours are coarse widths too (snapped, not rerun)
    assert len(every) == len(set(every)) == 2 * 5 * (3 * 7 + 18)


@pytest.mark.parametrize("case, study", [("shape", "shape-reduced"), ("pose", "pose-reduced"),
                                         ("shape-full", "shape-paper"), ("pose-full", "pose-paper")])
def test_study_runs_are_the_runs_paper_grid_sh_asks_for(case, study):
    """The cost model's study configs hash like those of the sweeps experiments/paper_grid.sh starts
    (their command lines, parsed and planned as ``gendr experiment sweep`` does): coarse runs, and the
    fine stage around a given best."""
    from gendr_experiments.cli import build_parser, search_plan, select_instances
    from gendr_experiments.cost import _fine, _searches
    from gendr_experiments.sweep import EXPERIMENTS, config_hash, expand, fine_grid
    searches = list(_searches(study))
    checked = 0
    for line in _paper_grid_commands(case):
        a = build_parser().parse_args(line[1:])
        insts = select_instances(a)
        plan = search_plan(a, insts[:1] + insts[-1:])  # the first and last instance of each sweep
        tau_key = EXPERIMENTS[a.experiment]
        axes = {tau_key: plan["taus"], "lr": plan["lrs"], "seed": plan["seeds"], **plan["extra_axes"]}
        for inst in plan["instances"]:
            s = next(v for v in searches if _same_instance(v, inst))
            sweep_coarse = expand(a.experiment, plan["base"], instances=[inst], axes=axes)
            assert {config_hash(c) for c in sweep_coarse} == {config_hash(c) for c in s.coarse}
            if plan["refine"]:
                best_tau, best_lr = plan["taus"][1], plan["lrs"][-1]
                fine = expand(a.experiment, plan["base"], instances=[inst], axes={
                    tau_key: fine_grid(best_tau, plan["fine_steps"], plan["taus"]), "lr": [best_lr],
                    "seed": plan["seeds"], **plan["extra_axes"]})
                new = {config_hash(c) for c in fine} - {config_hash(c) for c in sweep_coarse}
                assert new == {config_hash(c) for c in _fine(s, best_tau, best_lr)}
            else:
                assert not s.fine_bases
            checked += 1
    assert checked >= 2


def _same_instance(search, inst):
    c = search.coarse[0]
    if isinstance(inst, dict):
        return c.get("instance") is None and c["distribution"] == inst["distribution"] and c["tconorm"] == inst["tconorm"]
    return c.get("instance") == inst


def _paper_grid_commands(case):
    """The ``gendr experiment sweep`` command lines experiments/paper_grid.sh runs for ``case``."""
    import os
    import shlex
    import subprocess
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        show = Path(tmp) / "show_args"  # labels have spaces ("exponential rev"): print them quoted
        show.write_text('#!/usr/bin/env bash\nprintf "%q " "$@"; echo\n')
        show.chmod(0o755)
        out = subprocess.run(["bash", str(RESULTS.parent / "paper_grid.sh"), case], capture_output=True, text=True,
                             check=True, env=dict(os.environ, GENDR=str(show), SCHEDULER="tcp://127.0.0.1:8786")).stdout
    return [shlex.split(line) for line in out.splitlines()]


@pytest.mark.parametrize("study, name", [("shape-reduced", "paper_shape_grid"), ("pose-reduced", "paper_pose_grid")])
def test_study_configs_are_the_keys_the_sweep_wrote(study, name):
    """runs_left matches rows by key: the study's configs must hash like those paper_grid.sh's sweeps
    ran (the committed rows; the shape file also holds 43 instances' rows of a first pass at widths
    0.1, 0.01, 0.001 outside the study)."""
    from gendr_experiments.cost import runs_left
    from gendr_experiments.sweep import load_rows
    rows = [r for r in load_rows(RESULTS / f"{name}.jsonl") if r["status"] == "ok"]
    left = {json.dumps(c, sort_keys=True) for c in runs_left(study, rows)}
    expected = {json.dumps(c, sort_keys=True) for c in protocol_runs(study)}  # fine stages at 0.01
    study_rows = [r for r in rows if r.get("tau") not in (0.1, 0.001)]
    assert len(study_rows) > 200
    total = len(list(runs_left(study, [])))
    assert total == len(expected) == (6440 if study == "shape-reduced" else 345)
    assert total - len(left) == len(study_rows)  # every committed row of the study is one of its runs
