"""The command line (gendr.cli) and the image helpers it uses (gendr.images: PNG files via Pillow,
contact sheets)."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import gendr
from gendr.cli import DEMO_INSTANCES, main
from gendr.errors import BackendUnavailableError, DTypeError, InputValueError, ParameterError, ShapeError
from gendr.images import contact_sheet, read_png, to_uint8, write_png
from gendr.scenes import SCENES


# ------------------------------------------------------------------------------------------------
# PNG files and contact sheets
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("channels", [None, 1, 2, 3, 4])
def test_png_round_trip_uint8(tmp_path, channels):
    rng = np.random.default_rng(channels or 0)
    shape = (9, 11) if channels is None else (9, 11, channels)
    img = rng.integers(0, 256, shape, dtype=np.uint8)
    back = read_png(write_png(tmp_path / "x.png", img))
    assert back.dtype == np.uint8
    assert np.array_equal(back, img.reshape(9, 11, -1))
    from PIL import Image
    with Image.open(tmp_path / "x.png") as im:  # a plain 8-bit PNG of the matching colour type
        assert (im.format, im.mode, im.size) == ("PNG", {1: "L", 2: "LA", 3: "RGB", 4: "RGBA"}[channels or 1], (11, 9))


def test_png_float_conversion():
    img = np.array([[-1.0, 0.0, 0.5, 1.0, 2.0, np.nan]])
    assert to_uint8(img)[0, :, 0].tolist() == [0, 0, 128, 255, 255, 0]
    assert to_uint8(np.array([[True, False]]))[0, :, 0].tolist() == [255, 0]
    assert to_uint8(np.ones((2, 2), dtype=np.float32)).max() == 255


def test_write_png_round_trip_and_atomic(tmp_path):
    img = np.linspace(0, 1, 6 * 8 * 3).reshape(6, 8, 3)
    path = write_png(tmp_path / "a.png", img)
    assert path == tmp_path / "a.png"
    assert np.array_equal(read_png(path), to_uint8(img))
    assert os.listdir(tmp_path) == ["a.png"]  # no temporary file left behind
    assert oct(os.stat(path).st_mode & 0o777) != oct(0o600)  # not the private mode of a temp file
    write_png(str(tmp_path / "a.png"), np.zeros((2, 2)))  # overwrite, str path
    assert read_png(tmp_path / "a.png").shape == (2, 2, 1)


def test_write_png_failure_leaves_old_file_and_no_temp(tmp_path, monkeypatch):
    path = tmp_path / "keep.png"
    write_png(path, np.ones((3, 3)))
    before = path.read_bytes()

    def boom(src, dst):
        raise OSError("disk full")
    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        write_png(path, np.zeros((4, 4, 4)))
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["keep.png"]
    with pytest.raises(ShapeError):  # invalid input: nothing is created at all
        write_png(tmp_path / "bad.png", np.zeros((3, 3, 5)))
    assert os.listdir(tmp_path) == ["keep.png"]


@pytest.mark.parametrize("shape", [(4,), (2, 3, 5), (1, 2, 3, 4), (0, 3, 3)])
def test_png_bad_shapes_name_the_shape(tmp_path, shape):
    with pytest.raises(ShapeError, match=str(shape).replace("(", r"\(").replace(")", r"\)")):
        write_png(tmp_path / "x.png", np.zeros(shape))
    assert os.listdir(tmp_path) == []


def test_png_bad_dtype(tmp_path):
    with pytest.raises(DTypeError, match="int32"):
        write_png(tmp_path / "x.png", np.zeros((2, 2), dtype=np.int32))


def test_read_png_errors(tmp_path):
    p = tmp_path / "x.png"
    p.write_bytes(b"not a png at all")
    with pytest.raises(InputValueError, match="x.png"):
        read_png(p)
    data = bytearray(write_png(p, np.zeros((3, 3))).read_bytes())
    data[20] ^= 0xFF  # corrupt the IHDR -> CRC mismatch
    p.write_bytes(bytes(data))
    with pytest.raises(InputValueError, match="x.png"):
        read_png(p)
    p.write_bytes(bytes(data[:40]))  # truncated
    with pytest.raises(InputValueError, match="x.png"):
        read_png(p)
    with pytest.raises(InputValueError, match="missing.png"):
        read_png(tmp_path / "missing.png")


def test_read_png_scales_16_bit_gray_and_refuses_float_pixels(tmp_path, monkeypatch):
    """Pillow's convert() clips 16-bit gray at 255 (1000, 30000, 65535 all read as 255 before);
    float pixels (TIFF mode F) have no 8-bit meaning and were truncated to 0 / 1."""
    Image = pytest.importorskip("PIL.Image")
    Image.fromarray(np.array([[0, 1000, 30000, 65535]], dtype=np.uint16)).save(tmp_path / "g16.png")
    got = read_png(tmp_path / "g16.png")
    assert got.shape == (1, 4, 1) and got.ravel().tolist() == [0, 4, 117, 255]  # round(v·255/65535)
    from PIL import PngImagePlugin  # Pillow < 10.3 opened 16-bit gray PNGs as mode "I": the same
    monkeypatch.setitem(PngImagePlugin._MODES, (16, 0), ("I", "I;16B"))
    assert read_png(tmp_path / "g16.png").ravel().tolist() == [0, 4, 117, 255]
    Image.fromarray(np.array([[0.25, 0.5, 1.0]], dtype=np.float32)).save(tmp_path / "f.tiff")
    with pytest.raises(InputValueError, match=r"f.tiff.*float \(Pillow mode 'F'\)"):
        read_png(tmp_path / "f.tiff")


def test_without_pillow_render_says_what_to_install(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "PIL", None)  # import PIL fails as if it were not installed
    with pytest.raises(BackendUnavailableError, match=r"gendr\[images\]"):
        write_png(tmp_path / "x.png", np.zeros((2, 2)))
    assert main(["render", "cube", "-o", str(tmp_path / "c.png"), "--size", "8"]) == 2
    assert "gendr render needs Pillow" in capsys.readouterr().err
    assert os.listdir(tmp_path) == []


def test_contact_sheet_layout():
    a = np.zeros((4, 5, 4)); a[..., 0] = 1; a[..., 3] = 1          # red RGBA
    b = np.full((2, 3), 0.5)                                          # gray, smaller: centred
    c = (np.ones((4, 5, 3)) * 255).astype(np.uint8)                   # white RGB uint8
    sheet = contact_sheet([a, b, c], columns=2, pad=1, background=(0, 0, 1, 1))
    assert sheet.shape == (1 + 2 * (4 + 1), 1 + 2 * (5 + 1), 4)
    assert np.allclose(sheet[1:5, 1:6], a)
    assert np.allclose(sheet[0], [0, 0, 1, 1])  # border
    assert np.allclose(sheet[1 + 1:1 + 3, 7 + 1:7 + 4, :3], 0.5)  # b centred in cell (0, 1)
    assert np.allclose(sheet[1 + 1:1 + 3, 7 + 1:7 + 4, 3], 1.0)
    assert np.allclose(sheet[6:10, 1:6], 1.0)  # c in cell (1, 0)
    assert np.allclose(sheet[6:10, 7:12], [0, 0, 1, 1])  # empty cell: background
    assert contact_sheet([a] * 4).shape == (2 + 2 * 6, 2 + 2 * 7, 4)  # default: square-ish, pad 2
    batch = np.zeros((3, 4, 5, 4))
    assert contact_sheet(batch, columns=3, pad=0).shape == (4, 15, 4)


def test_contact_sheet_errors():
    with pytest.raises(ShapeError, match="at least one"):
        contact_sheet([])
    with pytest.raises(ShapeError, match=r"image 1 .*\(2, 2, 7\)"):
        contact_sheet([np.zeros((2, 2, 3)), np.zeros((2, 2, 7))])
    with pytest.raises(ParameterError, match="columns"):
        contact_sheet([np.zeros((2, 2, 3))], columns=0)


# ------------------------------------------------------------------------------------------------
# CLI
# ------------------------------------------------------------------------------------------------

def _run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _error_line(err):
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("gendr: error: ") and "Traceback" not in err
    return lines[0]


def test_help(capsys):
    code, out, _ = _run(capsys, "--help")
    assert code == 0
    assert "render" in out and "demo" in out and "list" in out and "examples:" in out
    for cmd in ("render", "demo", "list"):
        code, out, _ = _run(capsys, cmd, "--help")
        assert code == 0 and "examples:" in out and f"gendr {cmd}" in out
    code, out, _ = _run(capsys, "render", "--help")
    for option in ("--distribution", "--dist-param", "--reversed", "--squared", "--shift", "--tconorm",
                   "--tconorm-param", "--tau", "--eps", "--size", "--camera", "--azimuth", "--elevation",
                   "--distance", "--fov", "--blend", "--backend", "--batch-views", "--instance"):
        assert option in out


def test_usage_errors_exit_2(capsys):
    assert _run(capsys, )[0] == 2  # no command
    code, _, err = _run(capsys, "render", "icosphere", "-o", "x.png", "--size", "12y")
    assert code == 2 and "--size" in err
    code, _, err = _run(capsys, "list", "nothing")
    assert code == 2


def test_list(capsys):
    code, out, _ = _run(capsys, "list", "scenes")
    assert code == 0 and all(name in out for name in SCENES) and "1280" in out
    code, out, _ = _run(capsys, "list", "distributions")
    assert code == 0 and "logistic" in out
    code, out, _ = _run(capsys, "list", "tconorms")
    assert code == 0 and "probabilistic" in out and "yager" in out and "p (" in out
    code, out, _ = _run(capsys, "list", "backends")
    assert code == 0 and "torch" in out


def test_list_grid(capsys):
    code, out, _ = _run(capsys, "list", "grid")
    grid = gendr.paper_grid()
    assert code == 0
    lines = out.splitlines()  # exactly one line per instance on stdout
    assert len(lines) == len(grid) == 1242
    assert lines[0].split(None, 1) == ["0", grid[0].name]


def _alpha_checks(path, shape):
    img = read_png(path)
    assert img.shape == shape
    assert img[..., 3].max() > 0
    for corner in (img[0, 0], img[0, -1], img[-1, 0], img[-1, -1]):
        assert corner[3] == 0
    return img


def test_render_builtin_scene(tmp_path, capsys):
    out = tmp_path / "sub" / "sphere.png"
    code, stdout, err = _run(capsys, "render", "icosphere", "-o", str(out), "--size", "24x32")
    assert code == 0, err
    assert str(out) in stdout
    _alpha_checks(out, (24, 32, 4))


def test_render_options(tmp_path, capsys):
    out = tmp_path / "t.png"
    code, _, err = _run(capsys, "render", "tetrahedron", "-o", str(out), "--size", "20",
                        "--distribution", "logistic", "--squared", "--tau", "1e-4", "--tconorm", "yager",
                        "--tconorm-param", "p=2", "--camera", "orthographic", "--azimuth", "10",
                        "--elevation", "-15", "--blend", "hard", "--colors", "normals", "--eps", "1e-3")
    assert code == 0, err
    _alpha_checks(out, (20, 20, 4))


def test_render_batch_views(tmp_path, capsys):
    out = tmp_path / "views.png"
    code, _, err = _run(capsys, "render", "chair", "-o", str(out), "--size", "16", "--batch-views", "3",
                        "--blend", "none")
    assert code == 0, err
    img = read_png(out)
    assert img.shape == (16 + 4, 3 * 16 + 4 * 2, 4)
    for k in range(3):  # every view shows something
        x = 2 + k * 18
        assert img[2:18, x:x + 16, 3].max() > 0


def test_render_mesh_file(tmp_path, capsys):
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.creation.box(extents=(30.0, 20.0, 10.0))  # far outside the unit ball: normalised
    mesh.apply_translation((100.0, 0.0, 0.0))
    path = tmp_path / "box.obj"
    mesh.export(path)
    out = tmp_path / "box.png"
    code, stdout, err = _run(capsys, "render", str(path), "-o", str(out), "--size", "24")
    assert code == 0, err
    assert "box.obj" in stdout
    _alpha_checks(out, (24, 24, 4))


def test_bad_distribution_lists_valid_names(tmp_path, capsys):
    code, _, err = _run(capsys, "render", "cube", "-o", str(tmp_path / "x.png"), "--distribution", "nope")
    assert code == 2
    line = _error_line(err)
    assert "nope" in line and "logistic" in line
    for name in gendr.DISTRIBUTIONS:
        assert name in line
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("argv, needle", [
    (["render", "no_such_scene", "-o", "x.png"], "no_such_scene"),
    (["render", "cube", "-o", "x.png", "--tconorm", "yagr"], "yager"),
    (["render", "cube", "-o", "x.png", "--tconorm", "yager", "--tconorm-param", "p"], "NAME=VALUE"),
    (["render", "cube", "-o", "x.png", "--tconorm", "yager", "--tconorm-param", "p=-1"], "p"),
    (["render", "cube", "-o", "x.png", "--dist-param", "shape=0.5"], "shape"),
    (["render", "cube", "-o", "x.png", "--tau", "-1"], "tau"),
    (["render", "cube", "-o", "x.png", "--instance", "3", "--distribution", "logistic"], "--instance"),
    (["render", "cube", "-o", "x.png", "--backend", "nonexistent"], "torch"),
    (["demo", "-o", "d", "--scenes", "cube,nope"], "nope"),
])
def test_gendr_errors_are_one_line_exit_2(tmp_path, capsys, monkeypatch, argv, needle):
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(capsys, *argv)
    assert code == 2
    assert needle in _error_line(err)


def test_missing_mesh_file(tmp_path, capsys):
    code, _, err = _run(capsys, "render", str(tmp_path / "missing.obj"), "-o", str(tmp_path / "x.png"))
    assert code == 2 and "missing.obj" in _error_line(err)


def test_render_instance(tmp_path, capsys):
    grid = gendr.paper_grid()
    k = next(i for i, inst in enumerate(grid) if inst.tconorm.name == "probabilistic")
    out = tmp_path / "inst.png"
    code, stdout, err = _run(capsys, "render", "cube", "-o", str(out), "--size", "16", "--instance", str(k))
    assert code == 0, err
    assert grid[k].name in stdout
    assert read_png(out).shape == (16, 16, 4)
    code, _, err = _run(capsys, "render", "cube", "-o", str(out), "--instance", str(len(grid)))
    assert code == 2 and "out of range" in _error_line(err)


def test_demo(tmp_path, capsys):
    out = tmp_path / "demo"
    code, stdout, err = _run(capsys, "demo", "-o", str(out), "--size", "32")
    assert code == 0, err
    png, js = out / "contact_sheet.png", out / "contact_sheet.json"
    assert str(png) in stdout and str(js) in stdout and " s" in stdout
    sheet = read_png(png)
    summary = json.loads(js.read_text())
    assert [r["scene"] for r in summary["rows"]] == list(SCENES)
    assert len(summary["columns"]) == len(DEMO_INSTANCES) == 6
    pad = summary["pad"]
    assert sheet.shape == (pad + len(SCENES) * (32 + pad), pad + 6 * (32 + pad), 4)
    assert summary["sheet_size"] == list(sheet.shape[:2])
    labels = [c["label"] for c in summary["columns"]]
    assert any("softras" in l for l in labels) and any("heaviside" in l for l in labels)
    for r, row in enumerate(summary["cells"]):
        for c, cell in enumerate(row):
            assert (cell["row"], cell["column"], cell["scene"]) == (r, c, summary["rows"][r]["scene"])
            tile = sheet[cell["y"]:cell["y"] + cell["height"], cell["x"]:cell["x"] + cell["width"]]
            assert tile.shape == (32, 32, 4) and tile[..., 3].min() == 255  # composited: opaque
            assert cell["alpha_mean"] > 0, cell  # every scene is visible with every instance


def test_console_process_errors_have_no_traceback(tmp_path):
    res = subprocess.run([sys.executable, "-m", "gendr.cli", "render", "nope", "-o", str(tmp_path / "x.png")],
                         capture_output=True, text=True)
    assert res.returncode == 2
    assert res.stderr.startswith("gendr: error: ") and "Traceback" not in res.stderr


@pytest.mark.parametrize("name,words", [("x.jpg", "writes PNG files"), ("", "is a directory")])
def test_render_output_must_be_a_png_file(tmp_path, capsys, name, words):
    """(a .jpg name got PNG bytes; a directory failed after the render naming a temporary file)"""
    out = tmp_path / name
    code, _, err = _run(capsys, "render", "icosphere", "--size", "8", "-o", str(out))
    assert code == 2 and words in err and str(out) in err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv", [["render", "icosphere", "--size", "8", "-o", "{f}/sub/x.png"],
                                  ["demo", "--size", "8", "-o", "{f}/sheet"], ["gallery", "--size", "8", "-o", "{f}"],
                                  ["validate", "--quick", "-o", "{f}/report"]])
def test_an_unwritable_output_folder_fails_before_any_work(tmp_path, capsys, argv):
    """A file where a folder of -o should be: exit 1 with a raw '[Errno 17] File exists' after the
    whole render (91 s for a 512² render), or after the demo's; now exit 2 before any work."""
    f = tmp_path / "afile"
    f.write_text("keep me")
    argv = [a.replace("{f}", str(f)) for a in argv]
    code, _, err = _run(capsys, *argv)
    assert code == 2 and "'afile' exists and is not a directory" in err.replace(str(tmp_path) + "/", ""), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"] and f.read_text() == "keep me"


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc (a folder nobody can write into)")
def test_a_folder_nobody_may_write_into_fails_before_any_work(capsys):
    """os.access says yes to root everywhere: as root, -o /proc/x.png rendered, then exited 1."""
    code, _, err = _run(capsys, "render", "icosphere", "--size", "8", "-o", "/proc/gendr-test/x.png")
    assert code == 2 and "the directory '/proc' is not writable" in err, err


