"""``gendr validate``: run the hard-limit and gradient checks and write an HTML report + JSON summary.

The HTML page is self-contained (images inline as base64 PNGs, plots from matplotlib). The JSON
summary holds every count and error. The exit status is 0 only when every check passed.
"""
from __future__ import annotations

import base64
import contextlib
import html
import io
import json
import os
import re
import sys
import time
from dataclasses import asdict

import numpy as np
from tqdm import tqdm

import gendr
from gendr import scenes as gscenes

from . import gradcheck, hardlimit, surfaces
from .references import DEFAULT_REFERENCES

QUICK_SCENES = ("icosphere", "cube", "torus", "thin_shape", "teapot_like", "open_mesh", "degenerate_mesh")
QUICK_SIZE = (48, 64)
FULL_SIZE = (96, 128)


def _progress(total: int, label: str, enabled):
    """A tqdm bar on stderr, shown when stderr is a terminal (``enabled`` None) or when forced (True)."""
    return tqdm(total=total, desc=label, unit="check", file=sys.stderr, dynamic_ncols=True,
                disable=None if enabled is None else not enabled)


def _png_b64(img) -> str:
    """A float image in [0, 1] ([H, W] or [H, W, 3|4]) as a base64 PNG (nearest-neighbour upscaled)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    a = np.clip(np.asarray(img, dtype=np.float64), 0, 1)
    scale = max(1, 128 // a.shape[0])
    a = np.repeat(np.repeat(a, scale, 0), scale, 1)
    buf = io.BytesIO()
    plt.imsave(buf, a, cmap="gray" if a.ndim == 2 else None, vmin=0, vmax=1, format="png")
    return base64.b64encode(buf.getvalue()).decode()


def _diff_image(ours, ref, amb):
    """RGB: white = both, red = only ours, blue = only the reference, yellow = differing but ambiguous."""
    out = np.zeros(ours.shape + (3,))
    both = ours & ref
    out[both] = 0.55
    only_o, only_r = ours & ~ref, ref & ~ours
    out[only_o & ~amb] = (1, 0, 0)
    out[only_r & ~amb] = (0, 0.4, 1)
    out[(only_o | only_r) & amb] = (1, 1, 0)
    return out


def _plot_b64(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _grad_plot(grad_results):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.2))
    params = sorted({r.param for r in grad_results})
    for k, p in enumerate(params):
        rs = [r for r in grad_results if r.param == p]
        x = [r.instance for r in rs]
        axes[0].scatter(x, [max(r.pixel_max, 1e-16) for r in rs], s=10, label=p)
        axes[1].scatter(x, [max(r.loss_err, 1e-16) for r in rs], s=10, label=p)
    for ax, title, thr in ((axes[0], "per-pixel max rel. error", gradcheck.THRESHOLDS["pixel_max"]),
                           (axes[1], "scalar-loss rel. error", gradcheck.THRESHOLDS["loss"])):
        ax.set_yscale("log")
        ax.axhline(thr, color="k", ls="--", lw=0.8)
        ax.set_title(title)
        ax.set_xlabel("grid instance")
    axes[0].legend(fontsize=7)
    return _plot_b64(fig)


_ADAPTER_CACHE = {}


def _grad_task(task):
    """One gradient check (backend name, grid index, keep images) -> (results, images or None). An
    exception is a failed check (param "error: ..."), not the end of the run."""
    b, index, keep = task
    try:
        if b not in _ADAPTER_CACHE:
            _ADAPTER_CACHE[b] = gradcheck.ADAPTERS[b]()
        inst = gradcheck.instance_by_index(index)
        return gradcheck.check_instance(_ADAPTER_CACHE[b], inst, keep_images=keep)
    except Exception as e:
        inf, nan = float("inf"), float("nan")
        return [gradcheck.GradResult(b, index, f"#{index}", f"error: {type(e).__name__}: {e}"[:300], nan, inf, inf,
                                     nan, nan, inf, nan, 0.0)], None


def _set_threads(n):
    """Set torch's and Dr.Jit's thread counts (where installed); returns [(setter, previous value)]."""
    saved = []
    try:
        import torch
        saved.append((torch.set_num_threads, torch.get_num_threads()))
        torch.set_num_threads(n)
    except ImportError:
        pass
    try:
        import drjit
        saved.append((drjit.set_thread_count, drjit.thread_count()))
        drjit.set_thread_count(n)
    except ImportError:
        pass
    return saved


def _single_threaded():
    """Worker-process initializer: one compute thread per process (OpenMP, torch, Dr.Jit)."""
    os.environ["OMP_NUM_THREADS"] = "1"
    _set_threads(1)


@contextlib.contextmanager
def _one_thread():
    """torch and Dr.Jit on one thread, restored on exit. The checks render 8×12 to 96×128 images:
    there a thread pool only costs (quick validate on 2 cores with one busy: 50 s with the default
    2 threads, 13.6 s with 1); use ``jobs`` for parallelism."""
    saved = _set_threads(1)
    try:
        yield
    finally:
        for setter, value in saved:
            setter(value)


def run(backends=None, instances="quick", scenes=None, quick=True, outdir="validation_report", references=None,
        limit_instances=None, size=None, cameras=None, mesh_files=(), progress=None, stream=None, jobs=1):
    """Run everything and write ``outdir/report.html`` and ``outdir/summary.json``. Returns the summary dict.

    ``jobs`` > 1 runs the gradient checks in that many single-threaded worker processes (the checks
    are independent and each renders tiny 8×12 images, where one thread per process is fastest).
    """
    if not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1:
        raise gendr.ParameterError(f"jobs={jobs!r} must be an integer >= 1")
    with _one_thread():  # every render here is small: a thread pool only costs (see _one_thread)
        return _run(backends, instances, scenes, quick, outdir, references, limit_instances, size, cameras,
                    mesh_files, progress, stream, jobs)


def _run(backends, instances, scenes, quick, outdir, references, limit_instances, size, cameras, mesh_files,
         progress, stream, jobs):
    stream = stream or sys.stdout
    t_start = time.perf_counter()
    notes = []
    missing = []  # asked for (or broken) but not checked: the run fails
    bnames = hardlimit.usable_backends(backends, notes, missing)
    refs = hardlimit.open_references(DEFAULT_REFERENCES if references is None else references, notes,
                                     None if references is None else missing)
    H, W = size or (QUICK_SIZE if quick else FULL_SIZE)
    scene_names = list(scenes) if scenes else list(QUICK_SCENES if quick else gscenes.SCENES)
    meshes = {}
    for s in scene_names:
        meshes[s] = gscenes.get_scene(s)
    for path in mesh_files:
        meshes[os.path.basename(path)] = gscenes.normalize(gscenes.load_mesh(path), 0.95)
    lim = hardlimit.limit_instances(limit_instances or ("quick" if quick else "all"))
    cams_all = hardlimit.standard_cameras(H, W)
    cam_names = list(cameras) if cameras else list(hardlimit.QUICK_CAMERAS if quick else cams_all)
    ginst = gradcheck.select_instances(instances)
    os.makedirs(outdir, exist_ok=True)  # after every input is resolved: a bad name leaves no empty folder

    # --- hard limit -----------------------------------------------------------------------------
    n_hl = len(meshes) * len(cam_names) * len(bnames) * len(lim)
    checks = []
    t0 = time.perf_counter()
    with _progress(n_hl, "hard-limit", progress) as bar:
        for s, mesh in meshes.items():
            for cn in cam_names:
                checks.append(hardlimit.check_scene_camera(s, mesh, cn, cams_all[cn], H, W, bnames, refs, lim,
                                                           bar.update))
    t_hl = time.perf_counter() - t0

    # --- G-buffers (the hard-limit scenes and cameras) and textures ----------------------------
    t0 = time.perf_counter()
    gbuf = [r for c in checks for r in surfaces.check_gbuffer(c.scene, meshes[c.scene], c.camera, cams_all[c.camera],
                                                              H, W, bnames, refs, c.refs, c.edist)]
    t_gb = time.perf_counter() - t0
    t0 = time.perf_counter()
    tex_cams = [c for c in cam_names if c in surfaces.TEXTURED_QUICK_CAMERAS] if quick else cam_names
    tex = [r for name in gscenes.TEXTURED_SCENES for cn in tex_cams
           for r in surfaces.check_textures(name, gscenes.get_textured_scene(name), cn, cams_all[cn], H, W, bnames, refs)]
    t_tex = time.perf_counter() - t0

    # --- gradients -----------------------------------------------------------------------------
    grad_results, grad_images = [], {}
    gb = [b for b in bnames if b in gradcheck.ADAPTERS]
    for b in bnames:
        if b not in gradcheck.ADAPTERS:
            notes.append(f"gradient check: no gradient adapter for backend {b!r} (validation/gendr_validation/gradcheck.py ADAPTERS)")
    t0 = time.perf_counter()
    tasks = [(b, inst.index, k < 3) for b in gb for k, inst in enumerate(ginst)]
    with _progress(len(tasks), "gradients", progress) as bar:
        if jobs > 1 and len(tasks) > 1:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor
            with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"),
                                     initializer=_single_threaded) as pool:
                outcomes = pool.map(_grad_task, tasks, chunksize=4)
                for (b, index, _), (res, imgs) in zip(tasks, outcomes):
                    grad_results += res
                    if imgs:
                        grad_images[(b, index)] = imgs
                    bar.update()
        else:
            for b, index, keep in tasks:
                res, imgs = _grad_task((b, index, keep))
                grad_results += res
                if imgs:
                    grad_images[(b, index)] = imgs
                bar.update()
    parity = gradcheck.backend_parity(bnames, ginst)
    t_grad = time.perf_counter() - t0

    # --- summary -------------------------------------------------------------------------------
    hl_rows = [asdict(r) | {"passed": r.passed} for c in checks for r in c.results]
    table = {}
    for r in (r for c in checks for r in c.results):
        key = (r.scene, r.camera, r.backend, r.reference)
        e = table.setdefault(key, {"instances": 0, "failed_instances": 0, "differ_unambiguous": 0,
                                   "differ_ambiguous": 0, "ambiguous": r.ambiguous})
        e["instances"] += 1
        e["failed_instances"] += int(not r.passed)
        e["differ_unambiguous"] += max(r.differ_unambiguous, 0)
        e.setdefault("errors", 0)
        e["errors"] += int(bool(r.error))
        e["differ_ambiguous"] += r.differ_ambiguous
    rvr = [{"scene": c.scene, "camera": c.camera, "pair": k, **v} for c in checks for k, v in c.ref_vs_ref.items()]
    summary = {
        "gendr_version": gendr.__version__, "mode": "quick" if quick else "full", "image_size": [H, W],
        "backends": bnames, "references": list(refs), "scenes": list(meshes), "cameras": cam_names,
        "limit_instances": [x[0] for x in lim], "tiny_tau": hardlimit.TINY_TAU,
        "tiny_tau_squared": hardlimit.TINY_TAU_SQUARED, "ambiguity_px": hardlimit.AMBIGUITY_PX,
        "hard_limit": {
            "checks": len(hl_rows), "failed": sum(not r["passed"] for r in hl_rows),
            "differ_unambiguous_total": sum(max(r["differ_unambiguous"], 0) for r in hl_rows),
            "differ_ambiguous_total": sum(r["differ_ambiguous"] for r in hl_rows),
            "table": [{"scene": k[0], "camera": k[1], "backend": k[2], "reference": k[3], **v} for k, v in table.items()],
            "reference_vs_reference": rvr, "rows": hl_rows, "seconds": t_hl},
        "gradients": {
            "instances": [i.index for i in ginst], "checks": len(grad_results),
            "failed": sum(not r.passed for r in grad_results), "thresholds": gradcheck.THRESHOLDS,
            "floor": gradcheck.FLOOR, "steps": gradcheck.STEPS, "image_size": [gradcheck.H_DEFAULT, gradcheck.W_DEFAULT],
            "tau": gradcheck.TAU, "tau_squared": gradcheck.TAU_SQUARED,
            "rows": [asdict(r) | {"passed": r.passed} for r in grad_results], "backend_parity": parity,
            "seconds": t_grad,
            "note": "param p: the T-conorm parameter (learnable p), checked on parametric instances except hamacher(p=0)"},
        "textures": {
            "checks": len(tex), "failed": sum(not r.passed for r in tex),
            "differ_total": sum(max(r.differ, 0) for r in tex), "tolerance": {f"{k[0]}/{k[1]}": v for k, v in surfaces.TOLERANCE.items()},
            "texel_ambiguity": surfaces.TEXEL_AMBIGUITY, "rows": [asdict(r) | {"passed": r.passed} for r in tex],
            "seconds": t_tex},
        "gbuffer": {
            "checks": len(gbuf), "failed": sum(not r.passed for r in gbuf), "depth_rtol": surfaces.DEPTH_RTOL,
            "mask_differ_total": sum(max(r.mask_differ, 0) for r in gbuf),
            "depth_differ_total": sum(max(r.depth_differ, 0) for r in gbuf),
            "face_id_differ_total": sum(max(r.face_id_differ, 0) for r in gbuf),
            "depth_max_rel": max([r.depth_max_rel for r in gbuf if not r.error], default=0.0),
            "rows": [asdict(r) | {"passed": r.passed} for r in gbuf], "seconds": t_gb},
        "notes": notes,
        "missing": missing,
    }
    summary["gradients"]["parity_failed"] = sum(not r["passed"] for r in parity)
    summary["passed"] = (summary["hard_limit"]["failed"] == 0 and summary["gradients"]["failed"] == 0
                         and summary["gradients"]["parity_failed"] == 0 and bool(bnames) and bool(refs)
                         and not missing and (summary["gradients"]["checks"] > 0 or not gb)
                         and summary["textures"]["failed"] == 0 and summary["gbuffer"]["failed"] == 0)
    summary["seconds"] = time.perf_counter() - t_start
    with open(os.path.join(outdir, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1, default=float)
    with open(os.path.join(outdir, "report.html"), "w") as f:
        f.write(_html(summary, checks, grad_results, grad_images, lim))
    print_summary(summary, stream)
    return summary


#: the per-(scene, camera, backend) check kinds of the summary matrix: anchor prefix, label, title
KINDS = (("hl", "HL", "hard limit vs references (§1)"), ("gb", "GB", "G-buffers vs references (§4)"),
         ("tx", "TX", "textures vs references (§3)"))

# opens every <details> around the element a link points at (Chromium also expands closed details on
# fragment navigation; this makes it not depend on the browser version)
_OPEN_TARGET = """<script>function gendrOpen(){var e=document.getElementById(decodeURIComponent(location.hash.slice(1)));
for(;e;e=e.parentElement){if(e.tagName==='DETAILS')e.open=true;}}
window.addEventListener('hashchange',gendrOpen);window.addEventListener('load',gendrOpen);</script>"""


def _slug(*parts) -> str:
    """An HTML id / URL fragment from names (scene file names may hold dots, spaces, ...)."""
    return "-".join(re.sub(r"[^A-Za-z0-9_]+", "_", str(p)) for p in parts)


def matrix_cells(summary) -> dict:
    """``{(scene, camera, backend): {kind: passed}}`` over the per-scene check kinds (``KINDS``), from a
    summary dict (so a report can be re-drawn from summary.json)."""
    cells = {}

    def add(kind, rows, passed):
        for r in rows:
            d = cells.setdefault((r["scene"], r["camera"], r["backend"]), {})
            d[kind] = d.get(kind, True) and bool(passed(r))
    add("hl", summary["hard_limit"]["table"], lambda r: r["failed_instances"] == 0)
    add("tx", summary.get("textures", {}).get("rows", []), lambda r: r["passed"])
    add("gb", summary.get("gbuffer", {}).get("rows", []), lambda r: r["passed"])
    return cells


def _matrix_html(summary, ok) -> str:
    e = html.escape
    cells = matrix_cells(summary)
    backends = list(dict.fromkeys([*summary["backends"], *(k[2] for k in cells)]))
    scenes = list(dict.fromkeys(k[0] for k in cells))
    cams = list(dict.fromkeys(k[1] for k in cells))
    labels = {k: (lab, title) for k, lab, title in KINDS}
    # scenes down, camera x backend across: a screenful even for the full set of scenes
    out = ['<h2 id="summary">Summary</h2><p>One cell per scene &times; camera &times; backend; each check kind in it '
           '(' + ", ".join(f"<b>{lab}</b>: {e(t)}" for _, lab, t in KINDS) + ') is green when it passed, red when it '
           'failed, and links to its details. Passing details are collapsed, failing ones open.</p>'
           '<table class="matrix"><tr><th rowspan="2">scene</th>'
           + "".join(f'<th colspan="{len(backends)}">{e(c)}</th>' for c in cams) + "</tr><tr>"
           + "".join(f"<th>{e(b)}</th>" for _ in cams for b in backends) + "</tr>"]
    ncol = len(cams) * len(backends)
    for sc in scenes:
        out.append(f"<tr><td>{e(sc)}</td>")
        for cam in cams:
            for b in backends:
                kinds = cells.get((sc, cam, b))
                if kinds is None:
                    out.append('<td class="cell none">&ndash;</td>')
                    continue
                links = " ".join(f'<a class="{"ok" if kinds[k] else "fail"}" href="#{k}-{_slug(sc, cam, b)}" '
                                 f'title="{e(labels[k][1])}: {"pass" if kinds[k] else "FAIL"}">{labels[k][0]}</a>'
                                 for k, _, _ in KINDS if k in kinds)
                cls = "pass" if all(kinds.values()) else "failed"
                out.append(f'<td class="cell {cls}" data-scene="{e(sc)}" data-camera="{e(cam)}" data-backend="{e(b)}">'
                           f"{links}</td>")
        out.append("</tr>")
    gr = summary["gradients"]
    out.append('<tr><td><a href="#gradients">gradients vs FD</a></td>')
    span = max(1, ncol // max(1, len(backends)))
    for b in backends:
        rs = [r for r in gr["rows"] if r["backend"] == b]
        if not rs:
            out.append(f'<td colspan="{span}" class="cell none">&ndash;</td>')
            continue
        nf = sum(not r["passed"] for r in rs)
        out.append(f'<td colspan="{span}" class="cell {"failed" if nf else "pass"}"><a class="{"fail" if nf else "ok"}" '
                   f'href="#gr-{_slug(b)}">{e(b)}: {len(rs) - nf}/{len(rs)}</a></td>')
    out.append("</tr>")
    if gr["backend_parity"]:
        nf = sum(not r["passed"] for r in gr["backend_parity"])
        out.append(f'<tr><td><a href="#parity">backend parity</a></td><td colspan="{ncol}" '
                   f'class="cell {"failed" if nf else "pass"}"><a class="{"fail" if nf else "ok"}" href="#parity">'
                   f'{len(gr["backend_parity"]) - nf}/{len(gr["backend_parity"])}</a></td></tr>')
    out.append("</table>")
    return "\n".join(out)


def _details(ident, passed, summary_html, body) -> str:
    """A collapsible block: closed when it passed, open when it failed."""
    return (f'<details id="{ident}"{"" if passed else " open"} class="{"pass" if passed else "failed"}">'
            f"<summary>{summary_html}</summary>{body}</details>")


def _grad_scatter(rows):
    """Small multiples, one per grid instance: analytic (y) vs finite-difference (x) derivative of every
    sampled output of every check, scaled by the check's max |FD| sample; the diagonal is AD = FD."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = [r for r in rows if r.get("fd_samples")]
    insts = sorted({r["instance"] for r in rows})
    if not insts:
        return None
    params = list(dict.fromkeys([*gradcheck.PARAMS, *(r["param"] for r in rows)]))
    backends = list(dict.fromkeys(r["backend"] for r in rows))
    colors = {p: plt.cm.tab10(k % 10) for k, p in enumerate(params)}
    markers = dict(zip(backends, "o+x^sv"))
    ncols = min(6, len(insts))
    nrows = -(-len(insts) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(1.9 * ncols, 1.9 * nrows + 0.5), squeeze=False)
    # fixed margins, one scatter call per panel and backend: tight_layout / bbox "tight" cost seconds here
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.35 / fig.get_figheight() + 0.04,
                        top=1 - 0.45 / fig.get_figheight(), wspace=0.3, hspace=0.45)
    for ax in axes.flat[len(insts):]:
        ax.axis("off")
    for ax, i in zip(axes.flat, insts):
        rs = [r for r in rows if r["instance"] == i]
        lim = 1.05
        for b in backends:
            xs, ys, cs = [], [], []
            for r in (r for r in rs if r["backend"] == b):
                fd, ad = np.asarray(r["fd_samples"]), np.asarray(r["ad_samples"])
                sc = max(np.abs(fd).max(), 1e-300)
                xs.append(fd / sc)
                ys.append(ad / sc)
                cs += [colors[r["param"]]] * len(fd)
            if not xs:
                continue
            x, y = np.concatenate(xs), np.concatenate(ys)
            lim = max(lim, float(np.nanmax(np.abs(y), initial=0)) * 1.05)
            hollow = markers[b] == "o"
            ax.scatter(x, y, s=9 if hollow else 14, marker=markers[b], linewidths=0.8,
                       **({"facecolors": "none", "edgecolors": cs} if hollow else {"c": cs}))
        lim = min(lim, 1e3)
        ax.plot([-lim, lim], [-lim, lim], color="k", lw=0.6, zorder=0)
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
        failed = any(not r["passed"] for r in rs)
        ax.set_title(f"#{i} {rs[0]['name']}" + (" FAIL" if failed else ""), fontsize=6.5,
                     color="#c00" if failed else "k")
    for ax in axes[-1]:
        ax.set_xlabel("FD / max|FD|", fontsize=7)
    for ax in axes[:, 0]:
        ax.set_ylabel("AD / max|FD|", fontsize=7)
    handles = [plt.Line2D([], [], ls="", marker="s", color=colors[p], label=p) for p in params
               if any(r["param"] == p for r in rows)]
    handles += [plt.Line2D([], [], ls="", marker=markers[b], color="k", mfc="none", label=b) for b in backends]
    fig.legend(handles=handles, loc="upper center", ncol=len(handles), fontsize=7, frameon=False)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _html(summary, checks, grad_results, grad_images, lim):
    e = html.escape
    ok = lambda b: '<span class="ok">pass</span>' if b else '<span class="fail">FAIL</span>'
    out = [f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>gendr validation report</title>
<style>body{{font-family:sans-serif;margin:20px}} table{{border-collapse:collapse;font-size:12px}}
td,th{{border:1px solid #bbb;padding:2px 6px}} .ok{{color:#080;font-weight:bold}} .fail{{color:#c00;font-weight:bold}}
img{{image-rendering:pixelated;margin:2px}} figure{{display:inline-block;margin:4px;text-align:center;font-size:11px}}
table.matrix td.cell{{text-align:center;white-space:nowrap}} td.cell.pass{{background:#e6f4e6}}
td.cell.failed{{background:#fbe3e3}} td.cell a{{text-decoration:none;margin:0 2px}}
details{{margin:3px 0}} details>summary{{cursor:pointer}} details.failed>summary{{color:#c00;font-weight:bold}}
img.scatter{{image-rendering:auto;max-width:100%}}</style>{_OPEN_TARGET}
</head><body><h1>gendr validation report</h1>
<p>Overall: {ok(summary['passed'])} &middot; mode {e(summary['mode'])} &middot; image {summary['image_size'][0]}x{summary['image_size'][1]}
&middot; backends {e(', '.join(summary['backends']))} &middot; references {e(', '.join(summary['references']))}
&middot; {summary['seconds']:.1f} s &middot; <a href="#hard-limit">§1 hard limit</a> &middot;
<a href="#gradients">§2 gradients</a> &middot; <a href="#textures">§3 textures</a> &middot; <a href="#gbuffer">§4 G-buffers</a></p>"""]
    out.append(_matrix_html(summary, ok))
    scatter = _grad_scatter(summary["gradients"]["rows"])
    if scatter:
        out.append('<h3 id="gradient-picture">Gradients: analytic vs finite differences</h3><p>Analytic (AD, y) vs '
                   'finite-difference (FD, x) derivative of the sampled outputs the per-pixel metric compares, one '
                   'panel per grid instance, each check scaled by its largest |FD| sample; colour: parameter, marker: '
                   'backend; on the diagonal AD = FD. Tables in <a href="#gradients">§2</a>.</p>'
                   f'<img class="scatter" id="gradient-scatter" alt="AD vs FD scatter" src="data:image/png;base64,{scatter}">')
    if summary["notes"]:
        out.append("<h3>Notes</h3><ul>" + "".join(f"<li>{e(n)}</li>" for n in summary["notes"]) + "</ul>")
    hl = summary["hard_limit"]
    out.append(f"""<h2 id="hard-limit">1. Hard limit vs references</h2>
<p>gendr's binary silhouettes (heaviside + logical or, and every listed distribution at τ → 0 with the
probabilistic T-conorm, thresholded at alpha &ge; 1/2; τ = {summary['tiny_tau']:g}, squared τ = {summary['tiny_tau_squared']:g})
vs each reference, pixel by pixel. Pixels whose centre lies within δ of a projected edge are ambiguous
(δ per reference: {e(json.dumps(summary['ambiguity_px']))} px). {hl['checks']} comparisons, {hl['failed']} failed,
{hl['differ_unambiguous_total']} unambiguous pixels differ in total ({hl['differ_ambiguous_total']} ambiguous ones).
Images per scene &times; camera: each reference's mask, gendr's heaviside|or silhouette and a difference image
(grey: both, red: only gendr, blue: only the reference, yellow: differing but ambiguous); failing instances are shown too.</p>""")
    by_sc = {c_key: c for c_key, c in (((c.scene, c.camera), c) for c in checks)}
    rvr = {}
    for r in hl["reference_vs_reference"]:
        rvr.setdefault((r["scene"], r["camera"]), []).append(r)
    groups = {}
    for r in hl["table"]:
        groups.setdefault((r["scene"], r["camera"]), {}).setdefault(r["backend"], []).append(r)
    for (sc, cam), per_b in groups.items():
        passed = all(r["failed_instances"] == 0 for rs in per_b.values() for r in rs)
        body = ['<table><tr><th>backend</th><th>reference</th><th>instances</th><th>failed</th>'
                "<th>unambiguous differing px (sum)</th><th>ambiguous differing px</th><th>ambiguous px</th><th>render errors</th></tr>"]
        for b, rs in per_b.items():
            body.append(f'<tbody id="hl-{_slug(sc, cam, b)}">')
            for r in rs:
                body.append(f"<tr><td>{e(b)}</td><td>{e(r['reference'])}</td><td>{r['instances']}</td>"
                            f"<td>{ok(r['failed_instances'] == 0)} {r['failed_instances']}</td><td>{r['differ_unambiguous']}</td>"
                            f"<td>{r['differ_ambiguous']}</td><td>{r['ambiguous']}</td><td>{r['errors']}</td></tr>")
            body.append("</tbody>")
        body.append("</table>")
        if rvr.get((sc, cam)):
            body.append("<table><tr><th>reference pair</th><th>unambiguous differing px</th><th>ambiguous differing</th>"
                        "<th>max |depth difference|</th></tr>")
            for r in rvr[(sc, cam)]:
                body.append(f"<tr><td>{e(r['pair'])}</td><td>{r['differ_unambiguous']}</td><td>{r['differ_ambiguous']}</td>"
                            f"<td>{r['depth_max_abs_diff']:.2e}</td></tr>")
            body.append("</table>")
        c = by_sc.get((sc, cam))
        if c is not None:
            body.append("<div>")
            for rname, (mask, depth) in c.refs.items():
                body.append(f'<figure><img src="data:image/png;base64,{_png_b64(mask.astype(float))}"><figcaption>{e(rname)}</figcaption></figure>')
                dn = depth / depth.max() if depth.max() > 0 else depth
                body.append(f'<figure><img src="data:image/png;base64,{_png_b64(dn)}"><figcaption>{e(rname)} depth</figcaption></figure>')
            shown_alpha = set()
            for r in c.results:
                if (r.instance != "heaviside|or" and r.passed) or r.error:
                    continue
                if (r.backend, r.instance) not in shown_alpha:
                    shown_alpha.add((r.backend, r.instance))
                    body.append(f'<figure><img src="data:image/png;base64,{_png_b64(c.alphas[(r.backend, r.instance)])}">'
                                f"<figcaption>gendr {e(r.backend)} {e(r.instance)}</figcaption></figure>")
                ours = c.alphas[(r.backend, r.instance)] >= 0.5
                amb = c.edist < r.delta_px
                body.append(f'<figure><img src="data:image/png;base64,{_png_b64(_diff_image(ours, c.refs[r.reference][0], amb))}">'
                            f"<figcaption>{e(r.backend)} diff vs {e(r.reference)}: {r.differ_unambiguous} {ok(r.passed)}</figcaption></figure>")
            body.append("</div>")
        nfail = sum(r["failed_instances"] for rs in per_b.values() for r in rs)
        out.append(_details(f"hl-{_slug(sc, cam)}", passed, f"{e(sc)} / {e(cam)}: {ok(passed)}"
                            + (f" ({nfail} failed instance comparisons)" if nfail else ""), "\n".join(body)))
    gr = summary["gradients"]
    out.append(f"""<h2 id="gradients">2. Gradients vs central finite differences</h2>
<p>float64, scene: squashed icosphere (80 faces), image {gr['image_size'][0]}x{gr['image_size'][1]}, τ = {gr['tau']:g}
(squared: {gr['tau_squared']:g}), softmax blend. Metric |a − r| / max(|r|, {gr['floor']:g}); thresholds
{e(json.dumps(gr['thresholds']))}; steps h {e(json.dumps(gr['steps']))} (τ: relative). {gr['checks']} checks,
{gr['failed']} failed. {e(gr['note'])}.</p>""")
    if scatter:
        out.append('<p>The AD-vs-FD scatter of these checks is under the <a href="#gradient-picture">summary</a>.</p>')
    if grad_results:
        out.append(_details("gr-errors", True, "relative errors per instance (plot)",
                            f'<img src="data:image/png;base64,{_grad_plot(grad_results)}">'))
    for b in dict.fromkeys(r["backend"] for r in gr["rows"]):
        rs = [r for r in gr["rows"] if r["backend"] == b]
        nf = sum(not r["passed"] for r in rs)
        body = ["<table><tr><th>#</th><th>instance</th><th>param</th><th>h</th><th>pixel mean</th>"
                "<th>pixel max</th><th>loss AD</th><th>loss FD</th><th>loss err</th><th></th></tr>"]
        for r in rs:
            body.append(f"<tr><td>{r['instance']}</td><td>{e(r['name'])}</td><td>{e(r['param'])}</td><td>{r['step']:g}</td>"
                        f"<td>{r['pixel_mean']:.1e}</td><td>{r['pixel_max']:.1e}</td><td>{r['loss_ad']:.6g}</td><td>{r['loss_fd']:.6g}</td>"
                        f"<td>{r['loss_err']:.1e}</td><td>{ok(r['passed'])}</td></tr>")
        body.append("</table>")
        out.append(_details(f"gr-{_slug(b)}", nf == 0, f"{e(b)}: {len(rs) - nf}/{len(rs)} checks {ok(nf == 0)}", "\n".join(body)))
    if grad_images:
        body = []
        for (b, idx), imgs in grad_images.items():
            body.append(f"<h4>{e(b)} instance {idx}: image, FD and AD derivative (alpha channel, sampled outputs)</h4><div>")
            for p, (img, ad, fd) in imgs.items():
                s = max(np.nanmax(np.abs(fd[..., 3])), 1e-12)
                body.append(f'<figure><img src="data:image/png;base64,{_png_b64(img[..., 3])}"><figcaption>{e(p)}: alpha</figcaption></figure>')
                body.append(f'<figure><img src="data:image/png;base64,{_png_b64(0.5 + 0.5 * fd[..., 3] / s)}"><figcaption>FD</figcaption></figure>')
                body.append(f'<figure><img src="data:image/png;base64,{_png_b64(np.nan_to_num(0.5 + 0.5 * ad[..., 3] / s, nan=0.0))}"><figcaption>AD (sampled)</figcaption></figure>')
            body.append("</div>")
        out.append(_details("gr-images", True, "derivative images of the first instances", "\n".join(body)))
    if gr["backend_parity"]:
        nf = sum(not r["passed"] for r in gr["backend_parity"])
        body = ["<table><tr><th>#</th><th>instance</th><th>backends</th><th>max |diff|</th></tr>"]
        for r in gr["backend_parity"]:
            body.append(f"<tr><td>{r['instance']}</td><td>{e(r['name'])}</td><td>{e(r['backends'])}</td><td>{r['max_abs_diff']:.2e} "
                        f"{ok(r['passed'])} {e(r.get('error', ''))}</td></tr>")
        body.append("</table>")
        out.append(_details("parity", nf == 0, f"Backend parity (forward): {len(gr['backend_parity']) - nf}/"
                            f"{len(gr['backend_parity'])} {ok(nf == 0)}", "\n".join(body)))
    tx = summary["textures"]
    out.append(f"""<h2 id="textures">3. Textures vs references</h2>
<p>Hard-blend RGB of the textured built-in scenes, unlit (the colour is the sampled texture), vs Mitsuba's
albedo AOV and pyrender's FLAT shading with the same texture, filter and wrap. Compared: unambiguous pixels
both cover (edges as in §1; for nearest also texel coordinates within {e(json.dumps(tx['texel_ambiguity']))}
texels of a texel boundary). Tolerance max |Δrgb| per reference/filter: {e(json.dumps(tx['tolerance']))}.
{tx['checks']} comparisons, {tx['failed']} failed, {tx['differ_total']} pixels beyond tolerance.</p>""")
    out += _grouped_details("tx", tx["rows"], ok,
                            "<th>backend</th><th>reference</th><th>filter</th><th>compared px</th><th>ambiguous px</th>"
                            "<th>differing px</th><th>max |Δrgb|</th><th>tolerance</th><th></th>",
                            lambda r: f"<td>{e(r['filter'])}</td><td>{r['compared']}</td><td>{r['ambiguous']}</td><td>{r['differ']}</td>"
                                      f"<td>{r['max_abs_diff']:.1e}</td><td>{r['tolerance']:.1e}</td><td>{ok(r['passed'])} {e(r['error'])}</td>")
    gb = summary["gbuffer"]
    out.append(f"""<h2 id="gbuffer">4. G-buffers vs references</h2>
<p><code>Renderer.rasterize</code> on the scenes and cameras of §1: mask (face_id &ge; 0) vs the reference mask,
view depth vs the reference depth (relative tolerance {gb['depth_rtol']:g}), face ids vs Mitsuba's prim_index AOV
(exact), on unambiguous pixels. {gb['checks']} comparisons, {gb['failed']} failed; differing pixels: mask
{gb['mask_differ_total']}, depth {gb['depth_differ_total']}, face id {gb['face_id_differ_total']}; max relative
depth difference {gb['depth_max_rel']:.1e}.</p>""")
    out += _grouped_details("gb", gb["rows"], ok,
                            "<th>backend</th><th>reference</th><th>mask differ</th><th>depth differ</th>"
                            "<th>max rel. depth diff</th><th>face id differ</th><th>ambiguous px</th><th></th>",
                            lambda r: f"<td>{r['mask_differ']}</td><td>{r['depth_differ']}</td><td>{r['depth_max_rel']:.1e}</td>"
                                      f"<td>{'n/a' if r['face_id_differ'] < 0 and not r['error'] else r['face_id_differ']}</td>"
                                      f"<td>{r['ambiguous']}</td><td>{ok(r['passed'])} {e(r['error'])}</td>")
    out.append("</body></html>")
    return "\n".join(out)


def _grouped_details(kind, rows, ok, header, cells):
    """Per scene × camera a collapsible table (open when a row failed) with one <tbody id> per backend,
    the summary matrix's link targets."""
    e = html.escape
    groups = {}
    for r in rows:
        groups.setdefault((r["scene"], r["camera"]), {}).setdefault(r["backend"], []).append(r)
    out = []
    for (sc, cam), per_b in groups.items():
        nf = sum(not r["passed"] for rs in per_b.values() for r in rs)
        body = [f"<table><tr>{header}</tr>"]
        for b, rs in per_b.items():
            body.append(f'<tbody id="{kind}-{_slug(sc, cam, b)}">')
            body += [f"<tr><td>{e(b)}</td><td>{e(r['reference'])}</td>{cells(r)}</tr>" for r in rs]
            body.append("</tbody>")
        body.append("</table>")
        out.append(_details(f"{kind}-{_slug(sc, cam)}", nf == 0, f"{e(sc)} / {e(cam)}: {ok(nf == 0)}"
                            + (f" ({nf} failed)" if nf else ""), "\n".join(body)))
    return out


def print_summary(s, stream=None):
    stream = stream or sys.stdout
    hl, gr = s["hard_limit"], s["gradients"]
    w = stream.write
    w(f"gendr validate ({s['mode']}, {s['image_size'][0]}x{s['image_size'][1]}): backends {', '.join(s['backends']) or '-'}; "
      f"references {', '.join(s['references']) or '-'}\n")
    w(f"  hard limit: {hl['checks'] - hl['failed']}/{hl['checks']} comparisons pass; unambiguous differing px: "
      f"{hl['differ_unambiguous_total']} (ambiguous: {hl['differ_ambiguous_total']}); {hl['seconds']:.1f}s\n")
    fails = [r for r in hl["table"] if r["failed_instances"]]
    for r in fails[:10]:
        w(f"    FAIL {r['scene']}/{r['camera']}/{r['backend']} vs {r['reference']}: {r['differ_unambiguous']} px "
          f"over {r['failed_instances']} instances ({r['errors']} render errors)\n")
    if len(fails) > 10:
        w(f"    ... {len(fails) - 10} more in summary.json\n")
    errs = sorted({(r["backend"], r["error"]) for r in hl["rows"] if r["error"]})
    for b, m in errs[:3]:
        w(f"    render error ({b}): {m[:150]}\n")
    pf = [r for r in gr["backend_parity"] if not r["passed"]]
    if gr["backend_parity"]:
        w(f"  backend parity: {len(gr['backend_parity']) - len(pf)}/{len(gr['backend_parity'])} pass\n")
    w(f"  gradients: {gr['checks'] - gr['failed']}/{gr['checks']} checks pass over {len(gr['instances'])} instances; {gr['seconds']:.1f}s\n")
    bad = [r for r in gr["rows"] if not r["passed"]]
    for r in bad[:8]:
        w(f"    FAIL {r['backend']} #{r['instance']} {r['name']} d/{r['param']}: pixel max {r['pixel_max']:.1e}, loss err {r['loss_err']:.1e}\n")
    if len(bad) > 8:
        w(f"    ... {len(bad) - 8} more failures in summary.json\n")
    tx, gb = s.get("textures"), s.get("gbuffer")
    if tx is not None:
        mx = max([r["max_abs_diff"] for r in tx["rows"] if not r["error"]], default=0.0)
        w(f"  textures: {tx['checks'] - tx['failed']}/{tx['checks']} comparisons pass; pixels beyond tolerance: "
          f"{tx['differ_total']}; max |drgb| {mx:.1e}; {tx['seconds']:.1f}s\n")
        for r in [r for r in tx["rows"] if not r["passed"]][:5]:
            w(f"    FAIL {r['scene']}/{r['camera']}/{r['backend']} vs {r['reference']} {r['filter']}: {r['differ']} px "
              f"(max {r['max_abs_diff']:.1e}) {r['error'][:150]}\n")
    if gb is not None:
        face_ids = any(r["face_id_differ"] >= 0 for r in gb["rows"])  # (only references that give face ids)
        w(f"  G-buffer: {gb['checks'] - gb['failed']}/{gb['checks']} comparisons pass; differing px: mask "
          f"{gb['mask_differ_total']}, depth {gb['depth_differ_total']}, face id "
          f"{gb['face_id_differ_total'] if face_ids else 'n/a'}; "
          f"max rel. depth diff {gb['depth_max_rel']:.1e}; {gb['seconds']:.1f}s\n")
        for r in [r for r in gb["rows"] if not r["passed"]][:5]:
            w(f"    FAIL {r['scene']}/{r['camera']}/{r['backend']} vs {r['reference']}: mask {r['mask_differ']}, depth "
              f"{r['depth_differ']}, face id {r['face_id_differ']} {r['error'][:150]}\n")
    for n in s["notes"]:
        w(f"  note: {n}\n")
    for m in s.get("missing", []):
        w(f"  NOT CHECKED (asked for, or broken): {m}\n")
    if s["gradients"]["checks"] == 0:
        w("  gradients: no check ran (no instance, or no backend with a gradient adapter)\n")
    w(f"  {'PASSED' if s['passed'] else 'FAILED'} in {s['seconds']:.1f}s\n")
