"""The ``gendr`` command line: render a mesh, run the demo, list what exists.

    gendr render teapot_like -o teapot.png
    gendr render model.obj -o out.png --distribution gamma --dist-param shape=0.5 --reversed --tconorm yager --tconorm-param p=2
    gendr demo -o demo_out
    gendr list distributions

Errors raised on purpose by gendr (:class:`gendr.errors.GendrError`) are printed as one line
``gendr: error: ...`` with exit status 2, without a traceback. Only the spec layer is imported at
start-up; the array backend (torch) is imported when something is rendered.

Other packages add sub-commands through the ``gendr.commands`` entry-point group (this distribution
registers ``validate`` and ``gallery`` from gendr_validation and ``experiment`` from
gendr_experiments): see :func:`plugin_commands`. gendr imports a plug-in only to run it.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import tempfile
import time
from importlib import metadata
from pathlib import Path

import numpy as np

from .errors import GendrError, InputValueError, ParameterError

__all__ = ["main", "build_parser", "plugin_commands", "DEMO_INSTANCES", "COMMAND_GROUP"]

PROG = "gendr"
#: entry-point group of plug-in sub-commands (``gendr validate``, ``gendr experiment``, a third party's)
COMMAND_GROUP = "gendr.commands"
#: commands of gendr itself; a plug-in cannot replace them
BUILTIN_COMMANDS = ("render", "demo", "list")

#: (column label, distribution kwargs, tconorm kwargs, RGB blend) of the columns of ``gendr demo``. The
#: demo's ``--tau`` is used as is for plain distributions and squared (tau**2) for squared ones, so
#: that both blur over the same screen distance.
DEMO_INSTANCES = (
    ("logistic+probabilistic", dict(name="logistic"), dict(name="probabilistic"), "softmax"),
    ("softras: logistic(sq)+probabilistic", dict(name="logistic", squared=True), dict(name="probabilistic"), "softmax"),
    ("gaussian+einstein", dict(name="gaussian"), dict(name="einstein"), "softmax"),
    # heavy tails (cauchy, reciprocal, levy rev) reach every pixel from every face: O(H·W·F) pairs,
    # minutes for this sheet on 2 cores, so the demo shows a light-tailed one-sided family instead
    ("gamma(2,rev)+yager(p=2)", dict(name="gamma", shape=2.0, reversed=True), dict(name="yager", p=2.0), "softmax"),
    ("hard: heaviside+or", dict(name="heaviside"), dict(name="or"), "hard"),
    ("exponential(rev)+max", dict(name="exponential", reversed=True), dict(name="max"), "softmax"),
)
#: albedo of every demo scene and the gray the renders are composited over in the contact sheet
DEMO_ALBEDO = (0.95, 0.78, 0.5)
DEMO_BACKGROUND = 0.18

# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------

def _api(name: str):
    """``gendr.<name>``, or a clear error when this build of gendr does not have it."""
    import gendr
    try:
        return getattr(gendr, name)
    except AttributeError:
        raise GendrError(f"this gendr installation has no gendr.{name}() (the public API is incomplete); "
                         f"cannot continue") from None


def _size(text: str) -> tuple[int, int]:
    """``"256"`` -> (256, 256); ``"120x160"`` -> (H=120, W=160)."""
    parts = text.lower().replace("×", "x").split("x")
    try:
        if len(parts) == 1:
            h = w = int(parts[0])
        elif len(parts) == 2:
            h, w = int(parts[0]), int(parts[1])
        else:
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected N or HxW (e.g. 256 or 120x160), got {text!r}") from None
    if h < 1 or w < 1 or h > 16384 or w > 16384:
        raise argparse.ArgumentTypeError(f"image size must be between 1 and 16384 pixels, got {text!r}")
    return h, w


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        v = 0
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return v


def _key_values(pairs, option: str) -> dict[str, float]:
    """``["shape=0.5", "p=2"]`` -> {"shape": 0.5, "p": 2.0}."""
    out = {}
    for item in pairs or ():
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ParameterError(f"{option} expects NAME=VALUE (e.g. {option} p=2), got {item!r}")
        try:
            out[key] = float(value)
        except ValueError:
            raise ParameterError(f"{option} {key}={value!r}: the value must be a number") from None
    return out


def _resolve_mesh(spec: str, normalize_files: bool = True):
    """A built-in scene name or a mesh file path -> (Mesh, description)."""
    from .scenes import SCENES, get_scene, load_mesh, normalize
    if spec in SCENES:
        return get_scene(spec), f"scene {spec!r}"
    if os.path.exists(spec) or os.sep in spec or (os.altsep and os.altsep in spec) or os.path.splitext(spec)[1]:
        mesh = load_mesh(spec)  # a clear error naming the path when it does not exist
        return (normalize(mesh) if normalize_files else mesh), f"file {spec!r}"
    raise InputValueError(f"{spec!r} is neither a built-in scene ({', '.join(sorted(SCENES))}) nor an "
                          f"existing mesh file")


def _vertex_colors(mesh, mode: str):
    if mode == "white":
        return None
    if mode == "normals":
        return 0.5 + 0.5 * mesh.vertex_normals()
    if mode == "position":
        v = mesh.vertices
        lo, hi = v.min(axis=0), v.max(axis=0)
        return (v - lo) / np.where(hi > lo, hi - lo, 1.0)
    raise ParameterError(f"unknown colour mode {mode!r}")


DEFAULT_FOV, DEFAULT_ORTHO_SCALE = 40.0, 1.1


def _fov(args):
    return DEFAULT_FOV if args.fov is None else args.fov


def _ortho_scale(args):
    return DEFAULT_ORTHO_SCALE if args.ortho_scale is None else args.ortho_scale


def _camera(args, batch_azimuths=None):
    """An orbit camera from the command-line options (azimuth may be a list of B values)."""
    orbit_camera = _api("orbit_camera")
    az = args.azimuth if batch_azimuths is None else np.asarray(batch_azimuths, dtype=np.float64)
    # (each was ignored silently by the other camera)
    if args.camera == "orthographic" and args.fov is not None:
        raise ParameterError(f"--fov {args.fov:g} is for --camera perspective; the orthographic camera's "
                             f"view size is --ortho-scale")
    if args.camera == "perspective" and args.ortho_scale is not None:
        raise ParameterError(f"--ortho-scale {args.ortho_scale:g} is for --camera orthographic; the perspective "
                             f"camera's view size is --fov")
    if not abs(args.elevation) < 90.0:  # (the camera's message suggests an up vector: no option here)
        raise ParameterError(f"--elevation {args.elevation:g}: must lie strictly between -90 and 90 (at ±90 "
                             f"the view is along the up axis +Y and the camera's roll is undefined)")
    h, w = args.size
    if args.camera == "orthographic":
        ymag = _ortho_scale(args)
        return orbit_camera(az, args.elevation, args.distance, orthographic=True, ymag=ymag, xmag=ymag * w / h)
    return orbit_camera(az, args.elevation, args.distance, fov_y=_fov(args))


def _finish_image(img) -> np.ndarray:
    return np.asarray(img, dtype=np.float64)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


# ------------------------------------------------------------------------------------------------
# render
# ------------------------------------------------------------------------------------------------

def _render_specs(args):
    """(distribution, tconorm, label) from --instance or --distribution/--tconorm options."""
    if args.instance is not None:
        given = [opt for opt, v in (("--distribution", args.distribution), ("--tconorm", args.tconorm),
                                    ("--dist-param", args.dist_param), ("--tconorm-param", args.tconorm_param),
                                    ("--shift", args.shift)) if v]
        given += [opt for opt, v in (("--reversed", args.reversed), ("--squared", args.squared)) if v]
        if given:
            raise ParameterError(f"--instance picks the distribution and T-conorm; do not combine it with "
                                 f"{', '.join(given)}")
        grid = _api("paper_grid")()
        k = args.instance
        if not 0 <= k < len(grid):
            raise ParameterError(f"--instance {k} is out of range: the paper grid has instances 0..{len(grid) - 1} "
                                 f"(see `gendr list grid`)")
        inst = grid[k]
        return inst.distribution, inst.tconorm, f"instance {k} {inst.name}"
    distribution, tconorm = _api("distribution"), _api("tconorm")
    dist = distribution(args.distribution or "logistic", reversed=args.reversed, squared=args.squared,
                        shift=args.shift or 0.0, **_key_values(args.dist_param, "--dist-param"))
    tcn = tconorm(args.tconorm or "probabilistic", **_key_values(args.tconorm_param, "--tconorm-param"))
    return dist, tcn, f"{dist.label()}|{tcn.label()}"


def writable_dir(output, given=None, option: str = "-o") -> Path:
    """An output folder, checked before any work (a file in its path, or a folder we may not write
    into, failed only when the results were written): it exists as a writable directory, or its
    nearest existing ancestor is one (the folders are made later, when there is something to write).
    ``given``: the path the user named, for the message (default ``output``); ``option``: the
    option that named it (``gendr experiment``'s ``--csv``, ``--json``)."""
    path, given = Path(output), str(output if given is None else given)
    probe = path
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    if not probe.is_dir():
        raise ParameterError(f"{option} {given!r}: {str(probe)!r} exists and is not a directory")
    try:  # a real write: os.access says yes to root on read-only mounts and /proc
        tempfile.TemporaryFile(dir=probe).close()
    except OSError as e:
        raise ParameterError(f"{option} {given!r}: the directory {str(probe)!r} is not writable ({e.strerror})") from None
    return path


def _png_output(output: str) -> Path:
    """The -o path of a PNG to write, checked before any work: a .png name, not a directory, in a
    folder that can be made and written."""
    path = Path(output)
    if path.is_dir():
        raise ParameterError(f"-o {output!r} is a directory; name the PNG file to write (e.g. {output}/render.png)")
    if path.suffix.lower() != ".png":
        raise ParameterError(f"-o {output!r}: gendr render writes PNG files; give a name ending in .png")
    writable_dir(path.parent, given=output)
    return path


def cmd_render(args) -> int:
    from .images import contact_sheet, require_pillow, write_png
    require_pillow("gendr render")  # before rendering, not after
    path = _png_output(args.output)
    dist, tcn, label = _render_specs(args)
    mesh, what = _resolve_mesh(args.mesh, normalize_files=not args.no_normalize)
    tau = args.tau if args.tau is not None else (1e-4 if dist.squared else 0.01)
    Renderer = _api("Renderer")
    options = {} if args.device is None else {"device": args.device}
    renderer = Renderer(distribution=dist, tconorm=tcn, tau=tau, image_size=args.size,
                        backend=args.backend, eps=args.eps, blend=None if args.blend == "none" else args.blend,
                        **options)
    dtype = np.float64 if args.dtype == "float64" else np.float32
    colors = _vertex_colors(mesh, args.colors)
    n = args.batch_views
    azimuths = None if n is None else [args.azimuth + 360.0 * k / n for k in range(n)]
    camera = _camera(args, azimuths)
    t0 = time.perf_counter()
    img = renderer.render(mesh.vertices.astype(dtype), mesh.faces, camera,
                          vertex_colors=None if colors is None else colors.astype(dtype))
    images = _finish_image(renderer.to_numpy(img))
    seconds = time.perf_counter() - t0
    if n is None:
        out = images[0]
    else:
        columns = n if n <= 6 else math.ceil(math.sqrt(n))
        out = contact_sheet(list(images), columns=columns, pad=2, background=(0.0, 0.0, 0.0, 0.0))
    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, out)
    views = "" if n is None else f", {n} views"
    print(f"gendr: wrote {path} ({out.shape[0]}x{out.shape[1]} RGBA{views}; {what}, {mesh.num_faces} faces; "
          f"{label}, tau={tau:g}; {seconds:.2f} s)")
    return 0


