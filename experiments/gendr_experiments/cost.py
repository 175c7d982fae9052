"""What the experiments cost: seconds per run from what a run renders, fitted to measured rows, and
the CPU-hours of the paper's protocols (docs/experiments.md, "Scale: cost model and a Dask cluster").

A run's cost has three parts (:func:`run_features` computes the features from the config alone):

* a fixed part ``c0`` (loading meshes, the target silhouettes, kernel set-up);
* ``c1`` per rendered view per step (``view_steps`` = steps × views or pose pairs: projection,
  binning, the loss, the hard IoU the ``best`` metric renders every step);
* ``c2`` per billion (pixel, face) pairs the soft renderer evaluates (``gpairs``), times a factor per
  distribution family ``k_dist`` and per T-conorm family ``k_tconorm`` (a gamma CDF costs more per pair
  than a logistic one; ``max`` runs an arg-max loop where the others run a sum). The pairs are
  counted on the run's initial geometry (template or posed target, its cameras): every face's screen
  box grown by the renderer's culling distance at the run's τ (the distribution's ``eps`` radius, or
  the reference cut-off ``sqrt(cutoff·τ)``, :meth:`gendr.renderer.RenderSettings.culling_distance`),
  clipped to the image. Heavy tails at large τ cover every pixel from every face: they dominate.

``seconds = c0 + c1·view_steps + c2·k_dist·k_tconorm·gpairs``, one model per (experiment, protocol),
fitted in log space (relative errors) to rows' ``cpu_seconds`` (process CPU time; rows without it
give their wall ``seconds``, which on a shared machine also count the time other jobs took).
Families without rows get factor 1 (the geometric mean of the fitted ones).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np

from gendr.errors import ParameterError

__all__ = ["Footprint", "footprint", "run_features", "CostModel", "fit_cost_model", "protocol_runs",
           "study_progress", "runs_left", "protocol_cost", "PAPER_TAUS", "PAPER_LRS", "PAPER_ELEVATIONS",
           "PAPER_FINE_STEPS",
           "PAPER_TAUS_SQUARED", "PAPER_FINE_STEPS_SQUARED", "REDUCED_TAUS", "REDUCED_FINE_STEPS"]

#: the paper's search (docs/reference_implementation.md §2): 7 coarse τ, 3 learning rates, 5
#: elevations (each its own search), then 21 τ at 0.1-decade steps around the best one
PAPER_TAUS = tuple(10.0 ** -k for k in range(1, 8))
PAPER_LRS = (10 ** -1.25, 10 ** -1.5, 10 ** -1.75)
PAPER_ELEVATIONS = (-60.0, -30.0, 0.0, 30.0, 60.0)
PAPER_FINE_STEPS = tuple(round(0.1 * k, 1) for k in range(-10, 11))
#: gendr's τ is a width (squared instances render with width²): the paper's renderer τ grid for the
#: squared half is the widths sqrt(τ), its 0.1-decade fine steps are 0.05-decade steps of the width
PAPER_TAUS_SQUARED = tuple(math.sqrt(t) for t in PAPER_TAUS)
PAPER_FINE_STEPS_SQUARED = tuple(round(0.05 * k, 2) for k in range(-10, 11))
#: experiments/paper_grid.sh shape: widths 0.003, 0.01, 0.03 (about 10^-2.5, 10^-2, 10^-1.5), then best·10^±0.25
REDUCED_TAUS = (0.003, 0.01, 0.03)
REDUCED_FINE_STEPS = (-0.25, 0.25)


#: per-pair cost factors of the distribution and T-conorm families relative to their geometric mean,
#: fitted (Dr.Jit backend, one thread) to experiments/results/cost_timing.jsonl by ``gendr experiment
#: cost`` — one or two short runs each on a shared machine, so about ±30 %; ``tune`` weighs
#: candidates with them before it has timed them (families missing here count 1)
DEFAULT_K_DIST = {"gumbel_min": 0.46, "laplace": 0.55, "reciprocal": 0.58, "logistic": 0.65, "exponential": 0.82,
                  "cauchy": 0.84, "hyperbolic_secant": 0.85, "uniform": 0.92, "cubic_hermite": 0.98, "gamma": 1.52,
                  "gumbel_max": 1.61, "wigner_semicircle": 1.79, "levy": 1.95, "gaussian": 2.32}
DEFAULT_K_TCONORM = {"yager": 0.67, "aczel_alsina": 0.73, "probabilistic": 0.78, "hamacher": 0.91, "einstein": 0.97,
                     "max": 1.19, "schweizer_sklar": 1.23, "dombi": 1.32, "frank": 1.53}


# ------------------------------------------------------------------------------------------------
# features: pixel-face pairs from the geometry
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Footprint:
    """Pixel-face pairs of one render of a run's geometry (all its views) as a function of the
    culling distance (screen units): counted at ``radii``, interpolated linearly between them."""

    radii: tuple
    pairs: tuple

    def __call__(self, radius: float) -> float:
        r = np.asarray(self.radii)
        return float(np.interp(min(float(radius), r[-1]), r, np.asarray(self.pairs)))


def _geometry_key(cfg: dict) -> str:
    keys = ("experiment", "protocol", "target", "normalize_target", "template", "template_scale", "subdivisions",
            "views", "elevation", "distance", "fov_y", "image_size", "parametrization", "pairs", "seed",
            "gt_view_angle", "gt_angle_std", "distance_min", "distance_max", "fov_min", "fov_max")
    return json.dumps({k: cfg.get(k) for k in keys}, sort_keys=True, default=str)


def _geometry(cfg: dict):
    """(vertices [B?, V, 3], faces, camera, (H, W), scale): the initial geometry of a run's soft
    renders; ``scale`` multiplies the counted pairs (pose: the pairs counted on a sample of 8)."""
    import torch
    import gendr
    if cfg["experiment"] == "shape":
        from .shape import shape_target_views, shape_template
        camera, _, size = shape_target_views(cfg, silhouettes=False)
        tm = shape_template(cfg)
        return (torch.tensor(tm.vertices, dtype=torch.float32), torch.tensor(tm.faces), camera, size, 1.0)
    from .pose import make_pose_problem
    if cfg["parametrization"] == "lookat":
        n = int(cfg["pairs"])
        prob = make_pose_problem(cfg, pairs=min(n, 8))
        m = len(prob.pairs["d_true"])
        cam = gendr.orbit_camera(torch.zeros(m), torch.zeros(m), torch.tensor(prob.pairs["d_true"], dtype=torch.float32),
                                 fov_y=2.0 * float(cfg["gt_view_angle"]))
        return prob.verts_b, prob.faces, cam, (prob.size, prob.size), n / m
    prob = make_pose_problem(cfg)
    v = prob.verts @ torch.tensor(prob.poses["R_true"], dtype=torch.float32).T
    cam = gendr.orbit_camera(0.0, 0.0, prob.poses["d_true"], fov_y=prob.poses["fov"])
    return v, prob.faces, cam, (prob.size, prob.size), 1.0


_FOOTPRINTS: dict = {}


def footprint(cfg: dict) -> Footprint:
    """The :class:`Footprint` of a full run config (cached per geometry)."""
    key = _geometry_key(cfg)
    if key not in _FOOTPRINTS:
        _FOOTPRINTS[key] = _count_pairs(cfg)
    return _FOOTPRINTS[key]


def _count_pairs(cfg: dict) -> Footprint:
    import torch
    import gendr
    from gendr_torch.raster import pixel_ranges, prepare_faces  # the torch backend's own pair enumeration
    verts, faces, camera, (H, W), scale = _geometry(cfg)
    settings = gendr.Renderer("heaviside", "or", tau=1.0, image_size=(H, W), eps=0.0, blend=None,
                              backend="torch").settings
    with torch.no_grad():
        fc = prepare_faces(settings, camera, verts, faces, None, False)
        radii = [0.0, *np.logspace(-4, math.log10(2.0 * (1.0 + W / H)), 64)]
        pairs = []
        for r in radii:
            i0, i1, j0, j1 = pixel_ranges(fc, H, W, float(r))
            n = (i1 - i0 + 1).clamp(min=0).long() * (j1 - j0 + 1).clamp(min=0).long()
            pairs.append(float(n.sum()) * scale)
    return Footprint(tuple(radii), tuple(pairs))


_SETTINGS: dict = {}


def _instance_settings(cfg):
    """(distribution, T-conorm, RenderSettings) of a config's instance (cached: a study has 10^5 configs)."""
    from .common import instance_from_config, make_renderer
    key = json.dumps([cfg.get("instance"), cfg.get("distribution"), cfg.get("tconorm"), cfg["eps"], cfg.get("cutoff")],
                     sort_keys=True, default=str)
    if key not in _SETTINGS:
        dist, tcn, _ = instance_from_config(cfg)
        r = make_renderer(dist, tcn, 1.0, 8, eps=float(cfg["eps"]), cutoff=cfg.get("cutoff"))
        _SETTINGS[key] = (dist, tcn, r.settings)
    return _SETTINGS[key]


