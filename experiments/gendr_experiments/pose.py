"""Camera-pose optimisation (paper §5.2): recover the pose of an asymmetric object from its silhouette.

Two named protocols (:data:`POSE_PRESETS`; docs/experiments.md lists them beside the paper):

``quick`` (:data:`POSE_DEFAULTS`, ``parametrization="rotation"``, one pair per run):

* reference: ``target`` (default ``teapot_like``) rotated by a uniformly random rotation R*, seen by a
  camera on the +Z axis looking at the origin from a random distance d* ∈ [distance_min, distance_max]
  with a random vertical field of view fov* ∈ [fov_min, fov_max]; its hard silhouette (heaviside + or).
* initialisation: R₀ = R_δ·R*, R_δ a rotation about a uniformly random axis by an angle drawn
  uniformly from [angle_min, angle_max] (default 15°..75°); distance d₀ = d*·exp(u), u ∈ [−0.2, 0.2].
  The field of view is the camera's known intrinsic (the true fov*).
* parameters: a rotation vector ω (R = exp([ω]×)·R₀, ω₀ = 0) and log-distance; Adam(lr, betas) for
  ``steps`` steps; τ decays logarithmically from ``tau_start`` = 1e-1 to ``tau_end`` = 1e-7 (a new τ
  each step, passed to the renderer as is, also for squared instances).
* loss: soft IoU loss of the silhouette (``loss="iou"``) or mean squared error (``loss="mse"``).
* metric: the angular error between R and R* (angle of R·R*ᵀ, degrees); ``success`` = error <
  ``success_degrees`` (3°).

``paper`` (``parametrization="lookat"``, the paper's code; ``pairs`` pairs per run, one batch):

* ground truth per pair: distance U[gt_distance_min, gt_distance_max] = U[2.5, 4], elevation and
  azimuth N(0, gt_angle_std²) = N(0, 60²) degrees, view angle (half the vertical fov) 20°. The mesh
  (``paper:teapot.obj``, as it is) is first rotated by the ground-truth camera's rotation, so the
  reference is that rotated mesh seen from elevation = azimuth = 0 at the true distance and view
  angle, and the optimum is elevation = azimuth = 0.
* initial pose: distance U[2, 10], (elevation, azimuth) a uniformly random direction times an angle
  drawn uniformly from the bin [angle_min, angle_max] (15–35, 35–55 or 55–75°), view angle U[10, 30]°;
  the same ground truths and directions in every bin (as the reference code).
* parameters: (distance, elevation°, azimuth°, view angle°) per pair, all learnable;
  Adam(lr = 0.3, betas = (0.5, 0.99)), 1,000 steps, τ from 1e-1 to 1e-7 geometrically; loss = the
  soft IoU loss summed over the pairs (each pair's gradient is its own; Adam is element-wise, so a
  batch of pairs optimises them independently).
* metric: residual angle √(elevation² + azimuth²) of each pair after the last step; success when it is
  below ``success_degrees`` = 5° (the reference code's criterion; the paper's text says 3°, so rows
  also record the success rate at 3°). A pair whose pose leaves the camera's domain (distance <= 0,
  view angle outside (0, 90)°; the reference renders those mirrored) is frozen there and fails
  (``diverged``), so it cannot stop the other pairs of its batch.
"""
from __future__ import annotations

import math
import time

import numpy as np
import torch

import gendr

from gendr.errors import ParameterError

from .common import (axis_angle_to_matrix, data_digests, finite_update, hard_renderer, instance_from_config,
                     iou_loss_per_view, load_target_mesh, log_tau_schedule, make_renderer, preset_config,
                     random_rotation, rotation_about, rotation_angle_deg)

__all__ = ["POSE_DEFAULTS", "POSE_PRESETS", "pose_config", "run_pose", "PoseProblem", "LookAtPoseProblem",
           "make_pose_problem", "SUCCESS_DEGREES"]

SUCCESS_DEGREES = 3.0