@pytest.mark.parametrize("device,words", [("gpu", "is not a torch device"), ("cuda", "CUDA")])
def test_render_with_a_device_torch_cannot_use(tmp_path, capsys, device, words):
    import torch
    if device == "cuda" and torch.cuda.is_available():
        pytest.skip("this machine has CUDA: the device is usable")
    code, _, err = _run(capsys, "render", "icosphere", "--size", "8", "--device", device, "-o", str(tmp_path / "a.png"))
    assert code == 2 and words in err and "Traceback" not in err


def test_list_scenes_shows_first_sentences_not_doctests(capsys):
    """(the tetrahedron's line ran into its >>> example, the torus's into its second sentence)"""
    code, out, _ = _run(capsys, "list", "scenes")
    assert code == 0 and ">>>" not in out
    torus = next(line for line in out.splitlines() if line.strip().startswith("torus"))
    assert torus.rstrip().endswith("tube radius r")


def test_demo_with_an_empty_scene_list_is_an_error(tmp_path, capsys):
    """(--scenes "$EMPTY" rendered every scene: 209 s)"""
    code, _, err = _run(capsys, "demo", "--size", "8", "--scenes", " , ", "-o", str(tmp_path / "d"))
    assert code == 2 and "names no scene" in err
    assert not (tmp_path / "d").exists()


