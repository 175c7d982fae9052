"""benchmarks/ab_drjit.py runs end to end, writes the fields it documents, and its difference check
tells identical rasterizers from different ones (not a timing test)."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("drjit", reason="the Dr.Jit backend needs drjit (pip install gendr[drjit])")

ROOT = Path(__file__).resolve().parent.parent
AB = ROOT / "benchmarks" / "ab_drjit.py"
RASTER = ROOT / "backends" / "gendr_drjit" / "raster.py"
CENTRES = "    return (2.0 * Float(j) + (1.0 - W)) / H\n"


def _run(other, out):
    cmd = [sys.executable, str(AB), str(other), "--tau", "0.003", "--steps", "1", "--out", str(out)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    return json.loads(out.read_text())


def test_ab_drjit_same_and_shifted_rasterizer(tmp_path):
    same = _run(RASTER, tmp_path / "same.json")
    assert same["difference"] == {"image_max_abs": 0.0, "vertex_gradient_max_abs": 0.0}
    for key in ("cpu", "cores", "git_commit"):
        assert key in same["machine"]
    assert same["case"]["tau"] == 0.003 and same["case"]["threads"] == 1
    for version in ("current", "other"):
        for part in ("loop_a", "loop_b", "kernels", "step"):
            s = same["results"][version][part]
            assert s["steps"] == 1 and 0 < s["min_ms"] <= s["median_ms"] <= s["max_ms"], (version, part)
    # pixel centres moved by 1e-3 screen units: the check must see it
    src = RASTER.read_text()
    assert CENTRES in src
    shifted = tmp_path / "raster_shifted.py"
    shifted.write_text(src.replace(CENTRES, "    return (2.0 * Float(j) + (1.0 - W)) / H + 1e-3\n"))
    moved = _run(shifted, tmp_path / "moved.json")["difference"]
    assert moved["image_max_abs"] > 1e-4 and moved["vertex_gradient_max_abs"] > 0
