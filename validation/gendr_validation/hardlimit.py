"""Hard-limit check: gendr's binary silhouettes vs the reference renderers, pixel by pixel.

Two ways to get a binary silhouette from gendr (DESIGN.md §6):

* ``heaviside|or``: the heaviside CDF and the logical "or" — the exact hard limit;
* ``<distribution>@tau->0``: every distribution (plain and squared) of the paper's grid with the
  probabilistic T-conorm at a tiny τ (:data:`TINY_TAU`, :data:`TINY_TAU_SQUARED`), thresholded at
  alpha >= 1/2. Why 1/2: for a pixel at distance >= δ from every projected edge, each face's coverage
  is F(±δ/τ), which tends to 0 or 1 as τ -> 0 for every distribution (heavy tails too, only slower),
  and so does the probabilistic sum over finitely many faces; any threshold in (0, 1) then gives the
  same mask and 1/2 leaves the widest margin on both sides. The check also records how far from
  binary the unambiguous pixels still are (``max_nonbinary`` = max min(alpha, 1 - alpha)).

Ambiguous pixels: a pixel whose centre lies within δ of a projected (near-clipped) face edge —
computed from the mesh and camera in float64 NumPy (:func:`cameras.edge_distance`) — may legally
differ (fill rules, float32 geometry in the references). δ per reference (:data:`AMBIGUITY_PX`):
pyrender 1/256 px (Mesa's rasterizer snaps vertices to a 1/256-pixel fixed-point grid), Mitsuba
1e-3 px (float32 ray-triangle intersection). Every other pixel must agree: the target is 0.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

import gendr
from gendr.grid import DISTRIBUTION_SETTINGS

from .cameras import camera_geometry, edge_distance
from .references import get_reference, ReferenceUnavailableError

TINY_TAU = 1e-12          # screen units (1 unit = H/2 px): δ/τ ~ 1e7 at 48x64
TINY_TAU_SQUARED = 1e-24  # squared units: δ²/τ ~ 1e14
AMBIGUITY_PX = {"pyrender": 1.0 / 256.0, "mitsuba": 1e-3}


def ambiguity_px(reference_name: str) -> float:
    return AMBIGUITY_PX["pyrender" if reference_name.startswith("pyrender") else "mitsuba"]


def standard_cameras(H: int, W: int) -> dict:
    """The camera types every scene is checked with (all unbatched, aspect W/H respected).

    ``perspective`` and ``orthographic`` orbit cameras (xmag != ymag·W/H on purpose: pyrender
    cannot express that natively), ``intrinsics`` with fx != fy and an off-centre principal point,
    and ``perspective_near`` / ``orthographic_near`` whose near plane cuts through the mesh.
    """
    return {
        "perspective": gendr.orbit_camera(35.0, 25.0, 3.2, fov_y=40.0),
        "orthographic": gendr.orbit_camera(-50.0, 15.0, 3.0, orthographic=True, ymag=1.1, xmag=1.1 * W / H * 1.15),
        "intrinsics": gendr.IntrinsicsCamera(eye=(0.6, 0.9, 2.8), at=(0.05, -0.05, 0.0), fx=0.95 * H, fy=0.85 * H,
                                             cx=0.53 * W, cy=0.46 * H),
        "perspective_near": gendr.PerspectiveCamera(eye=(0.4, 0.5, 1.7), at=(0.0, 0.0, 0.0), fov_y=60.0, near=1.4),
        "orthographic_near": gendr.OrthographicCamera(eye=(-0.3, 0.6, 2.0), near=1.75, xmag=1.2 * W / H, ymag=1.2),
    }


QUICK_CAMERAS = ("perspective", "orthographic", "intrinsics", "perspective_near")


def limit_instances(which="all"):
    """[(name, distribution, tconorm, tau)] of the binary limits checked.

    ``which``: "all" (heaviside|or + the 46 distributions of the grid at τ -> 0), "quick"
    (heaviside|or + one distribution of each tail kind, plain and squared), or a list of names.
    """
    out = [("heaviside|or", gendr.distribution("heaviside"), gendr.tconorm("or"), 1.0)]
    for name, params, rev in DISTRIBUTION_SETTINGS:
        for sq in (False, True):
            d = gendr.distribution(name, reversed=rev, squared=sq, **params)
            out.append((f"{d.label()}@tau->0", d, gendr.tconorm("probabilistic"), TINY_TAU_SQUARED if sq else TINY_TAU))
    if which == "all":
        return out
    if which == "quick":
        keep = {"heaviside|or", "logistic@tau->0", "logistic+sq@tau->0", "uniform@tau->0", "cauchy@tau->0",
                "gamma(shape=0.5)+rev@tau->0", "levy+rev@tau->0"}
        return [o for o in out if o[0] in keep]
    names = set(which)
    sel = [o for o in out if o[0] in names]
    missing = names - {o[0] for o in sel}
    if missing:
        raise gendr.UnknownNameError("limit instance", sorted(missing)[0], [o[0] for o in out])
    return sel


def render_limit(backend, mesh, camera, H, W, dist, tcn, tau):
    """gendr's alpha [H, W] (float64) for one limit instance."""
    r = gendr.Renderer(dist, tcn, tau=tau, image_size=(H, W), backend=backend, blend=None)
    img = r.render(np.ascontiguousarray(mesh.vertices, dtype=np.float64), mesh.faces, camera)
    return np.asarray(r.to_numpy(img), dtype=np.float64)[0, ..., 3]


