"""Camera-pose optimisation (paper §5.2): recover the pose of an asymmetric object from its silhouette.

* reference: ``target`` (default ``teapot_like``) rotated by a uniformly random rotation R*, seen by a
  camera on the +Z axis looking at the origin from a random distance d* ∈ [distance_min, distance_max]
  with a random vertical field of view fov* ∈ [fov_min, fov_max]; its hard silhouette (heaviside + or).
* initialisation: R₀ = R_δ·R*, R_δ a rotation about a uniformly random axis by an angle drawn
  uniformly from [angle_min, angle_max] (default 15°..75°); distance d₀ = d*·exp(u), u ∈ [−0.2, 0.2].
  The field of view is the camera's known intrinsic (the true fov*); randomising it per run varies the
  perspective.
* parameters: a rotation vector ω (R = exp([ω]×)·R₀, ω₀ = 0) and log-distance; Adam(lr, betas=(0.5, 0.95))
  for ``steps`` steps; τ decays logarithmically from ``tau_start`` = 1e-1 to ``tau_end`` = 1e-7 (a new
  τ each step, passed to the renderer as is, also for squared instances).
* loss: soft IoU loss of the silhouette (``loss="iou"``) or mean squared error (``loss="mse"``).
* metric: the angular error between R and R* (angle of R·R*ᵀ, degrees); ``success`` = error < 3°.
  Over seeds, the success rate is the fraction of runs that end within 3°.
"""
from __future__ import annotations

import math
import time

import numpy as np
import torch

import gendr

from .common import (axis_angle_to_matrix, instance_from_config, iou_loss_per_view, load_target_mesh,
                     log_tau_schedule, make_renderer, random_rotation, rotation_about, rotation_angle_deg)

__all__ = ["POSE_DEFAULTS", "run_pose", "PoseProblem", "SUCCESS_DEGREES"]

SUCCESS_DEGREES = 3.0

POSE_DEFAULTS = dict(
    experiment="pose",
    target="teapot_like",
    instance=None,
    distribution="logistic",
    tconorm="probabilistic",
    tau_start=1e-1,
    tau_end=1e-7,
    lr=0.01,
    steps=300,
    image_size=64,
    angle_min=15.0,
    angle_max=75.0,
    distance_min=3.0,
    distance_max=4.0,
    fov_min=35.0,
    fov_max=45.0,
    loss="iou",
    seed=0,
    backend="torch",
    eps=1e-4,
)


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


class PoseProblem:
    """One pose optimisation, built once: the random reference and initial pose, the reference
    silhouette, the parameters (ω, log-distance) and Adam. :meth:`step` runs one optimisation step
    (what :func:`run_pose` loops over and ``benchmarks/bench_step.py`` times).

    ``config`` is merged over :data:`POSE_DEFAULTS`, then ``overrides``. ``backend_options`` go to
    the renderer's backend (e.g. ``{"freeze": True}`` for ``backend="drjit"``); they are run-time
    options, not part of the config (so results' config hashes do not change).
    """

    def __init__(self, config: dict | None = None, *, backend_options: dict | None = None, **overrides):
        cfg = dict(POSE_DEFAULTS)
        cfg.update(config or {})
        cfg.update(overrides)
        self.cfg = cfg
        self.poses = poses = pose_problem(cfg)
        self.size = size = int(cfg["image_size"])
        mesh = load_target_mesh(cfg["target"])
        self.verts = torch.tensor(mesh.vertices, dtype=torch.float32)
        self.faces = torch.tensor(mesh.faces)
        hard = gendr.Renderer("heaviside", "or", tau=1.0, image_size=size, backend=cfg["backend"], eps=0.0,
                              blend=None)
        with torch.no_grad():
            self.ref = _render(hard, self.verts, self.faces, torch.tensor(poses["R_true"], dtype=torch.float32),
                               poses["d_true"], poses["fov"])

        self.dist, self.tcn, self.label = instance_from_config(cfg)
        self.backend_options = backend_options or {}
        self.renderer = None
        self.R0 = torch.tensor(poses["R0"], dtype=torch.float32)
        self.omega = torch.zeros(3, requires_grad=True)
        self.log_d = torch.tensor(math.log(poses["d0"]), dtype=torch.float32, requires_grad=True)
        self.opt = torch.optim.Adam([self.omega, self.log_d], lr=float(cfg["lr"]), betas=(0.5, 0.95))

    def rotation(self) -> torch.Tensor:
        """The current estimate R = exp([ω]×)·R₀."""
        return axis_angle_to_matrix(self.omega) @ self.R0

    def step(self, step_index: int, callback=None) -> float:
        """One step at τ of ``step_index`` in the schedule: render, loss, backward, Adam. Returns the
        loss, or NaN (and makes no update) when the loss or a gradient is not finite. ``callback``
        as in :func:`run_pose`."""
        cfg, steps = self.cfg, int(self.cfg["steps"])
        tau = log_tau_schedule(step_index, steps, float(cfg["tau_start"]), float(cfg["tau_end"]))
        renderer = make_renderer(self.dist, self.tcn, tau, self.size, backend=cfg["backend"], eps=float(cfg["eps"]),
                                 **self.backend_options)
        if self.renderer is not None:  # one backend object for every τ: its frozen recordings (freeze=True) serve all
            renderer.backend = self.renderer.backend
        self.renderer = renderer
        R = self.rotation()
        sil = _render(renderer, self.verts, self.faces, R, torch.exp(self.log_d), self.poses["fov"])
        if cfg["loss"] == "mse":
            loss = (sil - self.ref).pow(2).mean()
        else:
            loss = iou_loss_per_view(sil, self.ref).mean()
        if not torch.isfinite(loss):
            return float("nan")
        self.opt.zero_grad()
        loss.backward()
        if not (torch.isfinite(self.omega.grad).all() and torch.isfinite(self.log_d.grad)):
            return float("nan")
        self.opt.step()
        if callback is not None:
            callback(step_index, sil.detach(), self.ref, float(loss.detach()))
        return float(loss.detach())


def run_pose(config: dict | None = None, *, callback=None, backend_options=None, **overrides) -> dict:
    """Run one pose optimisation; returns ``metric`` (final angular error in degrees), ``success``,
    ``initial_error``, ``distance_error`` (relative), ``seconds``, ... (see the module docstring).
    ``backend_options``: see :class:`PoseProblem`."""
    t0 = time.perf_counter()
    prob = PoseProblem(config, backend_options=backend_options, **overrides)
    poses = prob.poses
    nonfinite = False
    losses = []
    for step in range(int(prob.cfg["steps"])):
        loss = prob.step(step, callback)
        if math.isnan(loss):
            nonfinite = True
            break
        losses.append(loss)
    with torch.no_grad():
        R = prob.rotation()
    err = rotation_angle_deg(R, poses["R_true"])
    return {
        "metric": err,
        "metric_name": "angular_error_deg",
        "success": bool(err < SUCCESS_DEGREES),
        "initial_error": rotation_angle_deg(poses["R0"], poses["R_true"]),
        "distance_error": abs(float(torch.exp(prob.log_d.detach())) - poses["d_true"]) / poses["d_true"],
        "loss_first": losses[0] if losses else float("nan"),
        "loss_last": losses[-1] if losses else float("nan"),
        "steps_done": len(losses),
        "nonfinite": nonfinite,
        "instance_label": prob.label,
        "seconds": time.perf_counter() - t0,
    }
