"""Bad input to `gendr experiment`: one line naming the value, exit status 2, before any run and
without writing anything; runs that fail anyway are reported, not shown as results."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

pytest.importorskip("torch")

from gendr.cli import main as gendr_main  # noqa: E402
from gendr.errors import ParameterError  # noqa: E402
from gendr_experiments.common import check_config  # noqa: E402
from gendr_experiments.sweep import summarize_best  # noqa: E402

TINY = ["--set", "image_size=8", "--set", "views=1", "--set", "steps=1"]


def _row(**fields):
    """A result row with every field readers need (check_row), overridden by ``fields``."""
    from gendr_experiments.shape import shape_config
    row = {"key": "k", "experiment": "shape", "status": "ok", "instance": 5, "label": "x", "tau": 0.1, "lr": 0.05,
           "seed": 0, "metric": 0.5, "seconds": 1.0, "config": shape_config(instance=5, tau=0.1)}
    return {**row, **fields}


@pytest.mark.parametrize("argv,words", [
    (["sweep", "--experiment", "shape", "--instances", "99999"], "--instances 99999 is not an instance"),
    (["sweep", "--experiment", "shape", "--instances", "5-2"], "runs backwards"),
    (["sweep", "--experiment", "shape", "--instances", "abc"], "--instances expects integers"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--variants", "squarred"], "'squarred' is not a variant"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--taus", "abc"], "--taus expects comma-separated numbers"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--taus", "0"], "--taus must be numbers > 0"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--lrs", "-1"], "--lrs must be numbers > 0"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--set", "image_size16"], "--set expects NAME=VALUE"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--set", "views=0"], "views=0 must be an integer >= 1"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--set", "steps=2.5"], "steps=2.5 must be an integer"),
    (["sweep", "--experiment", "pose", "--instances", "1", "--bins", "35-15"], "--bins '35-15' runs backwards"),
    (["shape", "--steps", "-1"], "steps=-1 must be an integer >= 1"),
    (["shape", "--lr", "0"], "lr=0.0 must be a finite number > 0"),
    (["shape", "--dist-param", "shape"], "--dist-param expects NAME=VALUE"),
    (["pose", "--tau-start", "-1"], "tau_start=-1.0 must be a finite number > 0"),
    (["pose", "--angle-min", "80", "--angle-max", "10"], "angle_min=80.0 > angle_max=10.0"),
    (["shape", "--instance", "5", "--distribution", "cauchy"], "do not combine it with --distribution"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--device", "cuda"], "--device cuda needs the drjit backend"),
])
def test_bad_options_are_one_line_usage_errors(tmp_path, capsys, argv, words):
    out = tmp_path / "rows.jsonl"
    code = gendr_main(["experiment", *argv, *(["-o", str(out)] if argv[0] == "sweep" else [])])
    err = capsys.readouterr().err
    assert code == 2 and words in err and "Traceback" not in err, err
    assert not out.exists()


def test_a_sweep_whose_runs_fail_says_so_and_exits_1(tmp_path, capsys):
    """(it printed the failed instance with score 1.0000 and exited 0)"""
    out = tmp_path / "rows.jsonl"
    code = gendr_main(["experiment", "sweep", "--experiment", "shape", "--dists", "logistic", "--tconorms", "max",
                       "--variants", "plain", "--taus", "0.01", "--no-refine", "--workers", "0", "-q", *TINY,
                       "--set", "target=no_such_mesh.obj", "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 1
    assert "1 of the 1 runs ended in an error" in captured.err and "no_such_mesh.obj" in captured.err
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["status"] for r in rows] == ["error"]
    assert summarize_best(rows) == {}  # no result, so no score (figures leave the cell gray)
    assert "logistic|max" not in captured.out


@pytest.mark.parametrize("key,value", [("steps", 0), ("steps", True), ("lr", float("nan")), ("eps", 1.0),
                                       ("fov_y", 180.0), ("cutoff", 0.0), ("metric", "worst"), ("seed", -1)])
def test_check_config_names_the_setting(key, value):
    with pytest.raises(ParameterError, match=f"shape setting {key}="):
        check_config("shape", {key: value})
    check_config("shape", {"steps": 1, "lr": 0.1, "eps": 0.0, "fov_y": 30.0, "cutoff": None, "metric": "best"})


@pytest.mark.parametrize("argv,words", [
    (["verify", "{missing}"], "does not exist"),
    (["verify", "{dir}"], "is a directory"),
    # (a mistyped scene read as 'mesh file does not exist', with no word of the built-in scenes)
    (["shape", "--target", "teapot"], "neither a built-in scene (airplane, chair"),
    (["findings", "{notrow}"], "line 1 is not a result row"),
    (["verify", "{rows}", "--sample", "0"], "--sample must be >= 1"),
    (["verify", "{rows}", "--tolerance", "-1"], "--tolerance must be >= 0"),
    (["verify", "{rows}", "--json", "{dir}/nodir/v.json"], "does not exist"),
    (["cost", "{rows}", "--hours", "0"], "--hours must be > 0"),
    (["figures", "{rows}", "--fraction", "0", "-o", "{dir}/figs"], "--fraction must be in (0, 1]"),
    (["findings", "{rows}", "--noise", "-1"], "--noise must be >= 0"),
    (["findings", "{rows}", "--pose", "{rows}"], "no pose rows"),
    (["figures", "{rows}", "--experiment", "pose", "-o", "{dir}/figs"], "no pose rows"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--csv", "{dir}/nodir/x.csv", "-o", "{dir}/r.jsonl"],
     "does not exist"),
    (["sweep", "--experiment", "shape", "--instances", "1", "-o", "{dir}"], "is a directory"),
    (["sweep", "--experiment", "shape", "--instances", "1", "-o", "{dir}/notes.csv"], "refusing to append"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--scheduler", "nonsense", "-o", "{dir}/r.jsonl"],
     "is not a Dask address"),
    # (passed the check, then crashed in distributed with a traceback: TCP is what runs)
    (["sweep", "--experiment", "shape", "--instances", "1", "--scheduler", "inproc://host", "-o", "{dir}/r.jsonl"],
     "is not a Dask address"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--scheduler", "ucx://10.0.0.1:8786", "-o",
      "{dir}/r.jsonl"], "is not a Dask address"),
    # (a fine step of 400 overflowed, with a traceback, and nan failed, both after the coarse stage)
    (["sweep", "--experiment", "shape", "--instances", "1", "--taus", "0.1", "--fine-steps", "400", "--workers", "0",
      "-q", *TINY, "-o", "{dir}/r.jsonl"], "step 400.0 gives no finite tau > 0"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--taus", "0.1", "--fine-steps=nan,0.25", "--workers",
      "0", "-q", *TINY, "-o", "{dir}/r.jsonl"], "step nan gives no finite tau > 0"),
    (["tune", "--target", "tetrahedron", "--budget", "30", "--instances", "1", "--taus", "0.1", "--fine-steps",
      "400", "--workers", "0", *TINY, "-o", "{dir}/t.jsonl"], "step 400.0 gives no finite tau > 0"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--scheduler", "tcp://127.0.0.1:8786", "--workers", "2",
      "-o", "{dir}/r.jsonl"], "give one"),
    (["tune", "--target", "icosphere", "--budget", "10", "--top", "0"], "--top must be >= 1"),
    # a --set that the command sets itself was overwritten without a word (tune kept --target's mesh)
    (["sweep", "--experiment", "shape", "--instances", "1", "--set", "tau=0.5", "-o", "{dir}/r.jsonl"],
     "setting tau=0.5 (base, CLI --set) is set by the search axis tau (CLI --taus)"),
    (["sweep", "--experiment", "pose", "--instances", "1", "--bins", "15-35", "--set", "angle_max=50",
      "-o", "{dir}/r.jsonl"], "is set by the search axis angle_max (CLI --bins)"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--set", "tconorm=max", "-o", "{dir}/r.jsonl"],
     "is set by the instances"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--set", "protocol=quick", "-o", "{dir}/r.jsonl"],
     "both set protocol: give --protocol only"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--backend", "torch", "--set", "backend=drjit",
      "-o", "{dir}/r.jsonl"], "both set backend"),
    (["sweep", "--experiment", "shape", "--instances", "1", "--lrs", "0.1", "--set", "lr=0.2", "-o", "{dir}/r.jsonl"],
     "is set by the search axis lr (CLI --lrs)"),
    (["tune", "--target", "icosphere", "--budget", "10", "--set", "target=cube", "-o", "{dir}/t.jsonl"],
     "tune: setting target='cube' (base, CLI --set) is set by tune's target (CLI --target)"),
    (["tune", "--target", "icosphere", "--budget", "10", "--set", "lr=0.1", "-o", "{dir}/t.jsonl"],
     "is set by tune's lrs (CLI --lrs)"),
    # (each was a traceback, a run finished before the error, or "0 runs" with exit 0)
    (["pose", "--runs", "0"], "--runs must be >= 1, got 0"),
    (["shape", "--gif", "{dir}"], "is a directory; name the file to write"),
    (["shape", "--output-mesh", "{dir}"], "is a directory; name the file to write"),
    (["shape", "--gif", "{dir}/g.gif", "--gif-views", "0"], "--gif-views and --gif-every must be >= 1"),
    (["sweep", "--instances", "5", "--seeds", ",", "-o", "{dir}/s.jsonl"], "--seeds lists no values: got ','"),
    (["tune", "--target", "icosphere", "--budget", "10", "--lrs", ",", "-o", "{dir}/t.jsonl"], "--lrs lists no values"),
    (["sweep", "--instances", "5", "--scheduler", "tcp://127.0.0.1:99999", "-o", "{dir}/s.jsonl"],
     "Port out of range"),
    (["figures", "{errors}", "-o", "{dir}/figs"], "no finished rows (every run ended in an error)"),
])
def test_results_files_and_outputs_are_checked_before_any_work(tmp_path, capsys, argv, words):
    (tmp_path / "notrow.jsonl").write_text("[1, 2]\n")
    (tmp_path / "notes.csv").write_text("key,metric\n")
    (tmp_path / "rows.jsonl").write_text(json.dumps(_row()) + "\n")
    (tmp_path / "errors.jsonl").write_text(json.dumps(_row(status="error", metric=None)) + "\n")
    paths = {"missing": tmp_path / "missing.jsonl", "dir": tmp_path, "notrow": tmp_path / "notrow.jsonl",
             "rows": tmp_path / "rows.jsonl", "errors": tmp_path / "errors.jsonl"}
    before = sorted(p.name for p in tmp_path.iterdir())
    code = gendr_main(["experiment", *[a.format(**paths) for a in argv]])
    err = capsys.readouterr().err
    assert code == 2 and words in err and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_help_shows_each_default_once(capsys):
    """(ArgumentDefaultsHelpFormatter appended "(default: None)" after "(default: the protocol's)")"""
    assert gendr_main(["experiment", "shape", "--help"]) == 0
    out = capsys.readouterr().out
    assert "(default: None)" not in out and "(default: the protocol's)" in out


@pytest.mark.parametrize("argv,words", [
    (["recon"], "give exactly one of --data DIR and --synthetic"),
    (["recon", "--synthetic", "--data", "{dir}"], "give exactly one of"),
    (["recon", "--data", "{dir}/nodir"], "is not a directory"),
    (["recon", "--synthetic", "--steps", "-1"], "--steps must be >= 1"),
    (["recon", "--synthetic", "--batch-size", "0"], "--batch-size must be >= 1"),
    (["recon", "--synthetic", "--eval-views", "99"], "view ids are 0 ... 23"),
    (["recon", "--synthetic", "--device", "gpu"], "is not a torch device"),
    # --classes was ignored with --synthetic (always airplane, chair), and missing class files of
    # --data surfaced as a traceback
    (["recon", "--synthetic", "--classes", "02691156"], "--synthetic makes its classes from built-in scenes"),
    (["recon", "--synthetic", "--classes", "cube,"], "an empty class id"),
    (["recon", "--synthetic", "--eval-split", "test"], "makes the splits train and val, not ['test']"),
    (["recon", "--data", "{dir}"], "lacks 02691156_train_images.npz"),
    (["recon", "--synthetic", "--subdivisions", "-1"], "--subdivisions must be in [0, 8], got -1"),
])
def test_recon_options_are_checked_before_anything_is_written(tmp_path, capsys, argv, words):
    """(each failed after generating data or training, leaving the -o folder behind)"""
    out = tmp_path / "out"
    code = gendr_main(["experiment", *[a.format(dir=tmp_path) for a in argv], "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and words in err and "Traceback" not in err, err
    assert not out.exists()


def test_set_gives_the_axis_when_its_option_is_not_given(tmp_path):
    """Without --lrs (pose: --taus) the search runs the preset's value, which --set may change."""
    from gendr_experiments.sweep import load_rows
    out = tmp_path / "r.jsonl"
    assert gendr_main(["experiment", "sweep", "--experiment", "pose", "--instances", "271", "--no-refine", "-q",
                       "--workers", "0", "--set", "image_size=8", "--set", "steps=1", "--set", "pairs=1",
                       "--set", "lr=0.2", "--set", "tau_start=0.05", "-o", str(out)]) == 0
    [row] = load_rows(out)
    assert (row["lr"], row["tau_start"]) == (0.2, 0.05)