def run_features(cfg: dict) -> dict:
    """``view_steps``, ``gpairs`` (billions of pixel-face pairs the soft renders evaluate), the
    distribution and T-conorm families of a full run config (shape or pose)."""
    from .common import log_tau_schedule, renderer_tau
    dist, tcn, settings = _instance_settings(cfg)
    fp = footprint(cfg)
    steps = int(cfg["steps"])
    if cfg["experiment"] == "shape":
        views = _views(cfg)
        pairs = steps * fp(settings.culling_distance(renderer_tau(cfg["tau"], dist.squared)))
    else:
        views = int(cfg["pairs"]) if cfg["parametrization"] == "lookat" else 1
        taus = [log_tau_schedule(k, steps, float(cfg["tau_start"]), float(cfg["tau_end"])) for k in range(steps)]
        pairs = sum(fp(settings.culling_distance(t)) for t in taus)
    return {"view_steps": float(steps * views), "gpairs": pairs / 1e9, "dist_family": dist.name,
            "tconorm_family": tcn.name}


def _families(spec):
    from .common import instance_from_config
    return instance_from_config(spec)


def _views(cfg):
    from .targets import is_images_target, load_image_target
    if is_images_target(cfg.get("target")):
        return int(load_image_target(cfg["target"])[1].shape[0])
    return int(cfg["views"])


