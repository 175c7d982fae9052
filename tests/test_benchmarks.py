"""The benchmark scripts the docs quote run end to end and write the fields they document (smoke
tests with one repeat: not timing tests). bench_step.py and ab_drjit.py have their own files."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("torch")
BENCH = Path(__file__).resolve().parent.parent / "benchmarks"


def _run(script, *args, timeout=300):
    res = subprocess.run([sys.executable, str(BENCH / script), *map(str, args)], capture_output=True, text=True,
                         timeout=timeout)
    assert res.returncode == 0, res.stdout[-1000:] + res.stderr[-2000:]
    return res.stdout


def _check_timing(t, repeats=1):
    assert t["repeats"] == repeats and t["min_ms"] <= t["median_ms"] <= t["max_ms"] and t["stdev_ms"] >= 0
    assert t["peak_extra_mb"] >= 0


def test_bench_render_torch_and_drjit_render_the_same_scene(tmp_path):
    pytest.importorskip("drjit")
    rows = {}
    for backend, extra in (("torch", ()), ("drjit", ("--no-freeze",))):
        out = tmp_path / f"{backend}.json"
        _run("bench_render.py", "--backend", backend, "--repeats", 1, "--threads", 1, *extra, "--out", out)
        data = json.loads(out.read_text())
        assert {"cpu", "cores", "git_commit", "numpy", "gendr"} <= set(data["machine"])
        (row,) = data["results"]
        assert (row["case"], row["backend"], row["faces"], row["image_size"]) == ("default", backend, 1280, 256)
        assert backend in row["versions"]  # the array library's version
        for mode in ("forward", "forward_backward"):
            _check_timing(row[mode])
        rows[backend] = row
    drjit = rows["drjit"]
    assert drjit["forward"]["first_call_cold_ms"] > 0 and drjit["optimization_loop"]["median_ms"] > 0
    # the "cold" first calls compiled their kernels: their cache really was empty
    assert drjit["forward"]["first_call_cold_kernels_compiled"] > 0
    assert drjit["forward_backward"]["first_call_cold_kernels_compiled"] > 0
    assert drjit["optimization_loop"]["kernels_compiled_tau_changes"] == 0  # τ is opaque: no recompilation
    # the same scene: alpha sums agree to float32 rounding (measured 3e-7 relative)
    assert abs(rows["torch"]["alpha_sum"] - drjit["alpha_sum"]) <= 1e-5 * rows["torch"]["alpha_sum"]


def test_ab_render_prints_the_version_it_ran():
    pytest.importorskip("drjit")
    row = json.loads(_run("ab_render.py", "render", 32, 1, 2).strip().splitlines()[-1])
    assert row["gendr_drjit"].endswith("gendr_drjit/__init__.py") and "drjit" in row["machine"]["versions"]
    for k in ("fwd", "fwd_bwd"):
        t = row["results"][k]
        assert 0 < t["min_ms"] <= t["median_ms"] <= t["max_ms"] and t["repeats"] == 2


def test_ab_raster_against_a_copy_of_itself(tmp_path):
    other = tmp_path / "raster_copy.py"
    other.write_text((BENCH.parent / "backends" / "gendr_torch" / "raster.py").read_text())
    out = _run("ab_raster.py", other, "--n", 1, "--size", 32, "--out", tmp_path / "ab.json")
    assert "other: wall median" in out and "this: wall median" in out
    # the same module on both sides: the same image and gradients
    assert "image max diff 0.0\n" in out and "gradient max diff 0.0 " in out
    data = json.loads((tmp_path / "ab.json").read_text())
    assert data["image_max_diff"] == 0.0 and data["gradient_max_diff"] == 0.0 and "torch" in data["machine"]["versions"]
    for k in ("other", "this"):
        assert data["times"][k]["wall"]["repeats"] == 1 and data["times"][k]["cpu"]["median_ms"] > 0


@pytest.mark.slow
def test_cutoff_effect(tmp_path):
    out = tmp_path / "cutoff.json"
    _run("cutoff_effect.py", "--repeats", 1, "--out", out, timeout=900)
    data = json.loads(out.read_text())
    assert data["repeats"] == 1 and len(data["rows"]) >= 2
    for row in data["rows"]:
        assert row["cutoff"] == 100.0 and 0 <= row["mean_abs_alpha_change"] <= row["max_abs_alpha_change"] <= 1
        for k in ("fwd_bwd_exact", "fwd_bwd_cutoff"):
            t = row[k]
            assert 0 < t["min_ms"] <= t["median_ms"] <= t["max_ms"] and t["repeats"] == 1
    assert "torch" in data["machine"]["versions"]


def test_readme_figures_are_the_committed_json():
    """The README's performance table quotes benchmarks/results/*.json (committed, with the commit
    that made them), rounded as shown: a re-run that changes the JSON must change the README."""
    res = BENCH / "results"
    readme = (BENCH.parent / "README.md").read_text()

    def first(name):
        return json.loads((res / name).read_text())["results"][0]
    rows = {"torch": first("render_torch.json"), "compiled": first("render_torch_compiled.json"),
            "drjit": first("render_drjit.json")}
    large = first("render_drjit_large.json")
    commits = {json.loads(p.read_text())["machine"]["git_commit"] for p in res.glob("render_*.json")}
    assert len(commits) == 1 and f"measured at {commits.pop()}" in readme
    for key, r in rows.items():
        f, fb = r["forward"]["median_ms"], r["forward_backward"]["median_ms"]
        assert f"| {f:.1f} ms | {fb:.1f} ms" in readme, key
        d = 1 if key == "drjit" else 0  # (a few MB: one decimal)
        assert f"| {r['forward']['peak_extra_mb']:.{d}f} / {r['forward_backward']['peak_extra_mb']:.{d}f} MB" in readme, key
    assert f"(frozen: {rows['drjit']['frozen']['forward_backward']['median_ms']:.1f} ms)" in readme
    assert (f"drjit {large['forward']['median_ms'] / 1000:.2f} s forward, "
            f"{large['forward_backward']['median_ms'] / 1000:.2f} s forward+backward") in readme


def test_backends_table_is_the_committed_json():
    """docs/backends.md's comparison table quotes the same JSON as the README (it had kept figures
    of an older run: 58.1 / 103.8 ms for torch where the JSON says 42.0 / 104.1)."""
    res = BENCH / "results"
    doc = (BENCH.parent / "docs" / "backends.md").read_text()
    table = "\n".join(line for line in doc.splitlines() if line.startswith("| "))

    quoted = {k: json.loads((res / f"{k}.json").read_text())
              for k in ("render_torch", "render_torch_compiled", "render_drjit", "render_drjit_large", "step_torch")}
    torch_, compiled, drjit, large = (quoted[f"render_{k}"]["results"][0]
                                      for k in ("torch", "torch_compiled", "drjit", "drjit_large"))
    # every file the table quotes, not only one: "measured at" names a single commit for all
    commits = {q["machine"]["git_commit"] for q in quoted.values()}
    assert len(commits) == 1, commits
    assert f"measured at {commits.pop()}" in table

    def ms(r):
        return f"{r['forward']['median_ms']:.1f} / {r['forward_backward']['median_ms']:.1f} ms"
    assert f"| {ms(torch_)}; `compile=True`: {ms(compiled)} | {ms(drjit)}; a 100-step optimisation loop: " \
           f"{drjit['optimization_loop']['median_ms']:.1f} ms per step" in table
    assert (f"| {torch_['forward']['peak_extra_mb']:.0f} / {torch_['forward_backward']['peak_extra_mb']:.0f} MB | "
            f"{drjit['forward']['peak_extra_mb']:.1f} / {drjit['forward_backward']['peak_extra_mb']:.1f} MB |") in table
    assert (f"{large['forward']['median_ms'] / 1000:.2f} s / {large['forward_backward']['median_ms'] / 1000:.2f} s, "
            f"{large['forward']['peak_extra_mb']:.0f} / {large['forward_backward']['peak_extra_mb']:.0f} MB") in table
    assert (f"{drjit['forward']['first_call_cold_ms']:.0f} ms (fwd) / "
            f"{drjit['forward_backward']['first_call_cold_ms']:.0f} ms (fwd+bwd)") in table
    steps = {r["compile"]: r for r in quoted["step_torch"]["results"] if r["case"] == "shape"}
    assert (f"takes {steps[True]['first_step_ms'] / 1000:.1f} s with an empty Inductor cache, later ones "
            f"{steps[True]['median_ms']:.1f} ms against {steps[False]['median_ms']:.1f} ms eager") in table
