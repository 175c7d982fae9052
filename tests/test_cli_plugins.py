"""Plug-in sub-commands: the ``gendr.commands`` entry-point group (gendr/cli.py).

gendr's own plug-ins (validate, gallery from gendr_validation; experiment from gendr_experiments) are
registered in pyproject.toml; a fake third-party distribution made in a temporary directory (a
``*.dist-info`` folder with ``entry_points.txt``, found by importlib.metadata on sys.path) shows
that another package adds a command without touching gendr/.
"""
from __future__ import annotations

import subprocess
import sys
import textwrap
import tomllib
from importlib import metadata
from pathlib import Path

import pytest

from gendr import cli

ROOT = Path(__file__).resolve().parents[1]
OURS = {"validate": "gendr_validation.cli:validate_main",
        "gallery": "gendr_validation.cli:gallery_main",
        "experiment": "gendr_experiments.cli:main"}
PLUGIN_PACKAGES = ("gendr_validation", "gendr_experiments")


def _run_python(code: str) -> str:
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    return res.stdout


def test_importing_the_cli_imports_no_plugin():
    _run_python("import gendr.cli, sys; "
                f"bad = [m for m in sys.modules if m.startswith({PLUGIN_PACKAGES!r})]; assert not bad, bad")


def test_help_lists_the_plugins_without_importing_them():
    out = _run_python("import sys, gendr.cli; code = gendr.cli.main(['--help']); "
                      f"bad = [m for m in sys.modules if m.startswith({PLUGIN_PACKAGES!r})]; "
                      "assert code == 0 and not bad, (code, bad)")
    for name in OURS:
        assert f"    {name}" in out
    assert "check hard-limit silhouettes" in out  # the first line of validate_main's docstring


def test_pyproject_registers_our_commands_and_they_load():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = project["entry-points"]["gendr.commands"]
    assert declared == OURS
    for name, value in declared.items():
        ep = metadata.EntryPoint(name, value, cli.COMMAND_GROUP)
        assert callable(ep.load())


def test_installed_metadata_is_current():
    """The installed gendr distribution has pyproject's entry points (else re-run install.sh)."""
    installed = {ep.name: ep.value for ep in metadata.entry_points(group=cli.COMMAND_GROUP)
                 if ep.dist is None or ep.dist.name == "gendr"}
    assert installed == OURS, ("the installed metadata of gendr is older than pyproject.toml: "
                               "run `bash install.sh` (or `pip install -e .`) again")


def test_validate_help_goes_to_the_plugin(capsys):
    assert cli.main(["validate", "--help"]) == 0
    assert "usage: gendr validate" in capsys.readouterr().out
    assert cli.main(["gallery", "--no-such-option"]) == 2
    assert "unrecognized arguments: --no-such-option" in capsys.readouterr().err


def test_list_commands(capsys):
    assert cli.main(["list", "commands"]) == 0
    out = capsys.readouterr().out
    for name, value in OURS.items():
        assert name in out and value in out


# ------------------------------------------------------------------------------------------------
# a third party's command
# ------------------------------------------------------------------------------------------------
PLUGIN_SOURCE = '''
"""A third party's gendr commands (test fixture)."""
import argparse
import sys
from gendr.errors import ParameterError

IMPORTED = sys.modules[__name__]


def hello(argv):
    """Say hello to the arguments. More text that gendr --help leaves out."""
    print("hello", argv)
    return 3


def fails(argv):
    raise ParameterError("fails: the widget parameter w=-1 must be > 0")


def exits(argv):
    parser = argparse.ArgumentParser(prog="gendr exits")
    parser.add_argument("--n", type=int, required=True)
    parser.parse_args(argv)  # exits 2 on bad input, 0 on --help: gendr returns that status
    return 0


def nothing(argv):
    return None
'''

ENTRY_POINTS = """
[gendr.commands]
hello = gendr_fake_plugin:hello
fails = gendr_fake_plugin:fails
exits = gendr_fake_plugin:exits
nothing = gendr_fake_plugin:nothing
render = gendr_fake_plugin:hello
missing = gendr_fake_missing_module:main
"""


@pytest.fixture
def fake_plugin(tmp_path, monkeypatch):
    (tmp_path / "gendr_fake_plugin.py").write_text(textwrap.dedent(PLUGIN_SOURCE))
    info = tmp_path / "gendr_fake_plugin-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: gendr-fake-plugin\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "gendr_fake_plugin", raising=False)
    yield tmp_path
    sys.modules.pop("gendr_fake_plugin", None)