# ------------------------------------------------------------------------------------------------
# the model
# ------------------------------------------------------------------------------------------------

@dataclass
class CostModel:
    """``seconds = c0 + c1·view_steps + c2·k_dist·k_tconorm·gpairs`` (see the module docstring)."""

    experiment: str
    protocol: str
    c0: float
    c1: float
    c2: float
    k_dist: dict = field(default_factory=dict)
    k_tconorm: dict = field(default_factory=dict)
    n_rows: int = 0
    timer: str = "cpu_seconds"
    #: median |log(predicted / measured)| over the rows fitted (exp of it: typical factor off)
    median_abs_log_error: float = float("nan")
    #: where k_dist / k_tconorm come from when they were not fitted to these rows
    k_from: str | None = None

    def seconds(self, features: dict) -> float:
        k = self.k_dist.get(features["dist_family"], 1.0) * self.k_tconorm.get(features["tconorm_family"], 1.0)
        return self.c0 + self.c1 * features["view_steps"] + self.c2 * k * features["gpairs"]

    def predict(self, cfg: dict) -> float:
        return self.seconds(run_features(cfg))

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def _timer(row):
    if row.get("cpu_seconds") is not None:
        return "cpu_seconds", float(row["cpu_seconds"])
    return "seconds", float(row["seconds"])


def _on_cpu(row) -> bool:
    """The models are of CPU runs: rows whose renders ran on a GPU (`sweep --device cuda`) are left
    out of every fit (they still count as done runs)."""
    return row.get("provenance", {}).get("device", "cpu") == "cpu"