def test_render_at_a_pole_names_the_elevation_option(tmp_path, capsys):
    """(the camera's message told the user to choose an up vector, which the CLI has no option for)"""
    code, _, err = _run(capsys, "render", "icosphere", "--size", "8", "--elevation", "90", "-o", str(tmp_path / "a.png"))
    assert code == 2 and "--elevation 90: must lie strictly between -90 and 90" in err and "up vector" not in err


@pytest.mark.parametrize("argv,words", [(["--camera", "orthographic", "--fov", "10"], "--fov 10 is for --camera perspective"),
                                        (["--ortho-scale", "2"], "--ortho-scale 2 is for --camera orthographic")])
def test_an_option_of_the_other_camera_is_an_error(tmp_path, capsys, argv, words):
    """(each was ignored silently: exit 0 with another view than asked for)"""
    code, _, err = _run(capsys, "render", "icosphere", "--size", "8", *argv, "-o", str(tmp_path / "a.png"))
    assert code == 2 and words in err
    assert not (tmp_path / "a.png").exists()


# ------------------------------------------------------------------------------------------------
# gendr render: every option reaches the image
# ------------------------------------------------------------------------------------------------
#: the documented defaults of `gendr render` (its --help), restated here and not read from gendr.cli
CLI_DEFAULTS = dict(azimuth=30.0, elevation=20.0, distance=3.0, fov=40.0, ortho_scale=1.1)
#: (argv beyond `gendr render tetrahedron -o X --size 32 --tau 0.05`, what the image must then be:
#: Renderer keywords, camera keywords, vertex colour mode). τ = 0.05 (0.8 px at H = 32) so that the
#: coverage options (--shift, --eps, --reversed) move the soft edges by far more than 1/255.
CLI_CASES = {
    "defaults": ([], {}, {}, "white"),
    "orthographic": (["--camera", "orthographic"], {}, dict(camera="orthographic"), "white"),
    "orthographic-scale-nonsquare": (["--camera", "orthographic", "--ortho-scale", "0.8", "--size", "24x32"],
                                     dict(image_size=(24, 32)), dict(camera="orthographic", ortho_scale=0.8), "white"),
    "view": (["--azimuth", "-70", "--elevation", "35", "--distance", "2.5", "--fov", "55"], {},
             dict(azimuth=-70.0, elevation=35.0, distance=2.5, fov=55.0), "white"),
    "squared": (["--squared", "--tau", "0.003"], dict(distribution=dict(name="logistic", squared=True), tau=0.003),
                {}, "white"),
    "reversed": (["--distribution", "gumbel_max", "--reversed"],
                 dict(distribution=dict(name="gumbel_max", reversed=True)), {}, "white"),
    "shift": (["--shift", "1.5"], dict(distribution=dict(name="logistic", shift=1.5)), {}, "white"),
    "eps": (["--eps", "0.3"], dict(eps=0.3), {}, "white"),
    "tconorm": (["--tconorm", "yager", "--tconorm-param", "p=0.5"], dict(tconorm=dict(name="yager", p=0.5)), {},
                "white"),
    "colors-position": (["--colors", "position"], {}, {}, "position"),
    "colors-normals": (["--colors", "normals"], {}, {}, "normals"),
    "blend-hard": (["--blend", "hard", "--colors", "position"], dict(blend="hard"), {}, "position"),
    "blend-none": (["--blend", "none"], dict(blend=None), {}, "white"),
}