# ------------------------------------------------------------------------------------------------
# demo
# ------------------------------------------------------------------------------------------------

def _composite(img: np.ndarray, background: float) -> np.ndarray:
    """RGBA render -> opaque RGBA over a gray background (alpha-weighted), for the contact sheet."""
    a = np.clip(img[..., 3:4], 0.0, 1.0)
    rgb = a * np.clip(img[..., :3], 0.0, 1.0) + (1.0 - a) * background
    return np.concatenate([rgb, np.ones_like(a)], axis=-1)


def cmd_demo(args) -> int:
    from .images import contact_sheet, require_pillow, write_png
    from .scenes import SCENES, get_scene
    require_pillow("gendr demo")
    writable_dir(args.output)
    distribution, tconorm, Renderer = _api("distribution"), _api("tconorm"), _api("Renderer")
    scenes = list(SCENES) if args.scenes is None else [s.strip() for s in args.scenes.split(",") if s.strip()]
    if not scenes:  # (--scenes "$EMPTY" rendered every scene)
        raise ParameterError(f"--scenes {args.scenes!r} names no scene; leave it out for all of them")
    meshes = [get_scene(s) for s in scenes]  # validates names before any rendering
    h, w = args.size
    tau = args.tau
    options = {} if args.device is None else {"device": args.device}
    columns, renderers = [], []
    for label, dkw, tkw, blend in DEMO_INSTANCES:
        dkw, tkw = dict(dkw), dict(tkw)
        dist = distribution(dkw.pop("name"), **dkw)
        tcn = tconorm(tkw.pop("name"), **tkw)
        t = tau * tau if dist.squared else tau
        renderers.append(Renderer(distribution=dist, tconorm=tcn, tau=t, image_size=(h, w), backend=args.backend,
                                  eps=args.eps, blend=blend, **options))
        columns.append({"label": label, "distribution": dist.label(), "tconorm": tcn.label(), "tau": t,
                        "blend": blend})
    camera = _camera(args)
    t_start = time.perf_counter()
    images, cells = [], []
    for r, (name, mesh) in enumerate(zip(scenes, meshes)):
        verts = mesh.vertices.astype(np.float32)
        albedo = np.tile(np.asarray(DEMO_ALBEDO, dtype=np.float32), (len(verts), 1))
        row = []
        for c, renderer in enumerate(renderers):
            t0 = time.perf_counter()
            img = _finish_image(renderer.to_numpy(renderer.render(verts, mesh.faces, camera, vertex_colors=albedo)))[0]
            dt = time.perf_counter() - t0
            images.append(_composite(img, DEMO_BACKGROUND))
            row.append({"row": r, "column": c, "scene": name, "instance": columns[c]["label"],
                        "x": args.pad + c * (w + args.pad), "y": args.pad + r * (h + args.pad),
                        "width": w, "height": h, "seconds": round(dt, 4),
                        "alpha_mean": round(float(img[..., 3].mean()), 6)})
        cells.append(row)
        if args.verbose:
            print(f"  {name}: {sum(x['seconds'] for x in row):.2f} s", flush=True)
    sheet = contact_sheet(images, columns=len(renderers), pad=args.pad, background=(1.0, 1.0, 1.0, 1.0))
    elapsed = time.perf_counter() - t_start
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    png_path, json_path = out / "contact_sheet.png", out / "contact_sheet.json"
    write_png(png_path, sheet)
    summary = {
        "image": png_path.name,
        "sheet_size": [int(sheet.shape[0]), int(sheet.shape[1])],
        "cell_size": [h, w],
        "pad": args.pad,
        "layout": "rows are scenes, columns are instances; cell (r, c) has its top-left pixel at "
                  "(y, x) = (pad + r*(height+pad), pad + c*(width+pad))",
        "rows": [{"row": r, "scene": s, "vertices": m.num_vertices, "faces": m.num_faces}
                 for r, (s, m) in enumerate(zip(scenes, meshes))],
        "columns": [dict(column=c, **col) for c, col in enumerate(columns)],
        "cells": cells,
        "camera": {"kind": args.camera, "azimuth": args.azimuth, "elevation": args.elevation,
                   "distance": args.distance, **({"fov_y": _fov(args)} if args.camera == "perspective" else
                                                {"ymag": _ortho_scale(args)})},
        "backend": args.backend,
        "eps": args.eps,
        "render_seconds": round(elapsed, 3),
    }
    tmp = json_path.with_name(f".{json_path.name}.tmp")
    tmp.write_text(json.dumps(summary, indent=2) + "\n")
    os.replace(tmp, json_path)
    print(f"gendr: wrote {png_path} ({sheet.shape[0]}x{sheet.shape[1]}) and {json_path}: "
          f"{len(scenes)} scenes x {len(renderers)} instances at {h}x{w} in {elapsed:.2f} s")
    return 0