def fit_cost_model(rows, *, prior_weight: float = 0.3, k_from: CostModel | None = None) -> CostModel:
    """Fit :class:`CostModel` to finished rows of ONE (experiment, protocol) in log space (the
    relative error of every run counts the same). ``prior_weight`` pulls log k toward 0 (families
    with few rows stay near the others). ``k_from``: take the per-pair factors of this model (the
    same renderer backend's; they are the renderer's, not the experiment's) and fit only c0..c2."""
    from scipy.optimize import least_squares
    rows = [r for r in rows if r.get("status") == "ok" and r.get("seconds") and _on_cpu(r)]
    if not rows:
        raise ParameterError("no finished rows (of CPU runs) to fit a cost model to")
    groups = {(r["experiment"], r.get("protocol")) for r in rows}
    if len(groups) != 1:
        raise ParameterError(f"fit one (experiment, protocol) at a time, got {sorted(map(str, groups))}")
    exp, proto = groups.pop()
    feats = [run_features(r["config"]) for r in rows]
    timers = [_timer(r) for r in rows]
    y = np.log([t for _, t in timers])
    V = np.array([f["view_steps"] for f in feats])
    P = np.array([f["gpairs"] for f in feats])
    dfam = sorted({f["dist_family"] for f in feats})
    tfam = sorted({f["tconorm_family"] for f in feats})
    di = np.array([dfam.index(f["dist_family"]) for f in feats])
    ti = np.array([tfam.index(f["tconorm_family"]) for f in feats])
    nd, nt = (0, 0) if k_from else (len(dfam), len(tfam))
    fixed_d = np.array([k_from.k_dist.get(f, 1.0) for f in dfam]) if k_from else None
    fixed_t = np.array([k_from.k_tconorm.get(f, 1.0) for f in tfam]) if k_from else None

    def unpack(x):
        c = np.exp(x[:3])
        if k_from:
            return c, fixed_d, fixed_t
        kd = np.exp(x[3:3 + nd] - x[3:3 + nd].mean())
        kt = np.exp(x[3 + nd:] - x[3 + nd:].mean())
        return c, kd, kt

    def residuals(x):
        c, kd, kt = unpack(x)
        pred = c[0] + c[1] * V + c[2] * kd[di] * kt[ti] * P
        return np.concatenate([np.log(pred) - y, prior_weight * x[3:]])

    t_med = float(np.exp(np.median(y)))
    x0 = np.concatenate([np.log([0.2 * t_med, 0.3 * t_med / max(V.mean(), 1), 0.5 * t_med / max(P.mean(), 1e-9)]),
                         np.zeros(nd + nt)])
    sol = least_squares(residuals, x0, method="trf")
    c, kd, kt = unpack(sol.x)
    err = np.abs(residuals(sol.x)[:len(y)])
    if k_from:
        kd_all, kt_all = dict(k_from.k_dist), dict(k_from.k_tconorm)
    else:
        kd_all, kt_all = {f: float(k) for f, k in zip(dfam, kd)}, {f: float(k) for f, k in zip(tfam, kt)}
    return CostModel(exp, proto, float(c[0]), float(c[1]), float(c[2]), kd_all, kt_all,
                     len(rows), "/".join(sorted({n for n, _ in timers})), float(np.median(err)),
                     f"{k_from.experiment}/{k_from.protocol}" if k_from else None)


# ------------------------------------------------------------------------------------------------
# protocols: which runs, how many
# ------------------------------------------------------------------------------------------------

@dataclass
class _Search:
    """One search of a study, as ``gendr experiment sweep`` runs it: the coarse runs, then (where
    ``fine_bases``) a fine τ stage at ``fine_steps`` decades around the coarse τ and lr of the lowest
    mean metric (over the elevations), run at each base config (one per elevation)."""

    key: object            # the instance's grid index, else its label (best_tau's key)
    coarse: list           # full run configs
    fine_bases: list = field(default_factory=list)
    fine_steps: tuple = ()


#: the pose bins of the paper (and of paper_grid.sh pose)
PAPER_BINS = ((15.0, 35.0), (35.0, 55.0), (55.0, 75.0))