def test_third_party_command_is_listed_without_import(fake_plugin, capsys):
    commands = cli.plugin_commands()
    assert {"hello", "fails", "exits", "missing"} <= set(commands)
    assert "render" not in commands  # a built-in name cannot be taken
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "say hello to the arguments" in out and "More text" not in out
    assert "gendr_fake_plugin" not in sys.modules


def test_third_party_command_runs_with_its_arguments(fake_plugin, capsys):
    assert cli.main(["hello", "x", "--flag", "-o", "out", "--help"]) == 3
    assert capsys.readouterr().out == "hello ['x', '--flag', '-o', 'out', '--help']\n"
    assert cli.main(["hello"]) == 3
    assert cli.main(["nothing"]) == 0


def test_third_party_errors(fake_plugin, capsys):
    assert cli.main(["fails"]) == 2  # a GendrError: one line, no traceback
    assert capsys.readouterr().err == "gendr: error: fails: the widget parameter w=-1 must be > 0\n"
    assert cli.main(["exits", "--n", "x"]) == 2  # argparse's SystemExit becomes the exit status
    assert "invalid int value" in capsys.readouterr().err
    assert cli.main(["exits", "--help"]) == 0
    assert cli.main(["missing"]) == 2  # registered but not importable: says what to install
    err = capsys.readouterr().err
    assert "gendr missing is registered by gendr-fake-plugin" in err and "gendr_fake_missing_module" in err


def test_builtin_render_is_not_replaced(fake_plugin, tmp_path, capsys):
    assert cli.main(["render", "--help"]) == 0
    assert "usage: gendr render" in capsys.readouterr().out


def test_help_line_fallbacks(tmp_path, monkeypatch):
    """No docstring on the object: the module's; no source at all: a generic line."""
    (tmp_path / "gendr_fake_nodoc.py").write_text('"""Module line. Rest."""\ndef main(argv):\n    return 0\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    ep = metadata.EntryPoint("nodoc", "gendr_fake_nodoc:main", cli.COMMAND_GROUP)
    assert cli.plugin_help(ep) == "module line"
    ep = metadata.EntryPoint("gone", "gendr_fake_not_there.sub:main", cli.COMMAND_GROUP)
    assert cli.plugin_help(ep) == "a plug-in command"
    assert "gendr_fake_nodoc" not in sys.modules


def test_validate_without_its_extra_says_what_to_install(monkeypatch, tmp_path, capsys):
    pytest.importorskip("gendr_validation")
    monkeypatch.delitem(sys.modules, "gendr_validation.report", raising=False)
    monkeypatch.setitem(sys.modules, "tqdm", None)  # as if the validation extra were not installed
    assert cli.main(["validate", "-o", str(tmp_path / "r")]) == 2
    assert "gendr validate needs the validation extra (pip install gendr[validation])" in capsys.readouterr().err


@pytest.mark.slow
def test_the_committed_gallery_regenerates_pixel_for_pixel(tmp_path):
    """docs/gallery/*.png are results the docs show: `gendr gallery -o docs/gallery` must rebuild
    them from the code at hand (they matched exactly at 106d681; ~20 s). Pixel for pixel on purpose,
    so it also fails after a matplotlib or font update that redraws them: regenerate and commit
    the figures then."""
    np = pytest.importorskip("numpy")
    pytest.importorskip("matplotlib")
    Image = pytest.importorskip("PIL.Image")
    assert cli.main(["gallery", "-o", str(tmp_path)]) == 0
    committed = sorted((Path(__file__).resolve().parent.parent / "docs" / "gallery").glob("*.png"))
    assert committed and sorted(p.name for p in tmp_path.glob("*.png")) == [p.name for p in committed]
    for p in committed:
        np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / p.name)), np.asarray(Image.open(p)),
                                      err_msg=p.name)


def test_submodules_load_on_first_use_without_a_backend():
    """docs/conventions.md's `gendr.interop.from_pytorch3d_look_at(...)` after `import gendr` raised
    AttributeError (as did gendr.scenes and gendr.images, listed as public API in docs/index.md)."""
    out = _run_python("import sys, gendr; cam = gendr.interop.from_pytorch3d_look_at(2.7, 20, 30, fov=60, "
                      "image_size=(8, 8)); m = gendr.scenes.icosphere(1); gendr.images; "
                      "print(type(cam).__name__, m.faces.shape[0], 'torch' in sys.modules, 'drjit' in sys.modules)")
    assert out.split() == ["PerspectiveCamera", "80", "False", "False"], out
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        import gendr
        gendr.nope