# ------------------------------------------------------------------------------------------------
# list
# ------------------------------------------------------------------------------------------------

def _param_text(params) -> str:
    if not params:
        return "-"
    parts = []
    for p in params:
        s = f"{p.name} ({p.constraint.description}"
        s += f", default {p.default:g}" if p.default is not None else ", required"
        parts.append(s + ")")
    return ", ".join(parts)


def _first_sentence(doc: str, limit: int = 110) -> str:
    doc = (doc or "").split(">>>")[0]  # (not the examples)
    doc = " ".join(doc.replace("``", "").split())
    text = re.split(r"\.\s+(?=[A-Z0-9])", doc)[0].rstrip(".") if doc else ""
    return text if len(text) <= limit else text[:limit - 3].rstrip() + "..."


def cmd_list(args) -> int:
    what = args.what
    if what == "distributions":
        reg = _api("DISTRIBUTIONS")
        print("distributions (options for each: --reversed, --squared, --shift S):")
        for name, fam in reg.items():
            tails = "/".join(fam.tails)
            print(f"  {name:18s} params: {_param_text(fam.params)}; tails {tails}"
                  + (f"; {_first_sentence(fam.doc)}" if fam.doc else ""))
    elif what == "tconorms":
        reg = _api("TCONORMS")
        print("T-conorms:")
        for name, fam in reg.items():
            if fam.is_tconorm:
                print(f"  {name:16s} params: {_param_text(fam.params)}; {fam.kind}"
                      + (f"; {_first_sentence(fam.doc)}" if fam.doc else ""))
        others = [(name, fam) for name, fam in reg.items() if not fam.is_tconorm]
        if others:
            print("other aggregations (not T-conorms; selected like one with --tconorm NAME, not in the paper grid):")
            for name, fam in others:
                print(f"  {name:16s} params: {_param_text(fam.params)}; {fam.kind}, not a T-conorm"
                      + (f"; {_first_sentence(fam.doc)}" if fam.doc else ""))
    elif what == "scenes":
        from .scenes import SCENES
        print("built-in scenes (use the name in place of a mesh file):")
        for name, fn in SCENES.items():
            m = fn()
            print(f"  {name:16s} {m.num_vertices:6d} vertices {m.num_faces:6d} faces  {_first_sentence(fn.__doc__)}")
    elif what == "grid":
        grid = _api("paper_grid")()
        for k, inst in enumerate(grid):
            print(f"{k:5d}  {inst.name}")
        print(f"# {len(grid)} instances; render one with `gendr render SCENE -o out.png --instance K`",
              file=sys.stderr)
    elif what == "backends":
        backends = _api("available_backends")()
        for name, ep in sorted(backends.items()):
            print(f"  {name:10s} {ep.value}")
    elif what == "commands":
        print(f"built-in: {', '.join(BUILTIN_COMMANDS)}")
        print(f"plug-ins (entry-point group {COMMAND_GROUP}):")
        for name, ep in plugin_commands().items():
            dist = getattr(getattr(ep, "dist", None), "name", None) or "?"
            print(f"  {name:12s} {ep.value}  ({dist}): {plugin_help(ep)}")
    return 0