def _expected_cli_image(renderer_kw, camera_kw, colors):
    """The image `gendr render tetrahedron` should write, rendered directly through the Python API
    (float32, torch, as the command's --dtype and --backend defaults), with the camera built from
    the documented meaning of the options, not by gendr.cli's helpers: the eye on the orbit
    (distance·(cos e·sin a, sin e, cos e·cos a), looking at the origin), a vertical fov of --fov,
    or an orthographic view of half height --ortho-scale and half width --ortho-scale·W/H."""
    kw = dict(distribution=dict(name="logistic"), tconorm=dict(name="probabilistic"), tau=0.05,
              image_size=(32, 32), eps=1e-4, blend="softmax")
    kw.update(renderer_kw)
    dist, tcn = dict(kw.pop("distribution")), dict(kw.pop("tconorm"))
    r = gendr.Renderer(gendr.distribution(dist.pop("name"), **dist), gendr.tconorm(tcn.pop("name"), **tcn),
                       backend="torch", **kw)
    c = {**CLI_DEFAULTS, "camera": "perspective", **camera_kw}
    a, e = np.radians(c["azimuth"]), np.radians(c["elevation"])
    eye = c["distance"] * np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])
    H, W = kw["image_size"]
    if c["camera"] == "orthographic":
        cam = gendr.OrthographicCamera(eye=eye, ymag=c["ortho_scale"], xmag=c["ortho_scale"] * W / H)
    else:
        cam = gendr.PerspectiveCamera(eye=eye, fov_y=c["fov"])
    mesh = gendr.scenes.get_scene("tetrahedron")
    v, f = mesh.vertices, mesh.faces
    if colors == "white":
        vc = None
    elif colors == "position":  # the position in the bounding box, per axis
        vc = (v - v.min(0)) / (v.max(0) - v.min(0))
    else:  # 0.5 + 0.5·(unit area-weighted vertex normal), summed here from the faces' cross products
        fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        vn = np.zeros_like(v)
        for k in range(3):
            np.add.at(vn, f[:, k], fn)
        vc = 0.5 + 0.5 * vn / np.linalg.norm(vn, axis=1, keepdims=True)
    img = r.render(v.astype(np.float32), f, cam, vertex_colors=None if vc is None else vc.astype(np.float32))
    return np.asarray(r.to_numpy(img), dtype=np.float64)[0]


