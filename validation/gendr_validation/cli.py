"""The ``gendr validate`` and ``gendr gallery`` commands (gendr/cli.py imports this lazily)."""
from __future__ import annotations

import sys


def _csv(v):
    return [s.strip() for s in v.split(",") if s.strip()] if v else None


def validate_main(args) -> int:
    from . import report
    quick = not args.full
    instances = args.instances or ("quick" if quick else "all")
    if instances not in ("quick", "all"):
        instances = _csv(instances)
    summary = report.run(backends=_csv(args.backends), instances=instances, scenes=_csv(args.scenes), quick=quick,
                         outdir=args.output, references=_csv(args.references), mesh_files=args.mesh or (),
                         progress=True if args.progress else None, jobs=args.jobs)
    print(f"report: {args.output}/report.html  summary: {args.output}/summary.json")
    return 0 if summary["passed"] else 1


def gallery_main(args) -> int:
    from . import gallery
    files = gallery.generate(args.output, size=args.size)
    total = sum(f[1] for f in files)
    print(f"wrote {len(files)} figures ({total / 1e6:.2f} MB) to {args.output}")
    return 0
