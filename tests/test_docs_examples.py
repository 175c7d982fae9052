"""The Python examples of README.md and docs/*.md run as written, and the values their comments
quote are what they print. README's blocks run in order in one namespace, as a reader pastes them;
a docs block runs alone beside the names its page has introduced in prose (``verts``, ``faces``,
``cam``, ``tau``: a small float64 scene). A block that cannot run here is listed in ``NOT_RUN`` with
the reason; a new block runs by default."""
from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
import gendr  # noqa: E402
from gendr import scenes  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
#: blocks not run, by (file, text of their first line): why
NOT_RUN = {
    ("docs/architecture.md", "DISTRIBUTIONS.add(DistributionFamily("): "a template with ... placeholders "
                                                                       "(tests/test_extending.py follows it)",
    ("docs/architecture.md", "TCONORMS.add(TConormFamily("): "a template with ... placeholders "
                                                             "(tests/test_extending.py follows it)",
    ("docs/conventions.md", "# PyTorch3D"): "its first half is PyTorch3D code (not a dependency); the gendr half "
                                            "is tests/test_interop.py's subject",
}


def python_blocks(rel):
    """[(line of the block's first code line, code)] of the ```python blocks of ``rel``."""
    text = (ROOT / rel).read_text()
    return [(text[:m.start()].count("\n") + 2, m.group(1))
            for m in re.finditer(r"```python\n(.*?)```", text, re.S)]


DOCS = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))
ALL_BLOCKS = [(rel, line, code) for rel in DOCS for line, code in python_blocks(rel)]
DOC_BLOCKS = [b for b in ALL_BLOCKS if (b[0], b[2].splitlines()[0].strip()) not in NOT_RUN]


def _run(code, name, ns):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, name, "exec"), ns)
    return out.getvalue()


def _page_names():
    """The names the docs pages use without defining them: a float64 scene, its camera, τ."""
    m = scenes.icosphere(1)  # 80 faces: the pages' renders are 256² (learnable gamma: seconds)
    verts = torch.tensor(m.vertices, dtype=torch.float64)
    return dict(torch=torch, np=np, gendr=gendr, verts=verts, vertices=verts.float(), faces=torch.tensor(m.faces),
                cam=gendr.orbit_camera(30.0, 20.0, 3.0), tau=0.02)


def test_readme_examples_run_in_order(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    blocks = python_blocks("README.md")
    assert len(blocks) >= 3
    ns = {}
    for line, code in blocks:
        _run(code, f"README.md:{line}", ns)
    # what the comments say
    assert tuple(ns["image"].shape) == (1, 128, 128, 4)
    assert tuple(ns["verts"].grad.shape) == (642, 3) and torch.isfinite(ns["verts"].grad).all()
    assert len(ns["grid"]) == 1242
    assert isinstance(ns["g"], gendr.GBuffer)


@pytest.mark.parametrize("rel,line,code", DOC_BLOCKS, ids=[f"{r}:{n}" for r, n, _ in DOC_BLOCKS])
def test_docs_example_runs(rel, line, code, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _run(code, f"{rel}:{line}", _page_names())


def test_every_fence_has_a_language_this_file_knows():
    """Python blocks are found by their ```python fence, shell commands in the others: a ```py or
    an indented fence would be skipped without notice."""
    known = {"", "python", "bash", "toml", "json", "text"}
    for rel in ["README.md", *DOCS]:
        for m in re.finditer(r"^([ \t]*)```(\S*)", (ROOT / rel).read_text(), re.M):
            assert m.group(1) == "" and m.group(2) in known, f"{rel}: fence {m.group(0)!r}"


def test_not_run_lists_only_existing_blocks():
    listed = {(rel, code.splitlines()[0].strip()) for rel, _, code in ALL_BLOCKS}
    assert set(NOT_RUN) <= listed, set(NOT_RUN) - listed


def test_quoted_values_are_what_the_examples_print():
    # docs/grid.md: "inst.index, inst.name   # 1093, '...'"
    (_, code), = [b for b in python_blocks("docs/grid.md") if "paper_grid()" in b[1]]
    index, name = re.search(r"inst\.index, inst\.name\s+# (\d+), '([^']+)'", code).groups()
    ns = _page_names()
    _run(code, "docs/grid.md", ns)
    assert (ns["inst"].index, ns["inst"].name) == (int(index), name)
    # docs/distributions.md: the gradients of the eps example, "# 0.0 -1.07950 -12.5951 / 1e-6 ..."
    (_, code), = [b for b in python_blocks("docs/distributions.md") if "for eps in" in b[1]]
    quoted = [q.split() for q in re.search(r"print\(.*\)\s+#\s*(.*)", code).group(1).split("/")]
    printed = [row.split() for row in _run(code, "docs/distributions.md", {}).strip().splitlines()]
    assert len(printed) == len(quoted) == 3
    for want, got in zip(quoted, printed):
        assert float(want[0]) == float(got[0])
        for w, g in zip(want[1:], got[1:]):
            digits = len(w.split(".")[1])  # the quoted value, rounded to the digits it shows
            assert abs(float(g) - float(w)) <= 0.5 * 10.0 ** -digits, (want, got)


def documented_commands():
    """[(file, command)]: the ``gendr`` commands of the shell blocks of README.md and docs/*.md
    (continuation lines joined, chains split at && ; ||, environment assignments and the
    ``.venv/bin/`` prefix dropped)."""
    out = []
    for rel in ["README.md", *DOCS]:
        text = (ROOT / rel).read_text()
        for m in re.finditer(r"```(\w*)\n(.*?)```", text, re.S):
            if m.group(1) in ("python", "toml", "json", "text"):
                continue
            lines = re.sub(r"\\\n\s*", " ", m.group(2)).splitlines()
            for cmd in (part for line in lines for part in re.split(r"&&|;|\|\|", line)):
                cmd = re.sub(r"^(\w+=\S*\s+)+", "", cmd.strip().removeprefix("$ "))
                cmd = re.sub(r"^\S*/gendr ", "gendr ", cmd)
                if cmd.startswith("gendr "):
                    out.append((rel, cmd))
    return out


COMMANDS = documented_commands()


def test_documented_commands_parse():
    """Each documented ``gendr`` command line is accepted by the parser of its command (gendr's own,
    then the plug-in's: experiment, validate, gallery) as written; nothing runs. Lines whose arguments
    are a "..." placeholder are left out."""
    import shlex
    from gendr.cli import build_parser
    from gendr_experiments.cli import build_parser as experiment_parser
    from gendr_validation.cli import gallery_parser, validate_parser
    plugins = {"experiment": experiment_parser, "validate": validate_parser, "gallery": gallery_parser}
    checked = []
    for rel, cmd in COMMANDS:
        args = shlex.split(cmd, comments=True)[1:]
        if any("..." in a or "…" in a for a in args):
            continue
        err = io.StringIO()
        try:
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
                ns = build_parser(describe_plugins=False).parse_args(args)
                if ns.command in plugins:
                    plugins[ns.command]().parse_args(ns.plugin_args)
        except SystemExit as e:
            assert e.code == 0, f"{rel}: `{cmd}` does not parse: {err.getvalue().strip()}"
        checked.append(cmd)
    assert len(checked) >= 20, checked  # the docs have ~25 such lines: the extraction still finds them
