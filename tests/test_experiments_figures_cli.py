"""gendr_experiments.figures and the `gendr experiment` command line."""
import csv
import json

import numpy as np
import pytest

import gendr
from gendr.cli import main as gendr_main
from gendr_experiments.figures import (grid_labels, make_figures, score_matrix, silhouette_frame, top_fraction,
                                       write_gif)


def _fake_rows(n=60, seed=0):
    """n random grid instances × τ {0.1, 0.01} × lr {0.05, 0.02} × seeds {0, 1}: random metrics and
    seconds (a setting's seeds are averaged, its best τ and lr differ between instances)."""
    rng = np.random.default_rng(seed)
    grid = gendr.paper_grid()
    rows = []
    for inst in rng.choice(len(grid), n, replace=False):
        for tau in (0.1, 0.01):
            for lr in (0.05, 0.02):
                for sd in (0, 1):
                    rows.append(dict(key=f"{inst}-{tau}-{lr}-{sd}", experiment="shape", instance=int(inst),
                                     label=grid[inst].name, tau=tau, lr=lr, seed=sd, metric=float(rng.uniform()),
                                     seconds=float(rng.uniform(0.5, 2.0)), status="ok"))
    return rows


def _expected_best(rows):
    """instance -> the best setting, computed here: the (τ, lr) of the lowest mean metric over its seeds
    (docs/experiments.md: a shape score is the mean hard IoU loss), with the mean seconds and the run count."""
    groups = {}
    for r in rows:
        groups.setdefault((r["instance"], r["tau"], r["lr"]), []).append(r)
    best = {}
    for (inst, tau, lr), grp in groups.items():
        score = sum(r["metric"] for r in grp) / len(grp)
        if inst not in best or score < best[inst]["score"]:
            best[inst] = dict(label=grp[0]["label"], tau=tau, lr=lr, score=score, n=len(grp),
                              seconds=sum(r["seconds"] for r in grp) / len(grp))
    return best


def test_score_matrix_places_instances():
    grid = gendr.paper_grid()
    dl, tl = grid_labels()
    assert len(dl) == 23 and len(tl) == 27
    best = {k: {"score": float(k)} for k in (0, 28, 1241)}
    M = score_matrix(best)
    assert M[0, 0, 0] == 0 and M[1, 0, 1] == 28 and M[1, 22, 26] == 1241
    assert np.isnan(M).sum() == M.size - 3
    assert grid[28].distribution.squared and grid[28].tconorm.label() == "probabilistic"


def test_figures_written(tmp_path):
    rows = _fake_rows()
    written = make_figures(rows, tmp_path)
    names = {p.name for p in written}
    assert {"shape_heatmap.png", "shape_top10.png", "shape_best.csv", "shape_marginals.csv"} <= names
    for p in written:
        assert p.stat().st_size > 100
    assert len(top_fraction({i: {"score": float(i)} for i in range(50)}, 0.1)) == 5
    expected = _expected_best(rows)
    assert len(expected) == 60 and len({(b["tau"], b["lr"]) for b in expected.values()}) == 4  # all 4 win somewhere
    ranked = sorted(expected, key=lambda i: expected[i]["score"])
    assert top_fraction(expected, 0.1) == ranked[:6]  # top 10 % of 60, best first

    # shape_best.csv: one row per instance, its best setting. Scores are written to 6 significant
    # digits (rel 1e-5 covers the rounding, 5e-6), seconds to 3 decimals; τ and lr as Python writes
    # floats (exact).
    with open(tmp_path / "shape_best.csv", newline="") as f:
        reader = csv.DictReader(f)
        assert reader.fieldnames == ["instance", "label", "tau", "lr", "score", "mean_metric", "n", "seconds_per_run"]
        table = list(reader)
    assert sorted(int(r["instance"]) for r in table) == sorted(expected)
    for r in table:
        b = expected[int(r["instance"])]
        assert r["label"] == b["label"]
        assert (float(r["tau"]), float(r["lr"])) == (b["tau"], b["lr"]), (r, b)
        assert float(r["score"]) == pytest.approx(b["score"], rel=1e-5, abs=1e-12), (r, b)
        assert float(r["mean_metric"]) == pytest.approx(b["score"], rel=1e-5, abs=1e-12), (r, b)
        assert int(r["n"]) == b["n"] == 2
        assert float(r["seconds_per_run"]) == pytest.approx(b["seconds"], abs=5e-4 + 1e-9)

    # shape_marginals.csv (docs/experiments.md §4): per distribution row (plain and squared apart) and
    # per T-conorm column (both variants), the number of instances run and the mean, median and
    # minimum of their best score. The grid is distribution-major: index = (row·2 + squared)·27 + column.
    dl, tl = grid_labels()
    grid = gendr.paper_grid()
    want = {}
    for inst, b in expected.items():
        d, sq, t = inst // (2 * len(tl)), (inst // len(tl)) % 2, inst % len(tl)
        assert grid[inst].distribution.squared == bool(sq)
        want.setdefault(("distribution", dl[d], ("plain", "squared")[sq]), []).append(b["score"])
        want.setdefault(("tconorm", tl[t], "both"), []).append(b["score"])
    assert max(len(v) for v in want.values()) >= 3  # mean, median, min (and max) then differ
    with open(tmp_path / "shape_marginals.csv", newline="") as f:
        reader = csv.DictReader(f)
        assert reader.fieldnames == ["kind", "label", "variant", "n", "mean", "median", "min"]
        marg = {(r["kind"], r["label"], r["variant"]): r for r in reader}
    assert set(marg) == set(want)
    for k, scores in want.items():  # written to 4 decimals: half a unit of the last place
        r = marg[k]
        assert int(r["n"]) == len(scores), k
        assert float(r["mean"]) == pytest.approx(float(np.mean(scores)), abs=5e-5 + 1e-9), (k, r, scores)
        assert float(r["median"]) == pytest.approx(float(np.median(scores)), abs=5e-5 + 1e-9), (k, r, scores)
        assert float(r["min"]) == pytest.approx(min(scores), abs=5e-5 + 1e-9), (k, r, scores)


