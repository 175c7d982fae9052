"""benchmarks/bench_step.py runs end to end and writes the fields it documents (not a timing test)."""
import json
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parent.parent / "benchmarks" / "bench_step.py"


def test_bench_step_quickest_configuration(tmp_path):
    out = tmp_path / "step.json"
    cmd = [sys.executable, str(BENCH), "--case", "pose", "--dist", "logistic", "--backend", "torch", "--quick",
           "--threads", "1", "--out", str(out)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    data = json.loads(out.read_text())
    assert json.loads(res.stdout) == data  # printed and written
    for key in ("cpu", "cores", "git_commit"):
        assert key in data["machine"]
    assert set(data["versions"]) == {"torch", "drjit", "numpy", "python", "gendr"}
    assert len(data["loadavg_before"]) == len(data["loadavg_after"]) == 3
    (row,) = data["results"]
    assert (row["case"], row["backend"], row["freeze"], row["distribution"]) == ("pose", "torch", False, "logistic")
    assert row["repeats"] == 1 and row["threads"] == 1 and row["faces"] > 0
    for key in ("median_ms", "min_ms", "max_ms", "setup_ms", "first_step_ms", "first_call_ms"):
        assert row[key] > 0, key
    assert row["stdev_ms"] >= 0 and row["min_ms"] <= row["median_ms"] <= row["max_ms"]
    assert 0 <= row["loss_last"] <= 1 and row["renderer_tau"] > 0