POSE_DEFAULTS = dict(
    experiment="pose",
    protocol="quick",
    parametrization="rotation",  # "rotation" (ω and log-distance) or "lookat" (the paper's)
    target="teapot_like",
    normalize_target=True,
    instance=None,
    distribution="logistic",
    tconorm="probabilistic",
    tau_start=1e-1,
    tau_end=1e-7,
    lr=0.01,
    betas=(0.5, 0.95),
    steps=300,
    image_size=64,
    angle_min=15.0,
    angle_max=75.0,
    distance_min=3.0,            # rotation: the true distance range
    distance_max=4.0,
    fov_min=35.0,                # rotation: the true (known) vertical fov range, degrees
    fov_max=45.0,
    pairs=1,                     # lookat: pairs (ground truth, initial pose) per run, one batch
    gt_angle_std=60.0,           # lookat: std of the true elevation / azimuth, degrees
    gt_view_angle=20.0,          # lookat: true view angle (half the vertical fov), degrees
    init_distance_min=2.0,       # lookat: initial distance range
    init_distance_max=10.0,
    init_view_angle_min=10.0,    # lookat: initial view angle range, degrees
    init_view_angle_max=30.0,
    success_degrees=SUCCESS_DEGREES,
    loss="iou",
    seed=0,
    backend="torch",
    eps=1e-4,
    cutoff=None,
)

#: named protocols; ``paper`` is §5.2 as the paper's reference code runs it (one bin per run: set
#: ``angle_min`` / ``angle_max`` to 15/35, 35/55 or 55/75; 200 pairs per bin in the paper).
POSE_PRESETS = {
    "quick": POSE_DEFAULTS,
    "paper": dict(POSE_DEFAULTS, protocol="paper", parametrization="lookat", target="paper:teapot.obj",
                  normalize_target=False, lr=0.3, betas=(0.5, 0.99), steps=1000, angle_min=15.0, angle_max=35.0,
                  distance_min=2.5, distance_max=4.0, pairs=200, success_degrees=5.0, eps=1e-6, cutoff=100.0,
                  backend="drjit"),
}


def pose_config(config: dict | None = None, **overrides) -> dict:
    """The full config of a run: the preset named by ``protocol`` (default ``"quick"``), then
    ``config``, then ``overrides``. Unknown keys are an error."""
    cfg = preset_config("pose", POSE_PRESETS, config, overrides)
    cfg["betas"] = [float(b) for b in cfg["betas"]]  # one canonical form for the config hash
    if cfg["parametrization"] not in ("rotation", "lookat"):
        raise ParameterError(f"pose parametrization {cfg['parametrization']!r} must be 'rotation' or 'lookat'")
    return cfg


def pose_problem(cfg: dict):
    """The random reference pose and initial guess of run ``cfg`` (depends only on ``seed`` and the ranges)."""
    rng = np.random.default_rng(int(cfg["seed"]))
    R_true = random_rotation(rng)
    d_true = rng.uniform(cfg["distance_min"], cfg["distance_max"])
    fov = rng.uniform(cfg["fov_min"], cfg["fov_max"])
    axis = rng.normal(size=3)
    angle = rng.uniform(cfg["angle_min"], cfg["angle_max"])
    R0 = rotation_about(axis, angle) @ R_true
    d0 = d_true * math.exp(rng.uniform(-0.2, 0.2))
    return dict(R_true=R_true, d_true=float(d_true), fov=float(fov), R0=R0, d0=float(d0), angle=float(angle))


def _render(renderer, verts, faces, R, distance, fov):
    v = verts @ R.transpose(0, 1)
    cam = gendr.orbit_camera(0.0, 0.0, distance, fov_y=fov)
    return renderer.render(v, faces, cam)[..., 3]


