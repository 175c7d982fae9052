"""`gendr validate` writes a self-contained HTML report and a JSON summary; exit status follows the checks."""
import json

import pytest

pytest.importorskip("gendr_validation.report")
from gendr.cli import main  # noqa: E402
from gendr_validation import report  # noqa: E402


def test_report_smoke(tmp_path):
    import torch
    threads = torch.get_num_threads()
    s = report.run(backends=["torch"], instances=[271], scenes=["cube"], outdir=str(tmp_path), size=(24, 32),
                   cameras=["perspective", "orthographic"], limit_instances=["heaviside|or", "logistic@tau->0"])
    html = (tmp_path / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 8
    js = json.loads((tmp_path / "summary.json").read_text())
    hl = js["hard_limit"]
    # (with no reference installed the checks below would hold as 0 == 0: install.sh installs both)
    assert js["references"], "no reference renderer (pyrender, Mitsuba 3) is installed: run install.sh"
    assert hl["checks"] == 2 * 2 * len(js["references"])  # cameras x instances x references
    assert hl["differ_unambiguous_total"] == 0 and hl["failed"] == 0
    # 271 logistic|probabilistic: vertices, unlit vertices, camera, vertex colours, τ (no p, no shape)
    assert js["gradients"]["checks"] == 5 and js["gradients"]["instances"] == [271]
    assert js["passed"] == s["passed"]
    assert torch.get_num_threads() == threads  # run() uses one thread and restores the caller's setting


def test_cli_validate_exit_code(tmp_path, capsys):
    out = tmp_path / "r"
    code = main(["validate", "--backends", "torch", "--scenes", "tetrahedron", "--instances", "0", "-o", str(out),
                 "--progress"])
    js = json.loads((out / "summary.json").read_text())
    assert code == (0 if js["passed"] else 1)
    failed = {(r["instance"], r["param"]) for r in js["gradients"]["rows"] if not r["passed"]}
    assert failed == set() and code == 0
    captured = capsys.readouterr()
    assert "hard limit:" in captured.out
    # --progress: tqdm bars on stderr although it is not a terminal, each ending full
    n_hl = js["hard_limit"]["checks"] // len(js["references"])
    assert "hard-limit: 100%" in captured.err and f"{n_hl}/{n_hl}" in captured.err
    assert "gradients: 100%" in captured.err and "1/1" in captured.err


def test_progress_bar_only_on_a_terminal_unless_forced(capsys):
    for enabled, shown in ((None, False), (False, False), (True, True)):  # pytest's stderr is no terminal
        with report._progress(3, "checks", enabled) as bar:
            for _ in range(3):
                bar.update()
        assert ("checks: 100%" in capsys.readouterr().err) is shown


def test_cli_validate_bad_instance(tmp_path, capsys):
    assert main(["validate", "--instances", "abc", "-o", str(tmp_path)]) == 2
    assert "instance" in capsys.readouterr().err


@pytest.mark.parametrize("argv, words", [
    (["validate", "--scenes", "nosuch"], "unknown scene 'nosuch'"),
    (["validate", "--instances", "99999"], "instance index 99999"),
    (["validate", "--backends", "tourch"], "unknown backend 'tourch'"),  # was: a FAILED report, exit 1
    (["gallery", "--size", "0"], "gallery size=0 must be an integer >= 1"),
])
def test_bad_input_writes_nothing(tmp_path, capsys, argv, words):
    """(each left an empty output folder, or the gallery's first three figures, behind)"""
    out = tmp_path / "out"
    assert main([*argv, "-o", str(out)]) == 2
    assert words in capsys.readouterr().err
    assert not out.exists()


def test_report_renders_in_headless_chromium(tmp_path):
    browser = pytest.importorskip("gendr_validation.browser")
    try:
        browser.find_chromium()
    except Exception as exc:  # install.sh installs Debian's chromium; elsewhere this check is optional
        pytest.skip(str(exc))
    report.run(backends=["torch"], instances=[271], scenes=["cube"], outdir=str(tmp_path), size=(24, 32),
               cameras=["perspective"], limit_instances=["heaviside|or"])
    res = browser.check_report(tmp_path / "report.html", screenshot=tmp_path / "shot.png")
    assert res["images"] >= 4 and res["decoded"] == res["images"], res
    assert (tmp_path / "shot.png").stat().st_size > 10_000  # a real page, not an empty canvas


def test_gradient_jobs_match_serial(tmp_path):
    """--jobs N (worker processes) gives the same gradient rows, in the same order, as one process."""
    kw = dict(backends=["torch"], instances=[271, 177], scenes=["cube"], size=(24, 32), cameras=["perspective"],
              limit_instances=["heaviside|or"], references=[])
    serial = report.run(outdir=str(tmp_path / "a"), **kw)["gradients"]["rows"]
    pooled = report.run(outdir=str(tmp_path / "b"), jobs=2, **kw)["gradients"]["rows"]
    assert [(r["instance"], r["param"]) for r in pooled] == [(r["instance"], r["param"]) for r in serial]
    for a, b in zip(serial, pooled):  # deterministic float64 renders: equal to round-off of thread counts
        assert b["loss_ad"] == pytest.approx(a["loss_ad"], rel=1e-12, abs=1e-15)
        assert b["passed"] == a["passed"]


def _tiny_run(tmp_path, **kw):
    args = dict(backends=["torch"], instances=[271], scenes=["cube"], outdir=str(tmp_path), size=(12, 16),
                cameras=["perspective"], limit_instances=["heaviside|or"])
    return report.run(**(args | kw))


def test_a_run_that_checked_less_than_asked_fails(tmp_path, monkeypatch, capsys):
    """Each of these printed PASSED before, or ended the run without summary.json: no gradient
    check at all, a gradient check that raised, an AD derivative that is NaN at sampled outputs
    (the NaN samples were dropped from the comparison)."""
    import numpy as np
    from gendr_validation import gradcheck
    base = _tiny_run(tmp_path / "ok")
    assert base["passed"] and not base["missing"]
    none = _tiny_run(tmp_path / "none", instances=[])
    assert not none["passed"] and none["gradients"]["checks"] == 0
    assert "no check ran" in capsys.readouterr().out

    def boom(*a, **k):
        raise RuntimeError("simulated gradient bug")
    monkeypatch.setattr(gradcheck, "check_instance", boom)
    crashed = _tiny_run(tmp_path / "crash")
    assert not crashed["passed"] and (tmp_path / "crash" / "summary.json").exists()
    (row,) = crashed["gradients"]["rows"]
    assert row["param"].startswith("error: RuntimeError: simulated gradient bug") and not row["passed"]
    monkeypatch.undo()

    real = gradcheck.TorchAdapter.per_pixel

    def half_nan(self, *a, **k):
        out = np.array(real(self, *a, **k), dtype=float)
        out[::2] = np.nan
        return out
    monkeypatch.setattr(gradcheck.TorchAdapter, "per_pixel", half_nan)
    nan = _tiny_run(tmp_path / "nan")
    assert not nan["passed"] and any(r["param"] == "vertices" and not r["passed"] for r in nan["gradients"]["rows"])


def test_requested_or_broken_backends_and_references_that_do_not_run_fail(monkeypatch):
    import gendr
    from gendr_validation import hardlimit
    real = gendr.Renderer

    def broken_drjit(*a, backend="torch", **k):
        if backend == "drjit":
            raise RuntimeError("simulated construction bug")
        return real(*a, backend=backend, **k)
    monkeypatch.setattr(gendr, "Renderer", broken_drjit)
    notes, missing = [], []
    assert hardlimit.usable_backends(None, notes, missing) == ["torch"]  # broken: fails even unasked
    assert missing == ["backend drjit: RuntimeError: simulated construction bug"]

    def unavailable(*a, backend="torch", **k):
        if backend == "drjit":
            raise gendr.BackendUnavailableError("simulated missing extra")
        return real(*a, backend=backend, **k)
    monkeypatch.setattr(gendr, "Renderer", unavailable)
    missing = []
    assert hardlimit.usable_backends(None, [], missing) == ["torch"] and missing == []  # not asked: a note
    assert hardlimit.usable_backends(["torch", "drjit"], [], missing) == ["torch"] and len(missing) == 1
    monkeypatch.setattr(hardlimit, "get_reference", lambda n: (_ for _ in ()).throw(
        hardlimit.ReferenceUnavailableError(f"{n} simulated")))
    missing = []
    assert hardlimit.open_references(["pyrender-egl"], [], missing) == {} and missing == [
        "reference pyrender-egl: pyrender-egl simulated"]
    assert hardlimit.open_references(["pyrender-egl"], [], None) == {}  # the default set: a note only


@pytest.mark.parametrize("bad", [0, -1, 1.5, True])
def test_bad_jobs_is_rejected(tmp_path, bad):
    import gendr
    with pytest.raises(gendr.ParameterError, match="jobs"):
        report.run(backends=["torch"], instances=[271], outdir=str(tmp_path), jobs=bad)
    assert not (tmp_path / "summary.json").exists()


# --- the report read at a glance: summary matrix, collapsed passing details, AD-vs-FD scatter -------------
class _Page:
    """The parts of a report page the tests look at (stdlib HTML parser, no browser)."""

    def __init__(self, text):
        from html.parser import HTMLParser
        self.ids, self.hrefs, self.details, self.cells, self.imgs = set(), [], {}, [], {}
        page = self

        class P(HTMLParser):
            def handle_starttag(self, tag, attrs):
                a = dict(attrs)
                if "id" in a:
                    page.ids.add(a["id"])
                if tag == "a" and a.get("href", "").startswith("#"):
                    page.hrefs.append(a["href"][1:])
                if tag == "details":
                    page.details[a["id"]] = "open" in a
                if tag == "td" and "data-backend" in a:
                    page.cells.append(((a["data-scene"], a["data-camera"], a["data-backend"]), a["class"]))
                if tag == "img" and "id" in a:
                    page.imgs[a["id"]] = a["src"]

        P().feed(text)


@pytest.fixture(scope="module")
def small_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("glance")
    s = report.run(backends=["torch"], instances=[271], scenes=["cube"], outdir=str(out), size=(24, 32),
                   cameras=["perspective", "orthographic"], limit_instances=["heaviside|or"])
    return s, (out / "report.html").read_text()


def test_report_summary_matrix_links_and_collapsed_details(small_report):
    s, text = small_report
    page = _Page(text)
    assert text.index('id="summary"') < text.index('id="hard-limit"')  # the matrix comes first
    keys = {(r["scene"], r["camera"], r["backend"]) for k in ("textures", "gbuffer") for r in s[k]["rows"]}
    keys |= {(r["scene"], r["camera"], r["backend"]) for r in s["hard_limit"]["table"]}
    cells = [k for k, _ in page.cells]
    assert sorted(cells) == sorted(keys) and len(cells) == len(set(cells))  # one cell per scene x camera x backend
    assert ("cube", "perspective", "torch") in cells
    assert page.hrefs and all(h in page.ids for h in page.hrefs), set(page.hrefs) - page.ids
    for sc, cam, b in keys:
        assert any(h.endswith(f"-{report._slug(sc, cam, b)}") for h in page.hrefs)
    assert s["passed"] and page.details and not any(page.details.values())  # everything passed: all collapsed
    assert all(cls == "cell pass" for _, cls in page.cells)


def test_report_scatter_of_sampled_ad_vs_fd(small_report):
    s, text = small_report
    rows = s["gradients"]["rows"]
    assert all(len(r["ad_samples"]) == len(r["fd_samples"]) > 0 for r in rows)
    for r in rows:  # the samples the per-pixel metric compared: AD on the diagonal within its threshold
        ad, fd = (__import__("numpy").asarray(r[k]) for k in ("ad_samples", "fd_samples"))
        assert abs(ad - fd).max() <= 1e-2 * max(abs(fd).max(), 1e-3)
    src = _Page(text).imgs["gradient-scatter"]
    assert src.startswith("data:image/png;base64,") and len(src) > 2000


def test_report_failing_sections_are_open(small_report):
    import copy
    s, _ = small_report
    bad = copy.deepcopy(s)
    bad["passed"] = False
    hl = bad["hard_limit"]["table"][0]
    hl["failed_instances"] = 1
    gbr = next(r for r in bad["gbuffer"]["rows"] if r["camera"] != hl["camera"])
    gbr["passed"] = False
    bad["gradients"]["rows"][0]["passed"] = False
    page = _Page(report._html(bad, [], [], {}, None))
    failed_cells = {k for k, cls in page.cells if cls == "cell failed"}
    assert failed_cells == {(hl["scene"], hl["camera"], hl["backend"]), (gbr["scene"], gbr["camera"], gbr["backend"])}
    opened = {i for i, o in page.details.items() if o}
    assert opened == {f"hl-{report._slug(hl['scene'], hl['camera'])}", f"gb-{report._slug(gbr['scene'], gbr['camera'])}",
                      "gr-torch"}, opened
    assert f"hl-{report._slug(hl['scene'], hl['camera'], hl['backend'])}" in page.ids
    assert all(h in page.ids for h in page.hrefs)
