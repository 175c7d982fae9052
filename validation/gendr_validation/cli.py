"""``gendr validate`` and ``gendr gallery``: plug-in commands of the ``gendr.commands`` entry-point
group (pyproject.toml). Each ``main`` takes the arguments after the command name."""
from __future__ import annotations

import argparse

from gendr.cli import writable_dir


def _csv(v):
    return [s.strip() for s in v.split(",") if s.strip()] if v else None


def _import(name: str, command: str):
    """``gendr_validation.<name>``, or a one-line error naming the extra to install."""
    import importlib
    try:
        return importlib.import_module(f"{__package__}.{name}")
    except ImportError as e:
        from gendr.errors import BackendUnavailableError
        raise BackendUnavailableError(f"gendr {command} needs the validation extra "
                                      f"(pip install gendr[validation]): {e}") from e


def _parse(parser: argparse.ArgumentParser, argv):
    """(namespace, None), or (None, exit status) for --help and usage errors."""
    try:
        return parser.parse_args(argv), None
    except SystemExit as e:
        return None, e.code if isinstance(e.code, int) else (0 if e.code is None else 2)


def validate_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="gendr validate", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run the validation (docs/validation.md): gendr's hard-limit silhouettes vs pyrender and "
                    "Mitsuba 3 pixel by pixel, and AD gradients vs float64 central finite differences. Writes "
                    "OUTDIR/report.html (self-contained) and OUTDIR/summary.json; exit status 1 if a check fails.",
        epilog="examples:\n"
               "  gendr validate --quick -o validation_report      # < 2 minutes (the first run on a machine ~6: Dr.Jit compiles)\n"
               "  gendr validate --full -o full_report --instances all --jobs 2\n"
               "  gendr validate --instances 0,271 --scenes cube,torus --backends torch -o r")
    p.add_argument("-o", "--output", default="validation_report", metavar="OUTDIR", help="directory to write into (default: %(default)s)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="48x64, 7 scenes, 4 cameras, 7 limit instances, 13 gradient instances, textures, G-buffers (default)")
    mode.add_argument("--full", action="store_true", help="96x128, every scene and camera, all 47 limit instances, all gradient instances")
    p.add_argument("--backends", default=None, metavar="A,B", help="backends to check (default: every one that imports)")
    p.add_argument("--instances", default=None, metavar="SPEC",
                   help="gradient-check instances of the paper grid: comma-separated indices, 'all' or 'quick'")
    p.add_argument("--scenes", default=None, metavar="A,B", help="built-in scenes for the hard-limit check")
    p.add_argument("--mesh", action="append", default=None, metavar="FILE", help="also check a mesh file (repeatable)")
    p.add_argument("--references", default=None, metavar="A,B",
                   help="pyrender-osmesa, pyrender-egl, mitsuba-scalar_rgb, mitsuba-llvm_ad_rgb (default: pyrender-osmesa,mitsuba-scalar_rgb)")
    p.add_argument("--progress", action="store_true", help="show progress bars even when stderr is not a terminal")
    p.add_argument("--jobs", type=int, default=1, metavar="N",  # report.run checks it is >= 1
                   help="run the gradient checks in N single-threaded worker processes (default: %(default)s)")
    return p


def validate_main(argv=None) -> int:
    """Check hard-limit silhouettes against pyrender/Mitsuba and gradients against finite differences."""
    args, code = _parse(validate_parser(), argv)
    if args is None:
        return code
    report = _import("report", "validate")
    writable_dir(args.output)
    quick = not args.full
    instances = args.instances or ("quick" if quick else "all")
    if instances not in ("quick", "all"):
        instances = _csv(instances)
    summary = report.run(backends=_csv(args.backends), instances=instances, scenes=_csv(args.scenes), quick=quick,
                         outdir=args.output, references=_csv(args.references), mesh_files=args.mesh or (),
                         progress=True if args.progress else None, jobs=args.jobs)
    print(f"report: {args.output}/report.html  summary: {args.output}/summary.json")
    return 0 if summary["passed"] else 1


def gallery_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="gendr gallery", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Write PNG figures for the docs: every distribution's CDF and density, a rendered triangle per "
                    "distribution, T-conorm surfaces and renders across tau.",
        epilog="examples:\n  gendr gallery -o docs/gallery")
    p.add_argument("-o", "--output", default="docs/gallery", metavar="OUTDIR", help="directory (default: %(default)s)")
    p.add_argument("--size", type=int, default=64, help="render size in pixels (default: %(default)s)")
    return p


def gallery_main(argv=None) -> int:
    """Regenerate the documentation figures (distributions, T-conorms, renders across tau)."""
    args, code = _parse(gallery_parser(), argv)
    if args is None:
        return code
    gallery = _import("gallery", "gallery")
    writable_dir(args.output)
    files = gallery.generate(args.output, size=args.size)
    total = sum(f[1] for f in files)
    print(f"wrote {len(files)} figures ({total / 1e6:.2f} MB) to {args.output}")
    return 0
