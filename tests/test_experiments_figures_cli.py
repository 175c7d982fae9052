"""gendr_experiments.figures and the `gendr experiment` command line."""
import json

import numpy as np

import gendr
from gendr.cli import main as gendr_main
from gendr_experiments.figures import (grid_labels, make_figures, score_matrix, silhouette_frame, top_fraction,
                                       write_gif)


def _fake_rows(n=60, seed=0):
    rng = np.random.default_rng(seed)
    grid = gendr.paper_grid()
    rows = []
    for inst in rng.choice(len(grid), n, replace=False):
        for tau in (0.1, 0.01):
            rows.append(dict(key=f"{inst}-{tau}", experiment="shape", instance=int(inst), label=grid[inst].name,
                             tau=tau, lr=0.05, seed=0, metric=float(rng.uniform()), seconds=1.0, status="ok"))
    return rows


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