class _PoseBase:
    """What both parametrisations share: the config, the mesh, a renderer per τ of the schedule
    (one backend object for all), the loss, the step with its finiteness checks."""

    PARAMETRIZATION = None  # the config's "parametrization" this class optimises

    def __init__(self, config, backend_options, overrides):
        self.cfg = cfg = pose_config(config, **overrides)
        if cfg["parametrization"] != self.PARAMETRIZATION:  # (else a paper config ran the quick problem)
            raise ParameterError(f"{type(self).__name__} optimises parametrization={self.PARAMETRIZATION!r}; this "
                                 f"config has {cfg['parametrization']!r}: use make_pose_problem(config)")
        self.size = int(cfg["image_size"])
        mesh = load_target_mesh(cfg["target"], normalize=bool(cfg["normalize_target"]))
        self.verts = torch.tensor(mesh.vertices, dtype=torch.float32)
        self.faces = torch.tensor(mesh.faces)
        self.dist, self.tcn, self.label = instance_from_config(cfg)
        self.backend_options = backend_options or {}
        self.renderer = None

    def _adam(self, params):
        return torch.optim.Adam(params, lr=float(self.cfg["lr"]), betas=tuple(self.cfg["betas"]))

    def renderer_at(self, step_index: int):
        """The soft renderer at τ of ``step_index`` in the schedule; one backend object for every τ
        (its frozen recordings, with ``freeze=True``, serve all)."""
        cfg = self.cfg
        tau = log_tau_schedule(step_index, int(cfg["steps"]), float(cfg["tau_start"]), float(cfg["tau_end"]))
        if self.renderer is None:
            self.renderer = make_renderer(self.dist, self.tcn, tau, self.size, backend=cfg["backend"],
                                          eps=float(cfg["eps"]), cutoff=cfg["cutoff"], **self.backend_options)
        else:
            self.renderer = self.renderer.with_tau(tau)
        return self.renderer

    def step(self, step_index: int, callback=None) -> float:
        """One step at τ of ``step_index`` in the schedule: render, loss, backward, Adam. Returns the
        loss, or NaN (and makes no update) when the loss or a gradient is not finite. ``callback``
        as in :func:`run_pose`."""
        sil = self.silhouettes(self.renderer_at(step_index))
        if self.cfg["loss"] == "mse":
            per_view = (sil - self.ref).pow(2).mean((-1, -2))
        else:
            per_view = iou_loss_per_view(sil, self.ref)
        loss = self.reduce(per_view)
        if not finite_update(self.opt, loss):
            return float("nan")
        self.after_update()
        if callback is not None:
            callback(step_index, sil.detach(), self.ref, float(loss.detach()))
        return float(loss.detach())

    def after_update(self):
        """Called after each Adam update (the look-at problem keeps its pairs renderable here)."""


class PoseProblem(_PoseBase):
    """One pose optimisation with ``parametrization="rotation"`` (the ``quick`` protocol), built
    once: the random reference and initial pose, the reference silhouette, the parameters (ω,
    log-distance) and Adam. :meth:`step` runs one optimisation step (what :func:`run_pose` loops over
    and ``benchmarks/bench_step.py`` times).

    The config is :func:`pose_config` of ``config`` and ``overrides``; a ``lookat`` one (the
    ``paper`` protocol) is a ParameterError: :func:`make_pose_problem` picks the class. ``backend_options`` go to the
    renderer's backend (e.g. ``{"freeze": False}``: Dr.Jit renders are frozen by default,
    :func:`~gendr_experiments.common.make_renderer`); they are run-time options, not part of the
    config (so results' config hashes do not change).
    """

    PARAMETRIZATION = "rotation"

    def __init__(self, config: dict | None = None, *, backend_options: dict | None = None, **overrides):
        super().__init__(config, backend_options, overrides)
        self.poses = poses = pose_problem(self.cfg)
        with torch.no_grad():
            self.ref = _render(hard_renderer(self.size, self.cfg["backend"]), self.verts, self.faces,
                               torch.tensor(poses["R_true"], dtype=torch.float32), poses["d_true"], poses["fov"])
        self.R0 = torch.tensor(poses["R0"], dtype=torch.float32)
        self.omega = torch.zeros(3, requires_grad=True)
        self.log_d = torch.tensor(math.log(poses["d0"]), dtype=torch.float32, requires_grad=True)
        self.params = [self.omega, self.log_d]
        self.opt = self._adam(self.params)

    def rotation(self) -> torch.Tensor:
        """The current estimate R = exp([ω]×)·R₀."""
        return axis_angle_to_matrix(self.omega) @ self.R0

    def silhouettes(self, renderer):
        return _render(renderer, self.verts, self.faces, self.rotation(), torch.exp(self.log_d), self.poses["fov"])

    @staticmethod
    def reduce(per_view):
        return per_view.mean()

    def result(self) -> dict:
        with torch.no_grad():
            R = self.rotation()
        err = rotation_angle_deg(R, self.poses["R_true"])
        d_true = self.poses["d_true"]
        return {"metric": err, "metric_name": "angular_error_deg",
                "success": bool(err < float(self.cfg["success_degrees"])),
                "initial_error": rotation_angle_deg(self.poses["R0"], self.poses["R_true"]),
                "distance_error": abs(float(torch.exp(self.log_d.detach())) - d_true) / d_true}