def _searches(name: str, instances=None):
    from .common import grid_instance
    from .sweep import full_config
    if name not in STUDIES:
        raise ParameterError(f"unknown study {name!r}; known: {', '.join(STUDIES)}")
    full = name.endswith("-paper")
    if name.startswith("shape"):
        insts = list(range(1242)) if instances is None else instances
        if instances is None and not full:
            from gendr.grid import DISTRIBUTION_SETTINGS
            insts += [{"distribution": {"name": n, "reversed": rev, "squared": sq, **params}, "tconorm": "average"}
                      for n, params, rev in DISTRIBUTION_SETTINGS for sq in (False, True)]
        for inst in insts:
            spec = dict(inst) if isinstance(inst, dict) else {"instance": int(inst)}
            key = _families(spec)[2] if isinstance(inst, dict) else int(inst)
            squared = spec["distribution"]["squared"] if isinstance(inst, dict) else grid_instance(int(inst)).distribution.squared
            if full:
                taus, fine = ((PAPER_TAUS_SQUARED, PAPER_FINE_STEPS_SQUARED) if squared else (PAPER_TAUS, PAPER_FINE_STEPS))
            else:
                taus, fine = REDUCED_TAUS, REDUCED_FINE_STEPS
            bases = [full_config("shape", {"protocol": "paper", "elevation": el, **spec})
                     for el in (PAPER_ELEVATIONS if full else (30.0,))]
            lrs = PAPER_LRS if full else (bases[0]["lr"],)  # the preset's, as the sweep without --lrs
            yield _Search(key, [dict(b, tau=t, lr=lr) for b in bases for t in taus for lr in lrs], bases, fine)
    else:
        if instances is None:
            five = ("max", "probabilistic", "einstein", "yager(p=2)", "dombi(p=0.5)")
            insts = range(1242) if full else [i for i in range(1242) if not grid_instance(i).distribution.squared
                                              and grid_instance(i).tconorm.label() in five]
        else:
            insts = instances
        for inst in insts:
            base = full_config("pose", {"protocol": "paper", "instance": int(inst), "pairs": 200 if full else 17})
            yield _Search(int(inst), [dict(base, angle_min=a, angle_max=b, lr=lr) for a, b in PAPER_BINS
                                      for lr in ((0.1, 0.3) if full else (base["lr"],))])


def protocol_runs(name: str, *, best_tau=None, instances=None):
    """Yield the config of every run of a named study (the keys match the rows its sweep writes):

    * ``shape-paper``: the paper's search, every instance: 5 elevations × 3 lr × 7 τ, then at the best
      lr 21 τ at 0.1-decade steps around the best τ at each elevation (the best: of the mean over
      the elevations, as ``--elevations`` has it; fine τ that are coarse τ are not run again: 18 new
      around an inner best, 19 around an edge);
    * ``shape-reduced``: ``experiments/paper_grid.sh shape``: the 1,242 and "average" with each of the
      46 distribution settings, elevation 30, lr 10^-1.5, τ 0.003, 0.01, 0.03, then best·10^±0.25;
    * ``pose-paper``: every instance, 3 bins × 200 pairs (one run per bin) × lr {0.1, 0.3}, 1,000 steps;
    * ``pose-reduced``: ``experiments/paper_grid.sh pose``: 23 plain distributions × 5 T-conorms,
      3 bins × 17 pairs, lr 0.3.

    ``best_tau``: instance (grid index, else label) -> the best coarse τ the fine stage centres on
    (default 0.01; the fine stage runs at the preset's lr, 10^-1.5); ``instances``: grid indices or config dicts
    outside the grid (default: the study's)."""
    best_tau = {} if best_tau is None else best_tau
    for s in _searches(name, instances):
        yield from s.coarse
        yield from _fine(s, best_tau.get(s.key, 0.01))


def _fine(search, tau, lr=None):
    """The fine stage's new runs (at ``lr``, default the preset's): a fine τ that is a coarse τ has
    run at every lr already."""
    from .sweep import fine_grid
    if not search.fine_bases:
        return []
    coarse = sorted({c["tau"] for c in search.coarse})
    fine = [t for t in fine_grid(tau, search.fine_steps, coarse) if t not in coarse]
    return [dict(b, tau=t, lr=b["lr"] if lr is None else lr) for b in search.fine_bases for t in fine]