# ------------------------------------------------------------------------------------------------
# parser
# ------------------------------------------------------------------------------------------------

class _Formatter(argparse.RawDescriptionHelpFormatter):
    pass


def _add_view_options(p, *, size_default: str):
    g = p.add_argument_group("image and camera")
    g.add_argument("--size", type=_size, default=_size(size_default), metavar="N|HxW",
                   help=f"image size in pixels: N for NxN or HxW (default {size_default})")
    g.add_argument("--camera", choices=("perspective", "orthographic"), default="perspective",
                   help="projection; both orbit around the origin looking at it (default: %(default)s)")
    g.add_argument("--azimuth", type=float, default=30.0,
                   help="degrees around +Y; 0 looks from +Z, 90 from +X (default: %(default)s)")
    g.add_argument("--elevation", type=float, default=20.0, help="degrees above the XZ plane (default: %(default)s)")
    g.add_argument("--distance", type=float, default=3.0, help="camera distance from the origin (default: %(default)s)")
    g.add_argument("--fov", type=float, default=None,
                   help=f"vertical field of view in degrees, perspective only (default {DEFAULT_FOV:g})")
    g.add_argument("--ortho-scale", type=float, default=None, metavar="YMAG",
                   help=f"orthographic half height of the view in world units (default {DEFAULT_ORTHO_SCALE:g})")
    g = p.add_argument_group("backend")
    g.add_argument("--backend", default="torch", help="array backend, see `gendr list backends` (default: %(default)s)")
    g.add_argument("--device", default=None, help="backend device, e.g. cuda (default: the backend's)")
    g.add_argument("--eps", type=float, default=1e-4,
                   help="coverage below eps is culled; 0 = exact dense rendering (default: %(default)s)")