def test_an_unreachable_scheduler_fails_fast_naming_it(tmp_path, capsys):
    """(a refused connection was retried for distributed's 30 s connect timeout, then shown as a
    bare "gendr: error: Timed out")"""
    import socket
    import time
    pytest.importorskip("distributed")
    with socket.socket() as s:  # a port that nothing listens on: bound, never listened
        s.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{s.getsockname()[1]}"
        t0 = time.monotonic()
        code = gendr_main(["experiment", "sweep", "--experiment", "shape", "--instances", "1", "--taus", "0.1",
                           "--no-refine", "-q", *TINY, "--scheduler", address, "-o", str(tmp_path / "r.jsonl")])
        seconds = time.monotonic() - t0
    err = capsys.readouterr().err
    assert code == 2 and f"gendr experiment: error: no Dask scheduler answers at {address}" in err, err
    assert seconds < 15, seconds  # the probe's timeout is 5 s; refused answers at once
    assert not (tmp_path / "r.jsonl").exists()


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc (a folder nobody can write into)")
@pytest.mark.parametrize("argv", [
    ["sweep", "--experiment", "shape", "--instances", "1", "--taus", "0.1", "--no-refine", "--workers", "0", "-q",
     *TINY, "-o", "/proc/gendr-test/r.jsonl"],
    ["sweep", "--experiment", "shape", "--instances", "1", "--taus", "0.1", "--no-refine", "--workers", "0", "-q",
     *TINY, "-o", "/proc/r.jsonl"],
    ["tune", "--target", "tetrahedron", "--budget", "30", "--instances", "1", "--taus", "0.1", "--workers", "0",
     *TINY, "-o", "/proc/t.jsonl"],
    ["sweep", "--experiment", "shape", "--instances", "1", "--taus", "0.1", "--no-refine", "--workers", "0", "-q",
     *TINY, "--csv", "/proc/r.csv", "-o", "{dir}/r.jsonl"],
])
def test_an_unwritable_output_fails_before_any_run(tmp_path, capsys, monkeypatch, argv):
    """As root os.access says yes to /proc: the runs ran, then writing their rows failed (exit 1)."""
    import gendr_experiments.sweep as sweep

    def no_runs(*args, **kw):
        raise AssertionError("a run started")
    monkeypatch.setattr(sweep, "run_config", no_runs)
    code = gendr_main(["experiment", *[a.format(dir=tmp_path) for a in argv]])
    err = capsys.readouterr().err
    assert code == 2 and "is not writable" in err and "Traceback" not in err, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", [["findings"], ["figures", "-o", "{dir}/figs"], ["verify"], ["cost"]])