def test_gif(tmp_path):
    frames = [silhouette_frame(np.random.rand(3, 8, 8), np.random.rand(3, 8, 8)) for _ in range(4)]
    p = write_gif(frames, tmp_path / "a.gif")
    import imageio.v2 as imageio
    assert len(imageio.mimread(p)) == 4


def test_cli_help_and_shape(tmp_path, capsys):
    assert gendr_main(["experiment", "--help"]) == 0
    assert "shape" in capsys.readouterr().out
    for sub in ("shape", "pose", "sweep", "figures", "recon"):
        assert gendr_main(["experiment", sub, "--help"]) == 0
    capsys.readouterr()
    gif, obj = tmp_path / "s.gif", tmp_path / "s.obj"
    assert gendr_main(["experiment", "shape", "--target", "cube", "--steps", "3", "--size", "16", "--views", "3",
                       "--subdivisions", "1", "--gif", str(gif), "--gif-every", "1", "--output-mesh", str(obj),
                       "--threads", "1"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["steps_done"] == 3 and gif.exists() and obj.read_text().startswith("v ")


def test_cli_sweep_then_figures(tmp_path, capsys):
    out = tmp_path / "sw.jsonl"
    args = ["experiment", "sweep", "--dists", "logistic,exponential rev", "--tconorms", "max,probabilistic",
            "--variants", "plain", "--taus", "0.1", "--no-refine", "--workers", "0", "-q", "-o", str(out),
            "--set", "target=tetrahedron", "--set", "steps=2", "--set", "image_size=12", "--set", "views=2",
            "--set", "subdivisions=1"]
    assert gendr_main(args) == 0
    assert len(out.read_text().splitlines()) == 4
    assert gendr_main(args) == 0  # resume: nothing new
    assert len(out.read_text().splitlines()) == 4
    assert gendr_main(["experiment", "figures", str(out), "-o", str(tmp_path / "figs")]) == 0
    assert (tmp_path / "figs" / "shape_heatmap.png").exists()
    assert gendr_main(["experiment", "sweep", "--dists", "nope", "-o", str(out)]) != 0


def test_average_runs_beside_the_grid_in_sweeps_figures_and_findings(tmp_path, capsys):
    """"average" is not a T-conorm (no grid index): a sweep selects it by label, refines it by label,
    the heatmap draws it as an extra column and the findings compare it."""
    out = tmp_path / "avg.jsonl"
    args = ["experiment", "sweep", "--dists", "logistic", "--tconorms", "probabilistic,average", "--variants",
            "plain,squared", "--taus", "0.1,0.05", "--fine-steps=-0.25", "--workers", "0", "-q", "-o", str(out),
            "--set", "target=tetrahedron", "--set", "steps=2", "--set", "image_size=12", "--set", "views=2",
            "--set", "subdivisions=1"]
    assert gendr_main(args) == 0
    from gendr_experiments.figures import column_labels, score_matrix
    from gendr_experiments.sweep import load_rows, summarize_best
    rows = load_rows(out)
    assert len(rows) == 12  # 4 instances x (2 coarse + 1 fine)
    avg = [r for r in rows if r["tconorm"] == "average"]
    assert len(avg) == 6 and all(r["instance"] is None and r["status"] == "ok" for r in avg)
    best = summarize_best(rows, "shape")
    assert set(best) >= {"logistic|average", "logistic+sq|average"}
    M = score_matrix(best)
    col = column_labels().index("average")
    assert np.isfinite(M[:, 5, col]).all() and M[0, 5, col] == best["logistic|average"]["score"]
    assert gendr_main(["experiment", "figures", str(out), "-o", str(tmp_path / "figs")]) == 0
    assert "average" in (tmp_path / "figs" / "shape_marginals.csv").read_text()
    capsys.readouterr()
    assert gendr_main(["experiment", "findings", str(out)]) == 0
    assert "| average poor |" in capsys.readouterr().out