def lookat_rotation(azimuth, elevation) -> np.ndarray:
    """``[..., 3, 3]`` world-to-view rotations (rows: right, up, back) of gendr's orbit cameras at
    these angles (degrees), computed by the spec's own camera math (:meth:`gendr.Camera.basis`)."""
    az, el = np.asarray(azimuth, dtype=np.float64), np.asarray(elevation, dtype=np.float64)
    cam = gendr.PerspectiveCamera(eye=gendr.Orbit(az, el, 1.0))
    P = {"azimuth": az, "elevation": el, "distance": 1.0, "at": (0.0, 0.0, 0.0), "up": (0.0, 1.0, 0.0)}
    r, u, b, _ = cam.basis(np, P)
    return np.stack([np.stack(np.broadcast_arrays(*r), -1), np.stack(np.broadcast_arrays(*u), -1),
                     np.stack(np.broadcast_arrays(*b), -1)], -2)


def lookat_pairs(cfg: dict) -> dict:
    """The ``pairs`` (ground truth, initial pose) of a ``lookat`` run as arrays ``[pairs]``. Ground
    truths and directions depend only on ``seed``; the bin [angle_min, angle_max] scales the same
    uniform draw, so every bin perturbs the same poses in the same directions."""
    n, seed = int(cfg["pairs"]), int(cfg["seed"])
    if n < 1:
        raise ParameterError(f"pose pairs={n!r} must be >= 1")
    gt = np.random.default_rng([seed, 0])
    d_true = gt.uniform(cfg["distance_min"], cfg["distance_max"], n)
    el_true, az_true = gt.normal(0.0, cfg["gt_angle_std"], (2, n))
    init = np.random.default_rng([seed, 1])
    d0 = init.uniform(cfg["init_distance_min"], cfg["init_distance_max"], n)
    direction = init.normal(size=(n, 2))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    angle = cfg["angle_min"] + init.uniform(0.0, 1.0, n) * (cfg["angle_max"] - cfg["angle_min"])
    va0 = init.uniform(cfg["init_view_angle_min"], cfg["init_view_angle_max"], n)
    return dict(d_true=d_true, el_true=el_true, az_true=az_true, d0=d0, el0=direction[:, 0] * angle,
                az0=direction[:, 1] * angle, view_angle0=va0, angle=angle)