@pytest.mark.parametrize("bad, words", [
    (dict(seconds=None), "field seconds=None must be a number"),
    (dict(metric="0.5"), "field metric='0.5' must be a number or null"),
    (dict(instance=True), "field instance=True must be an integer or null"),
    ("-seconds", "the row lacks the field 'seconds'"),
    ("-config", "the row lacks the field 'config'"),
    ("-status", "the row lacks the field 'status'"),
])
def test_rows_missing_a_field_or_of_a_wrong_type_name_file_line_and_field(tmp_path, capsys, monkeypatch, command,
                                                                          bad, words):
    """(KeyError / TypeError tracebacks in findings, figures and verify; cost said "no rows to fit", exit 0)"""
    import gendr_experiments.sweep as sweep
    monkeypatch.setattr(sweep, "run_config", None)  # verify must not re-run anything
    row = _row(key="k2")
    if isinstance(bad, str):
        del row[bad[1:]]
    else:
        row.update(bad)
    path = tmp_path / "rows.jsonl"
    path.write_text(json.dumps(_row()) + "\n" + json.dumps(row) + "\n")
    code = gendr_main(["experiment", *[a.format(dir=tmp_path) for a in command], str(path)])
    err = capsys.readouterr().err
    assert code == 2 and f"{path}: line 2" in err and words in err and "Traceback" not in err, err
    assert not (tmp_path / "figs").exists()