def build_parser(describe_plugins: bool = True) -> argparse.ArgumentParser:
    """The ``gendr`` parser. ``describe_plugins=False`` leaves the plug-in commands' help lines
    empty (reading them from the plug-ins' sources costs tens of ms that only ``--help`` needs)."""
    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="gendr - a generalized differentiable mesh renderer (GenDR, Petersen et al., CVPR 2022).\n"
                    "Soft coverage p = F(d/tau) of a chosen distribution F, aggregated over faces by a "
                    "chosen T-conorm.",
        epilog="examples:\n"
               "  gendr list scenes                       # what can be rendered without a file\n"
               "  gendr render teapot_like -o teapot.png  # logistic + probabilistic, 256x256\n"
               "  gendr render model.obj -o soft.png --distribution gamma --dist-param shape=0.5 --reversed\n"
               "  gendr render chair -o sheet.png --batch-views 8 --size 128\n"
               "  gendr demo -o demo_out                  # every scene x six renderers in one contact sheet\n"
               "\nrun `gendr COMMAND --help` for the options of each command. Commands after `list` are\n"
               f"plug-ins (entry-point group {COMMAND_GROUP}; `gendr list commands`).")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    # render ------------------------------------------------------------------------------------
    p = sub.add_parser(
        "render", formatter_class=_Formatter,
        help="render a built-in scene or a mesh file to an RGBA PNG",
        description="Render MESH_OR_SCENE with one distribution and T-conorm to an RGBA PNG (alpha = the "
                    "soft silhouette, RGB = Lambert-shaded colour).",
        epilog="examples:\n"
               "  gendr render icosphere -o sphere.png\n"
               "  gendr render torus -o softras.png --distribution logistic --squared --tau 1e-4\n"
               "  gendr render airplane -o a.png --distribution cauchy --tconorm yager --tconorm-param p=2\n"
               "  gendr render bunny.ply -o b.png --size 480x640 --camera orthographic --azimuth 90\n"
               "  gendr render chair -o c.png --instance 17   # instance 17 of `gendr list grid`\n"
               "\nmesh files (OBJ, PLY, STL, OFF, GLB, ...) are read with trimesh and scaled into the unit\n"
               "ball unless --no-normalize is given; built-in scenes already fit it.")
    p.add_argument("mesh", metavar="MESH_OR_SCENE",
                   help="a built-in scene name (`gendr list scenes`) or a mesh file path")
    p.add_argument("-o", "--output", required=True, metavar="OUT.png", help="PNG file to write")
    g = p.add_argument_group("renderer (see `gendr list distributions` / `gendr list tconorms`)")
    g.add_argument("--distribution", default=None, metavar="NAME",
                   help="distribution whose CDF gives soft coverage (default logistic)")
    g.add_argument("--dist-param", action="append", default=None, metavar="NAME=VALUE",
                   help="distribution parameter, repeatable (e.g. shape=0.5 for gamma)")
    g.add_argument("--reversed", action="store_true", help="use the reversed distribution 1 - F(-x)")
    g.add_argument("--squared", action="store_true", help="use the squared variant F(d|d|/tau) (SoftRas)")
    g.add_argument("--shift", type=float, default=None, help="shift the distribution: F(x + S) (default 0)")
    g.add_argument("--tconorm", default=None, metavar="NAME",
                   help="T-conorm aggregating the faces (default probabilistic; or 'average', the mean "
                        "over the faces, which is not a T-conorm)")
    g.add_argument("--tconorm-param", action="append", default=None, metavar="NAME=VALUE",
                   help="T-conorm parameter, repeatable (e.g. p=2 for yager)")
    g.add_argument("--instance", type=int, default=None, metavar="K",
                   help="use instance K of the paper's grid (`gendr list grid`) instead of the above")
    g.add_argument("--tau", type=float, default=None,
                   help="scale of the distribution in screen units: 1 unit = H/2 pixels; squared units for "
                        "squared distributions (default: 0.01, or 0.01**2 = 1e-4 for squared ones)")
    g.add_argument("--blend", choices=("softmax", "hard", "none"), default="softmax",
                   help="RGB blend: SoftRas softmax over depth, nearest face (z-buffer), or none: alpha only (default: %(default)s)")
    g.add_argument("--colors", choices=("white", "normals", "position"), default="white",
                   help="vertex albedo: white, the vertex normals or the position in the bounding box (default: %(default)s)")
    g.add_argument("--dtype", choices=("float32", "float64"), default="float32", help="floating point precision (default: %(default)s)")
    g.add_argument("--batch-views", type=_positive_int, default=None, metavar="N",
                   help="render N views at azimuths spaced 360/N degrees apart (from --azimuth) into one sheet")
    g.add_argument("--no-normalize", action="store_true",
                   help="keep a mesh file's coordinates instead of scaling it into the unit ball")
    _add_view_options(p, size_default="256")
    p.set_defaults(func=cmd_render)

    # demo --------------------------------------------------------------------------------------
    p = sub.add_parser(
        "demo", formatter_class=_Formatter,
        help="render every built-in scene with several renderers into a contact sheet",
        description=f"Render every built-in scene (rows) with {len(DEMO_INSTANCES)} instances (columns): "
                    f"{'; '.join(label for label, *_ in DEMO_INSTANCES)}. Writes OUTDIR/contact_sheet.png "
                    "(renders composited over dark gray) and OUTDIR/contact_sheet.json (which scene and "
                    "instance is where, timings).",
        epilog="examples:\n"
               "  gendr demo -o demo_out\n"
               "  gendr demo -o demo_out --size 64 --scenes icosphere,chair --tau 0.03")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="directory to write into (created)")
    p.add_argument("--tau", type=float, default=0.02,
                   help="scale of the distributions in screen units; squared instances use tau**2 (default: %(default)s)")
    p.add_argument("--scenes", default=None, metavar="A,B,...", help="comma-separated scenes (default: all)")
    p.add_argument("--pad", type=int, default=2, help="pixels between cells (default: %(default)s)")
    p.add_argument("-v", "--verbose", action="store_true", help="print the time of each scene")
    _add_view_options(p, size_default="128")
    p.set_defaults(func=cmd_demo)

    # list --------------------------------------------------------------------------------------
    p = sub.add_parser(
        "list", formatter_class=_Formatter,
        help="list distributions, T-conorms, scenes, the paper grid, backends or commands",
        description="Print the names (and parameters) of what can be chosen.",
        epilog="examples:\n  gendr list distributions\n  gendr list grid | grep yager")
    p.add_argument("what", choices=("distributions", "tconorms", "scenes", "grid", "backends", "commands"))
    p.set_defaults(func=cmd_list)

    # plug-in commands (entry-point group gendr.commands), imported only when they run -------
    for name, ep in plugin_commands().items():
        p = sub.add_parser(name, add_help=False, prefix_chars="\0",  # every argument goes to the plug-in
                           help=plugin_help(ep) if describe_plugins else None)
        p.add_argument("plugin_args", nargs=argparse.REMAINDER)
        p.set_defaults(func=_run_plugin, plugin=ep)
    return parser