def study_progress(name: str, rows, *, instances=None):
    """Yield ``(config, row)`` for every run of study ``name`` (:func:`protocol_runs`) as its sweep
    (``paper_grid.sh``, which reruns errors) goes on: ``row`` is the finished (``status`` ok) row of
    that config among ``rows`` (matched by key), else None. Once every coarse run of a search has a
    row, its fine stage centres, as the sweep's does, on the best τ and lr of those rows (a setting
    whose runs all ended in an error is skipped, an error beside finished runs scores worst); before
    (or if every coarse run ended in an error, which the sweep reruns first), on τ 0.01 at the
    preset's lr."""
    from .sweep import config_hash, summarize_best
    by_key = {r["key"]: r for r in rows}

    def ok(r):
        return r if r is not None and r.get("status") == "ok" else None
    for s in _searches(name, instances):
        found = [by_key.get(config_hash(c)) for c in s.coarse]
        yield from ((c, ok(r)) for c, r in zip(s.coarse, found))
        if not s.fine_bases:
            continue
        tau, lr = 0.01, None
        best = summarize_best(found, "shape") if all(found) else {}
        if best:  # one entry unless the rows name the instance differently (kept rows of older code)
            b = min(best.values(), key=lambda v: v["score"])
            tau, lr = b["tau"], b["lr"]
        yield from ((c, ok(by_key.get(config_hash(c)))) for c in _fine(s, tau, lr))


def runs_left(name: str, rows, *, instances=None):
    """The configs of the runs of study ``name`` that ``rows`` do not hold finished
    (:func:`study_progress`)."""
    return (c for c, r in study_progress(name, rows, instances=instances) if r is None)


def protocol_cost(model: CostModel, name: str, *, rows=None, **kw) -> dict:
    """Predicted ``runs``, ``cpu_hours`` and the most expensive single run of a study
    (:func:`protocol_runs`) under ``model``. With ``rows`` (a sweep's), its fine stages centre as
    the sweep's do (:func:`study_progress`), and ``done`` (the runs the rows hold: their measured
    CPU and wall hours) and ``left`` (the runs they lack: predicted) are added."""
    runs, total, worst = 0, 0.0, 0.0
    done, left, left_s = [], 0, 0.0
    pairs = (((c, None) for c in protocol_runs(name, **kw)) if rows is None
             else study_progress(name, rows, instances=kw.get("instances")))
    for cfg, row in pairs:
        s = model.predict(cfg)
        runs += 1
        total += s
        worst = max(worst, s)
        if row is not None:
            done.append(row)
        else:
            left += 1
            left_s += s
    out = {"study": name, "runs": runs, "cpu_hours": total / 3600.0, "longest_run_s": worst}
    if rows is not None:  # older rows have wall seconds only: not counted as CPU time
        cpu = [r["cpu_seconds"] for r in done if r.get("cpu_seconds") is not None]
        out["done"] = {"runs": len(done), "cpu_hours": sum(cpu) / 3600.0, "wall_only_runs": len(done) - len(cpu),
                       "wall_hours": sum(float(r.get("seconds") or 0.0) for r in done) / 3600.0}
        out["left"] = {"runs": left, "cpu_hours": left_s / 3600.0}
    return out


# ------------------------------------------------------------------------------------------------
# the report of ``gendr experiment cost``
# ------------------------------------------------------------------------------------------------

STUDIES = ("shape-paper", "shape-reduced", "pose-paper", "pose-reduced")


class _Const(dict):
    """best_tau mapping every instance to one value."""

    def __init__(self, value):
        super().__init__()
        self.value = value

    def get(self, key, default=None):
        return self.value


def best_measured_tau(rows) -> dict:
    """instance -> the τ of its best (lowest mean metric) shape row among ``rows`` (paper protocol,
    full length), coarse or fine: where a full study's fine stage would centre, as far as the rows
    tell."""
    from .shape import shape_config
    from .sweep import summarize_best
    steps = shape_config(protocol="paper")["steps"]  # not the short timing runs
    rows = [r for r in rows if r.get("experiment") == "shape" and r.get("protocol") == "paper"
            and r.get("status") == "ok" and r.get("metric") is not None and r["config"].get("steps") == steps]
    return {i: b["tau"] for i, b in summarize_best(rows, "shape").items()}  # grid index, else label