def test_a_corrupt_line_before_the_last_is_an_error_naming_it(tmp_path, capsys):
    """(it was skipped without a word: only a row cut short by a kill is skipped, wherever a resume
    left it)"""
    from gendr.errors import InputValueError
    from gendr_experiments.sweep import load_rows
    path = tmp_path / "rows.jsonl"
    good = [json.dumps(_row(key=k)) for k in ("a", "b")]
    path.write_text(good[0] + '\n{"key": "zz", "experiment": "shape", "metric": 0.1, <<corrupt\n' + good[1] + "\n")
    with pytest.raises(InputValueError, match=r"rows.jsonl: line 2 is not JSON \(.*column 53\)"):
        load_rows(path)
    assert gendr_main(["experiment", "findings", str(path)]) == 2
    assert f"{path}: line 2 is not JSON" in capsys.readouterr().err
    for text in ("<<<<<<< HEAD", "garbage", '{"key": "a"} extra'):
        path.write_text(good[0] + "\n" + text + "\n" + good[1] + "\n")
        with pytest.raises(InputValueError, match="line 2 is not JSON"):
            load_rows(path)
    # every prefix of a row is what a kill leaves: skipped, before other rows (a resume appends
    # after it) or last
    for k in range(1, len(good[1])):
        path.write_text(good[0] + "\n" + good[1][:k] + "\n" + good[1] + "\n" + good[1][:k])
        assert [r["key"] for r in load_rows(path)] == ["a", "b"], good[1][:k]