# ------------------------------------------------------------------------------------------------
# plug-in commands
# ------------------------------------------------------------------------------------------------

def plugin_commands() -> dict[str, metadata.EntryPoint]:
    """Sub-commands other packages register under the ``gendr.commands`` entry-point group.

    Returns name -> entry point, sorted by name. The entry point (``NAME = "module:main"``) names a
    callable ``main(argv: list[str]) -> int`` that parses its own arguments (``gendr NAME ARGS...`` calls
    ``main(ARGS)``). A name that a built-in command already has, or that an earlier registration
    took, is skipped. Nothing is imported here.
    """
    found = {}
    for ep in metadata.entry_points(group=COMMAND_GROUP):
        if ep.name not in BUILTIN_COMMANDS and ep.name not in found:
            found[ep.name] = ep
    return dict(sorted(found.items()))


def plugin_help(ep: metadata.EntryPoint) -> str:
    """One line for ``gendr --help``: the first sentence of the docstring of the entry point's object
    (else of its module), read from the source file without importing the plug-in (importing
    gendr_experiments imports torch: seconds); a generic line where the source cannot be read."""
    module, _, attr = ep.value.partition(":")
    doc = _source_docstring(module.strip(), attr.split("[")[0].strip())
    dist = getattr(getattr(ep, "dist", None), "name", None)
    if not doc:
        return f"a plug-in command{f' from {dist}' if dist else ''}"
    line = _first_sentence(doc)
    return line[:1].lower() + line[1:] if line[1:2].islower() else line  # as argparse's own lines