class LookAtPoseProblem(_PoseBase):
    """The paper's pose optimisation (``parametrization="lookat"``): ``pairs`` independent pairs in
    one batch, parameters (distance, elevation°, azimuth°, view angle°) per pair; see the module
    docstring. :meth:`step` as :class:`PoseProblem`'s."""

    PARAMETRIZATION = "lookat"

    def __init__(self, config: dict | None = None, *, backend_options: dict | None = None, **overrides):
        super().__init__(config, backend_options, overrides)
        cfg = self.cfg
        self.pairs = pr = lookat_pairs(cfg)
        R = torch.tensor(lookat_rotation(pr["az_true"], pr["el_true"]), dtype=torch.float32)   # [n, 3, 3]
        # the reference's relative formulation: rotate the mesh into the true camera's frame; the
        # camera at elevation = azimuth = 0 has the identity rotation, so there it sees the true view
        self.verts_b = torch.einsum("nij,vj->nvi", R, self.verts)
        gt_fov = torch.full((len(pr["d0"]),), 2.0 * float(cfg["gt_view_angle"]))
        with torch.no_grad():
            self.ref = self._render(hard_renderer(self.size, cfg["backend"]),
                                    torch.tensor(pr["d_true"], dtype=torch.float32),
                                    torch.zeros(len(gt_fov)), torch.zeros(len(gt_fov)), gt_fov)
        init = np.stack([pr["d0"], pr["el0"], pr["az0"], pr["view_angle0"]], 1)
        self.pose = torch.tensor(init, dtype=torch.float32, requires_grad=True)   # [n, 4]
        self.params = [self.pose]
        self.opt = self._adam(self.params)
        self._last = self.pose.detach().clone()
        #: pairs whose pose left the camera's domain (distance <= 0, view angle outside (0, 90)°):
        #: frozen at their last valid pose and counted as failures
        self.diverged = torch.zeros(len(init), dtype=torch.bool)

    def after_update(self):
        """One pair stepping out of the camera's domain must not stop the others (the batch is a set
        of independent runs): such a pair is frozen at its last valid pose from then on."""
        with torch.no_grad():
            p = self.pose
            bad = ~((p[:, 0] > 0) & (p[:, 3] > 0) & (p[:, 3] < 90) & torch.isfinite(p).all(1))
            self.diverged |= bad
            p[self.diverged] = self._last[self.diverged]
            self._last = p.detach().clone()

    def _render(self, renderer, distance, elevation, azimuth, fov_y):
        cam = gendr.orbit_camera(azimuth, elevation, distance, fov_y=fov_y)
        return renderer.render(self.verts_b, self.faces, cam)[..., 3]

    def silhouettes(self, renderer):
        p = self.pose
        return self._render(renderer, p[:, 0], p[:, 1], p[:, 2], 2.0 * p[:, 3])

    @staticmethod
    def reduce(per_view):
        return per_view.sum()

    def residual_deg(self) -> np.ndarray:
        """``[pairs]`` √(elevation² + azimuth²) of the current poses, degrees (0 = solved)."""
        p = self.pose.detach().double().numpy()
        return np.hypot(p[:, 1], p[:, 2])

    def result(self) -> dict:
        res = self.residual_deg()
        ok = res < float(self.cfg["success_degrees"])
        ok &= ~self.diverged.numpy()
        return {"metric": float(1.0 - ok.mean()), "metric_name": "failure_rate", "diverged": int(self.diverged.sum()),
                "success_rate": float(ok.mean()), "successes": int(ok.sum()), "pairs": int(len(res)),
                "success_rate_3deg": float(((res < 3.0) & ~self.diverged.numpy()).mean()),
                "residual_deg_median": float(np.median(res)), "residual_deg": [float(x) for x in res],
                "initial_residual_deg": [float(x) for x in self.pairs["angle"]],
                "distance_error_median": float(np.median(np.abs(self.pose.detach().numpy()[:, 0] - self.pairs["d_true"])
                                                         / self.pairs["d_true"]))}


def make_pose_problem(config: dict | None = None, *, backend_options: dict | None = None, **overrides):
    """:class:`PoseProblem` or :class:`LookAtPoseProblem`, by the config's ``parametrization``."""
    cfg = pose_config(config, **overrides)
    cls = LookAtPoseProblem if cfg["parametrization"] == "lookat" else PoseProblem
    return cls(cfg, backend_options=backend_options)


def run_pose(config: dict | None = None, *, callback=None, backend_options=None, **overrides) -> dict:
    """Run one pose optimisation (``rotation``: one pair; ``lookat``: a batch of ``pairs``).

    ``rotation`` returns ``metric`` (final angular error in degrees), ``success``, ``initial_error``,
    ``distance_error`` (relative); ``lookat`` returns ``metric`` (failure rate, 1 − success rate),
    ``success_rate``, ``successes``, ``pairs``, ``success_rate_3deg``, ``residual_deg`` (per pair),
    ``residual_deg_median``. Both: ``loss_first``, ``loss_last``, ``steps_done``, ``nonfinite``,
    ``seconds``, ``data`` (digest of the mesh file). ``backend_options``: see :class:`PoseProblem`."""
    t0 = time.perf_counter()
    prob = make_pose_problem(config, backend_options=backend_options, **overrides)
    nonfinite = False
    losses = []
    for step in range(int(prob.cfg["steps"])):
        loss = prob.step(step, callback)
        if math.isnan(loss):
            nonfinite = True
            break
        losses.append(loss)
    out = prob.result()
    out.update({
        "loss_first": losses[0] if losses else float("nan"),
        "loss_last": losses[-1] if losses else float("nan"),
        "steps_done": len(losses),
        "nonfinite": nonfinite,
        "instance_label": prob.label,
        "data": data_digests(prob.cfg),
        "seconds": time.perf_counter() - t0,
    })
    return out