def cost_report(rows, *, studies=STUDIES, hours: float = 24.0, efficiency: float = 0.9, holdout=(),
                left: bool = False) -> dict:
    """Fit one :class:`CostModel` per (experiment, protocol) of ``rows`` and predict ``studies``
    (:func:`protocol_runs`) with the ``paper`` models. Returns a dict: ``models`` (each with its fit
    quality and, where wall-only rows of the same protocol exist, ``wall_over_model``: their median
    measured wall seconds / predicted CPU seconds), ``table`` (shape-paper seconds per run by
    distribution, variant and τ), ``studies`` (runs, CPU-hours with the fine stage centred on the
    measured best τ or 0.01, and on 0.1 / 0.001 for every instance, cores for a run of ``hours``
    at ``efficiency``; with ``left``, the fine stages centred where the rows' sweep centres them and
    ``done`` / ``left``: :func:`protocol_cost` with the rows), ``holdout`` (rows not fitted, each
    measured against its model's prediction)."""
    from .figures import grid_labels
    from .sweep import full_config
    all_rows, rows = rows, [r for r in rows if r.get("status") == "ok" and r.get("seconds") and r.get("config")
                            and _on_cpu(r)]
    groups = {}
    for r in rows:
        groups.setdefault((r["experiment"], r.get("protocol") or "quick"), []).append(r)
    models, out_models, by_backend = {}, [], {}
    for (exp, proto), grp in sorted(groups.items(), key=lambda kv: -len(kv[1])):  # most rows first
        cpu = [r for r in grp if r.get("cpu_seconds") is not None]
        use = cpu if cpu else grp
        if len(use) < 3:
            continue
        backend = use[0]["config"].get("backend")
        donor = by_backend.get(backend)  # per-pair factors of the backend, from its largest group
        m = fit_cost_model(use, k_from=donor)
        by_backend.setdefault(backend, m)
        models[(exp, proto)] = m
        info = m.to_dict()
        wall_only = [r for r in grp if r.get("cpu_seconds") is None]
        if cpu and wall_only:
            ratio = [r["seconds"] / m.predict(r["config"]) for r in wall_only]
            info["wall_over_model"] = {"rows": len(wall_only), "median": float(np.median(ratio)),
                                       "p10": float(np.percentile(ratio, 10)), "p90": float(np.percentile(ratio, 90))}
        out_models.append(info)
    report = {"models": out_models, "table": None, "studies": [], "holdout": []}
    for r in holdout:
        m = models.get((r["experiment"], r.get("protocol") or "quick"))
        if m is None or r.get("status") != "ok":
            continue
        name, t = _timer(r)
        p = m.predict(r["config"])
        report["holdout"].append({"label": r.get("label"), "experiment": r["experiment"], "tau": r.get("tau", r.get("tau_start")),
                                  "steps": r["config"]["steps"], "timer": name, "measured": t, "predicted": p,
                                  "ratio": t / p})
    shape = models.get(("shape", "paper"))
    if shape is not None:
        dl, tl = grid_labels()
        prob = tl.index("probabilistic")
        table = {}
        for d, label in enumerate(dl):
            for sq in (0, 1):
                inst = (d * 2 + sq) * len(tl) + prob
                base = full_config("shape", {"protocol": "paper", "instance": inst})
                table[label + (" sq" if sq else "")] = [shape.predict(dict(base, tau=t)) for t in PAPER_TAUS]
        report["table"] = {"taus": list(PAPER_TAUS), "tconorm": "probabilistic", "seconds": table}
    measured = best_measured_tau(rows)
    for study in studies:
        m = models.get((study.split("-")[0], "paper"))
        if m is None:
            report["studies"].append({"study": study, "error": f"no {study.split('-')[0]} paper-protocol rows to fit"})
            continue
        # a sweep's rows (left): its fine stages where they are; else around the measured best τ
        res = protocol_cost(m, study, rows=all_rows) if left else protocol_cost(m, study, best_tau=measured)
        if study.startswith("shape"):
            res["cpu_hours_if_best_tau"] = {
                str(t): protocol_cost(m, study, best_tau=_Const(t))["cpu_hours"] for t in (0.1, 0.001)}
        held = [h["ratio"] for h in report["holdout"] if h["experiment"] == study.split("-")[0]]
        if held:  # full-length runs measured beside the model: scale by their median ratio
            res["holdout_factor"] = float(np.median(held))
            res["cpu_hours_holdout_corrected"] = res["cpu_hours"] * res["holdout_factor"]
            if left:
                res["left"]["cpu_hours_holdout_corrected"] = res["left"]["cpu_hours"] * res["holdout_factor"]
        cpu_h = res.get("cpu_hours_holdout_corrected", res["cpu_hours"])
        res["cores_for_hours"] = {"hours": hours, "efficiency": efficiency,
                                  "cores": int(math.ceil(cpu_h / (hours * efficiency)))}
        report["studies"].append(res)
    return report