def _source_file(module: str) -> Path | None:
    """The .py file of ``module``, found without importing it or its parent packages."""
    import importlib.util
    top, *parts = module.split(".")
    try:
        spec = importlib.util.find_spec(top)  # a top-level name is found, not imported
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin:
        return None
    path, dirs = Path(spec.origin), list(spec.submodule_search_locations or ())
    for part in parts:
        for d in dirs:
            if (Path(d) / part / "__init__.py").is_file():
                path, dirs = Path(d) / part / "__init__.py", [Path(d) / part]
                break
            if (Path(d) / f"{part}.py").is_file():
                path, dirs = Path(d) / f"{part}.py", []
                break
        else:
            return None
    return path if path.suffix == ".py" else None


def _source_docstring(module: str, attr: str) -> str | None:
    import ast
    path = _source_file(module)
    if path is None:
        return None
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"))
    except (OSError, SyntaxError, UnicodeDecodeError, ValueError):
        return None
    for node in tree.body:
        if (isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.name == attr
                and ast.get_docstring(node)):
            return ast.get_docstring(node)
    return ast.get_docstring(tree)


def _run_plugin(args) -> int:
    """``gendr NAME ARGS...``: import the plug-in's ``main`` and call ``main(ARGS)``."""
    ep = args.plugin
    try:
        main = ep.load()
    except ImportError as exc:
        dist = getattr(getattr(ep, "dist", None), "name", None) or "its package"
        raise GendrError(f"gendr {ep.name} is registered by {dist} ({ep.value}) but cannot be imported: {exc} "
                         f"(install the optional dependencies of {dist} that it needs)") from exc
    try:
        code = main(list(args.plugin_args))
    except SystemExit as e:  # a plug-in whose argparse exits (--help, usage errors)
        code = e.code if isinstance(e.code, int) or e.code is None else 2
    return 0 if code is None else int(code)


def _version() -> str:
    try:
        from . import __version__
        return __version__
    except ImportError:  # pragma: no cover
        return "unknown"


def main(argv=None) -> int:
    """Run the command line with ``argv`` (default ``sys.argv[1:]``); returns the exit status.

    0 on success, 2 for usage errors and for errors gendr raises on purpose (printed as one line).
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(describe_plugins=not argv or argv[0].startswith("-"))  # `gendr --help`
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, --version, usage errors
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    try:
        return args.func(args)
    except GendrError as e:
        message = _one_line(e)
        print(f"{PROG}: error: {message}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. `gendr list grid | head`: stop quietly, as command-line tools do
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        except (OSError, ValueError, AttributeError):
            pass
        return 141
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except OSError as e:
        print(f"{PROG}: error: {_one_line(e)}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