def test_verify_reports_a_failed_rerun_as_an_error_not_a_drift(tmp_path, capsys):
    """(a re-run that failed, here its mesh is gone, was a drift of inf, written as Infinity: not JSON)"""
    from gendr_experiments.shape import shape_config
    cfg = shape_config(instance=5, tau=0.1, target=str(tmp_path / "gone.obj"), steps=1, image_size=8, views=1)
    path = tmp_path / "rows.jsonl"
    path.write_text(json.dumps(_row(config=dict(cfg, experiment="shape"))) + "\n")
    out = tmp_path / "v.json"
    code = gendr_main(["experiment", "verify", str(path), "--json", str(out)])
    captured = capsys.readouterr()
    assert code == 1 and "re-run failed" in captured.out and "gone.obj" in captured.out, captured
    assert "0 beyond tolerance, 1 re-runs failed" in captured.err

    def not_json(name):
        raise AssertionError(f"{name} is not JSON")
    [v] = json.loads(out.read_text(), parse_constant=not_json)
    assert v["drift"] is None and not v["ok"] and v["status"].startswith("error: ") and "gone.obj" in v["status"]


@pytest.mark.parametrize("value", [3.7, "12", True, None])
def test_a_config_instance_must_be_an_integer(value):
    """(int() made 3.7, "12" and True instances 3, 12 and 1; grid_instance took True)"""
    from gendr_experiments.common import grid_instance, instance_from_config
    from gendr_experiments.shape import shape_config
    if value is None:
        with pytest.raises(ParameterError, match="instance index None"):
            grid_instance(None)
        assert grid_instance(np.int64(3)).name == instance_from_config({"instance": 3})[2]
        return
    with pytest.raises(ParameterError, match=f"instance index {value!r} must be an integer"):
        instance_from_config({"instance": value})
    with pytest.raises(ParameterError, match=f"instance={value!r} must be None or an integer >= 0"):
        shape_config(instance=value)
    if value is True:
        with pytest.raises(ParameterError, match="instance index True"):
            grid_instance(True)