@dataclass
class LimitResult:
    scene: str
    camera: str
    backend: str
    reference: str
    instance: str
    pixels: int
    ambiguous: int
    differ_unambiguous: int
    differ_ambiguous: int
    max_nonbinary: float
    delta_px: float
    seconds: float
    error: str = ""  # the exception gendr raised, if rendering failed (counts as a failure)

    @property
    def passed(self) -> bool:
        return not self.error and self.differ_unambiguous == 0


def compare_masks(ours: np.ndarray, ref: np.ndarray, edist: np.ndarray, delta: float):
    amb = edist < delta
    diff = ours != ref
    return int(amb.sum()), int((diff & ~amb).sum()), int((diff & amb).sum())


@dataclass
class SceneCameraCheck:
    """Everything computed for one scene × camera: reference masks, edge distances, our alphas."""

    scene: str
    camera: str
    refs: dict = field(default_factory=dict)   # reference -> (mask, depth)
    edist: np.ndarray | None = None
    alphas: dict = field(default_factory=dict)  # (backend, instance) -> alpha
    results: list = field(default_factory=list)
    ref_vs_ref: dict = field(default_factory=dict)


def check_scene_camera(scene_name, mesh, camera_name, camera, H, W, backends, references, instances,
                       progress=None):
    """Run every (backend, instance) on one scene × camera against every reference."""
    chk = SceneCameraCheck(scene_name, camera_name)
    chk.edist = edge_distance(mesh, camera_geometry(camera), H, W)
    for rname, ref in references.items():
        chk.refs[rname] = ref.render(mesh, camera, H, W)
    rnames = list(references)
    for i in range(len(rnames)):
        for j in range(i + 1, len(rnames)):
            a, b = chk.refs[rnames[i]][0], chk.refs[rnames[j]][0]
            delta = max(ambiguity_px(rnames[i]), ambiguity_px(rnames[j]))
            amb, du, da = compare_masks(a, b, chk.edist, delta)
            both = a & b
            ddiff = float(np.abs(chk.refs[rnames[i]][1] - chk.refs[rnames[j]][1])[both].max()) if both.any() else 0.0
            chk.ref_vs_ref[f"{rnames[i]} vs {rnames[j]}"] = {"differ_unambiguous": du, "differ_ambiguous": da,
                                                             "ambiguous": amb, "depth_max_abs_diff": ddiff}
    for bname in backends:
        for iname, dist, tcn, tau in instances:
            t0 = time.perf_counter()
            try:
                alpha = render_limit(bname, mesh, camera, H, W, dist, tcn, tau)
            except Exception as e:  # a backend bug must not stop the run: record it as a failure
                msg = f"{type(e).__name__}: {e}"
                for rname in rnames:
                    amb = int((chk.edist < ambiguity_px(rname)).sum())
                    chk.results.append(LimitResult(scene_name, camera_name, bname, rname, iname, H * W, amb, -1, 0,
                                                   float("nan"), ambiguity_px(rname), time.perf_counter() - t0, msg[:300]))
                if progress:
                    progress()
                continue
            dt = time.perf_counter() - t0
            chk.alphas[(bname, iname)] = alpha
            ours = alpha >= 0.5
            for rname in rnames:
                delta = ambiguity_px(rname)
                amb, du, da = compare_masks(ours, chk.refs[rname][0], chk.edist, delta)
                unamb = chk.edist >= delta
                nonbin = float(np.minimum(alpha, 1 - alpha)[unamb].max()) if unamb.any() else 0.0
                chk.results.append(LimitResult(scene_name, camera_name, bname, rname, iname, H * W, amb, du, da,
                                               nonbin, delta, dt))
            if progress:
                progress()
    return chk


def open_references(names, notes=None, missing=None):
    """{name: Reference} of those that can run; unavailable ones are skipped with a note, and, when
    ``missing`` is a list (the names were asked for), recorded there too (the run then fails)."""
    out = {}
    for n in names:
        try:
            out[n] = get_reference(n)
        except ReferenceUnavailableError as e:
            if notes is not None:
                notes.append(f"reference {n} skipped: {e}")
            if missing is not None:
                missing.append(f"reference {n}: {e}")
    return out


def usable_backends(names=None, notes=None, missing=None):
    """Registered backends that import (``gendr.available_backends()``); others skipped with a note.
    A name that is not registered at all is an :class:`~gendr.UnknownNameError` (a typo, not a
    missing extra). With a ``missing`` list, a backend that imports but fails to construct (a bug,
    not a missing extra) is recorded there, and so is any unavailable one of ``names`` (asked for):
    the run then fails rather than pass on fewer backends."""
    registered = sorted(gendr.available_backends())
    unknown = [n for n in names or () if n not in registered]
    if unknown:
        raise gendr.UnknownNameError("backend", unknown[0], registered)
    out = []
    for n in (names or sorted(gendr.available_backends())):
        try:
            gendr.Renderer("heaviside", "or", tau=1.0, image_size=(2, 2), backend=n, blend=None)
        except Exception as e:  # report, don't crash
            if notes is not None:
                notes.append(f"backend {n} skipped: {type(e).__name__}: {e}")
            unavailable = isinstance(e, (gendr.BackendUnavailableError, ImportError))
            if missing is not None and (names or not unavailable):
                missing.append(f"backend {n}: {type(e).__name__}: {e}")
            continue
        out.append(n)
    return out