def format_report(report) -> str:
    """The text ``gendr experiment cost`` prints."""
    lines = []
    for m in report["models"]:
        lines.append(f"{m['experiment']}/{m['protocol']}: {m['n_rows']} rows ({m['timer']}), seconds = "
                     f"{m['c0']:.3g} + {m['c1']:.3g}·view_steps + {m['c2']:.3g}·k·gpairs; typical error ×"
                     f"{math.exp(m['median_abs_log_error']):.2f}")
        if m.get("k_from"):
            lines.append(f"  k_dist, k_tconorm: those of {m['k_from']} (same backend)")
        else:
            lines.append("  k_dist: " + ", ".join(f"{k} {v:.2f}" for k, v in sorted(m["k_dist"].items(),
                                                                                 key=lambda kv: kv[1])))
            lines.append("  k_tconorm: " + ", ".join(f"{k} {v:.2f}" for k, v in sorted(m["k_tconorm"].items(),
                                                                                      key=lambda kv: kv[1])))
        if "wall_over_model" in m:
            w = m["wall_over_model"]
            lines.append(f"  {w['rows']} rows with wall seconds only: measured / model = {w['median']:.2f} (median; "
                         f"10-90 %: {w['p10']:.2f}-{w['p90']:.2f})")
    t = report.get("table")
    if t:
        lines.append("")
        lines.append(f"shape, paper protocol: predicted CPU seconds per run ({t['tconorm']}; elevation 30)")
        lines.append(f"  {'distribution':22s}" + "".join(f"{x:>8.0e}" for x in t["taus"]))
        for label, secs in t["seconds"].items():
            lines.append(f"  {label:22s}" + "".join(f"{s:8.1f}" for s in secs))
    if report.get("holdout"):
        lines.append("")
        lines.append("held-out rows (not fitted): measured vs predicted")
        for h in report["holdout"]:
            lines.append(f"  {h['experiment']:5s} {str(h['label']):32s} tau={h['tau']:<8g} steps={h['steps']:<5d} "
                         f"{h['timer']} {h['measured']:8.1f}  model {h['predicted']:8.1f}  ratio {h['ratio']:.2f}")
    lines.append("")
    for s in report["studies"]:
        if "error" in s:
            lines.append(f"{s['study']}: {s['error']}")
            continue
        c = s["cores_for_hours"]
        extra = ""
        if "cpu_hours_if_best_tau" in s:
            extra = " (fine stage at best τ 0.1 for all: " + \
                    f"{s['cpu_hours_if_best_tau']['0.1']:,.0f}; 0.001: {s['cpu_hours_if_best_tau']['0.001']:,.0f})"
        lines.append(f"{s['study']}: {s['runs']:,} runs, {s['cpu_hours']:,.0f} CPU-hours{extra}; longest run "
                     f"{s['longest_run_s']:,.0f} s")
        if "holdout_factor" in s:
            lines.append(f"  × {s['holdout_factor']:.2f} (held-out full-length runs / model) = "
                         f"{s['cpu_hours_holdout_corrected']:,.0f} CPU-hours")
        lines.append(f"  {c['cores']:,} cores for {c['hours']:g} h at {c['efficiency']:.0%} utilisation")
        if "left" in s:
            rest = s["left"]
            corr = (f" (× {s['holdout_factor']:.2f}: {rest['cpu_hours_holdout_corrected']:,.1f})"
                    if "cpu_hours_holdout_corrected" in rest else "")
            d = s["done"]
            wall_only = f"; {d['wall_only_runs']} rows with wall seconds only" if d["wall_only_runs"] else ""
            lines.append(f"  done (the rows' runs of it): {d['runs']:,} runs, {d['cpu_hours']:,.1f} CPU-hours measured "
                         f"({d['wall_hours']:,.1f} wall-hours, one run at a time{wall_only})")
            lines.append(f"  left (runs the rows lack): {rest['runs']:,} runs, {rest['cpu_hours']:,.1f} CPU-hours{corr}")
    return "\n".join(lines)
