"""`gendr validate` writes a self-contained HTML report and a JSON summary; exit status follows the checks."""
import json

import pytest

pytest.importorskip("gendr_validation.report")
from gendr.cli import main  # noqa: E402
from gendr_validation import report  # noqa: E402


def test_report_smoke(tmp_path):
    s = report.run(backends=["torch"], instances=[271], scenes=["cube"], outdir=str(tmp_path), size=(24, 32),
                   cameras=["perspective", "orthographic"], limit_instances=["heaviside|or", "logistic@tau->0"])
    html = (tmp_path / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 8
    js = json.loads((tmp_path / "summary.json").read_text())
    hl = js["hard_limit"]
    assert hl["checks"] == 2 * 2 * len(js["references"])  # cameras x instances x references
    assert hl["differ_unambiguous_total"] == 0 and hl["failed"] == 0
    assert js["gradients"]["checks"] == 4 and js["gradients"]["instances"] == [271]
    assert js["passed"] == s["passed"]


def test_cli_validate_exit_code(tmp_path, capsys):
    out = tmp_path / "r"
    code = main(["validate", "--backends", "torch", "--scenes", "tetrahedron", "--instances", "0", "-o", str(out)])
    js = json.loads((out / "summary.json").read_text())
    assert code == (0 if js["passed"] else 1)
    # the lit vertex gradient is a known torch-backend bug (docs/validation.md): today the run fails on it
    failed = {(r["instance"], r["param"]) for r in js["gradients"]["rows"] if not r["passed"]}
    assert failed <= {(0, "vertices")}
    assert "hard limit:" in capsys.readouterr().out


def test_cli_validate_bad_instance(tmp_path, capsys):
    assert main(["validate", "--instances", "abc", "-o", str(tmp_path)]) == 2
    assert "instance" in capsys.readouterr().err