@pytest.mark.parametrize("case", list(CLI_CASES))
def test_render_options_reach_the_image(tmp_path, capsys, case):
    """`gendr render` with one non-default option writes the image the Python API renders with
    that setting. Catches an option the command parses but does not pass on (ignoring --camera
    orthographic, --ortho-scale, --squared, --reversed, --shift, --eps, --colors, --tconorm-param,
    the view options, or a --blend replaced by the default softmax): _alpha_checks-style tests only
    see that *some* image was written.

    Tolerance: the PNG holds 8-bit values, so it is round(255·value) (to_uint8): at most 0.5/255
    from the rendered value; the direct render differs from the command's only by float32 rounding
    (~1e-6: the camera is built here from an eye position, the command's from an Orbit), which can
    push a value across a rounding boundary, so each channel may differ by one 8-bit step, 1/255.
    Each option changes the image by far more than that (asserted against the all-defaults image,
    so that the comparison cannot pass for an option that has no visible effect in this scene)."""
    argv, renderer_kw, camera_kw, colors = CLI_CASES[case]
    out = tmp_path / "x.png"
    code, _, err = _run(capsys, "render", "tetrahedron", "-o", str(out), "--size", "32", "--tau", "0.05", *argv)
    assert code == 0, err
    got = read_png(out).astype(np.float64) / 255.0
    want = _expected_cli_image(renderer_kw, camera_kw, colors)
    assert got.shape == want.shape
    assert want[..., 3].max() > 0.99 and want[..., 3].min() < 0.01  # the mesh is in view, not filling it
    diff = np.abs(got - np.clip(want, 0.0, 1.0)).max()
    assert diff <= 1.0 / 255.0 + 1e-9, f"gendr render {' '.join(argv)}: the PNG differs from the API's image by {diff * 255:.1f}/255"
    if case != "defaults":
        base = _expected_cli_image({}, {}, "white")
        if base.shape == want.shape:
            assert np.abs(base - want).max() > 10.0 / 255.0, f"{argv} does not change this image: the case tests nothing"
