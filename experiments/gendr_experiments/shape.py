"""Shape optimisation (paper §5.1): deform a sphere until its soft silhouettes from 24 views match
the hard silhouettes of a target mesh.

* target: a built-in scene (``airplane``, ``chair``, ...) or a mesh file (scaled into the unit ball),
  rendered with the hard renderer (heaviside + logical or) from ``views`` azimuths spaced
  360/views degrees apart at one ``elevation`` — one batched camera.
* model (as SoftRas' ``demo_deform``): an icosphere template of radius 0.5 with per-vertex
  displacements ``δ`` and a centre offset ``c`` (both start at 0). Vertices
  ``v = sigmoid(logit(|v₀|) + δ)·sign(v₀)``, then shifted towards ``tanh(c)`` while staying in
  [−1, 1]³: ``v' = relu(v)·(1 − tanh c) − relu(−v)·(1 + tanh c) + tanh c``.
* loss: soft IoU loss (per view, averaged over views) + ``lambda_lap``·Laplacian + ``lambda_flat``·flatten.
  Laplacian: Σ_v ||v − mean(neighbours)||² (uniform weights). Flatten: Σ_edges (cos θ + 1)² with θ the
  dihedral angle. Defaults 0.03 and 0.0003 — SoftRas' weights for the same losses (sums, not means).
* optimiser: Adam(lr, betas=(0.5, 0.95)) for ``steps`` steps (100).
* metric: the hard-renderer IoU loss (heaviside + or; per view, averaged) of the final mesh.
"""
from __future__ import annotations

import math
import time

import numpy as np
import torch

import gendr
from gendr.scenes import icosphere

from .common import (flatten_edges, flatten_loss, instance_from_config, laplacian_loss, load_target_mesh,
                     make_renderer, mesh_laplacian, renderer_tau, soft_iou_loss, iou_loss_per_view)

__all__ = ["SHAPE_DEFAULTS", "run_shape", "ShapeProblem", "SphereDeformer", "shape_cameras"]

SHAPE_DEFAULTS = dict(
    experiment="shape",
    target="airplane",          # built-in scene name or mesh file
    instance=None,              # grid index, or distribution/tconorm below
    distribution="logistic",
    tconorm="probabilistic",
    tau=0.01,                   # blur width in screen units (squared instances get tau**2)
    lr=0.05,
    steps=100,
    image_size=64,
    views=24,
    elevation=30.0,
    distance=4.0,
    fov_y=35.0,
    subdivisions=2,             # icosphere template: 2 -> 162 vertices, 3 -> 642
    lambda_lap=0.03,
    lambda_flat=0.0003,
    seed=0,
    backend="torch",
    eps=1e-4,
)


class SphereDeformer(torch.nn.Module):
    """SoftRas' deformation model: bounded per-vertex displacements of a sphere plus a centre offset."""

    def __init__(self, subdivisions: int = 2, dtype=torch.float32):
        super().__init__()
        s = icosphere(subdivisions, radius=0.5)
        v0 = torch.tensor(s.vertices, dtype=dtype)
        self.register_buffer("faces", torch.tensor(s.faces))
        self.register_buffer("base", torch.log(v0.abs() / (1 - v0.abs())))
        self.register_buffer("sign", torch.sign(v0))
        self.displace = torch.nn.Parameter(torch.zeros_like(v0))
        self.center = torch.nn.Parameter(torch.zeros(1, 3, dtype=dtype))
        self.faces_np = s.faces

    def forward(self) -> torch.Tensor:
        c = torch.tanh(self.center)
        v = torch.sigmoid(self.base + self.displace) * self.sign
        v = torch.relu(v) * (1 - c) - torch.relu(-v) * (1 + c)
        return v + c


def shape_cameras(cfg: dict):
    n = int(cfg["views"])
    az = torch.arange(n, dtype=torch.float32) * (360.0 / n)
    return gendr.orbit_camera(az, float(cfg["elevation"]), float(cfg["distance"]), fov_y=float(cfg["fov_y"]))


def hard_silhouettes(vertices, faces, camera, image_size, backend="torch") -> torch.Tensor:
    r = gendr.Renderer("heaviside", "or", tau=1.0, image_size=image_size, backend=backend, eps=0.0, blend=None)
    with torch.no_grad():
        return r.render(vertices, faces, camera)[..., 3]


class ShapeProblem:
    """One shape optimisation, built once: target silhouettes, renderer, model, Laplacian, flatten
    edges and Adam. :meth:`step` runs one optimisation step (what :func:`run_shape` loops over and
    ``benchmarks/bench_step.py`` times).

    ``config`` is merged over :data:`SHAPE_DEFAULTS`, then ``overrides``. ``backend_options`` go to
    the renderer's backend (e.g. ``{"freeze": True}`` for ``backend="drjit"``); they are run-time
    options, not part of the config (so results' config hashes do not change).
    """

    def __init__(self, config: dict | None = None, *, backend_options: dict | None = None, **overrides):
        cfg = dict(SHAPE_DEFAULTS)
        cfg.update(config or {})
        cfg.update(overrides)
        self.cfg = cfg
        torch.manual_seed(int(cfg["seed"]))
        self.size = size = int(cfg["image_size"])
        self.camera = cam = shape_cameras(cfg)
        target = load_target_mesh(cfg["target"])
        tv = torch.tensor(target.vertices, dtype=torch.float32)
        tf = torch.tensor(target.faces)
        self.target_sil = hard_silhouettes(tv, tf, cam, size, cfg["backend"])

        dist, tcn, self.label = instance_from_config(cfg)
        self.tau = renderer_tau(cfg["tau"], dist.squared)
        self.renderer = make_renderer(dist, tcn, self.tau, size, backend=cfg["backend"], eps=float(cfg["eps"]),
                                      **(backend_options or {}))
        self.model = model = SphereDeformer(int(cfg["subdivisions"]))
        self.L = mesh_laplacian(model.base.shape[0], model.faces_np)
        self.fedges = flatten_edges(model.faces_np)
        self.opt = torch.optim.Adam(model.parameters(), lr=float(cfg["lr"]), betas=(0.5, 0.95))

    def hard_iou_loss(self):
        """``(vertices, hard IoU loss)`` of the current mesh (heaviside + or; per view, averaged)."""
        with torch.no_grad():
            v = self.model()
        sil = hard_silhouettes(v, self.model.faces, self.camera, self.size, self.cfg["backend"])
        return v, float(iou_loss_per_view(sil, self.target_sil).mean())

    def step(self, step_index: int, callback=None) -> float:
        """One step: render, loss, backward, Adam. Returns the soft IoU loss, or NaN (and makes no
        update) when the total loss is not finite. ``callback`` as in :func:`run_shape`."""
        cfg, model = self.cfg, self.model
        v = model()
        sil = self.renderer.render(v, model.faces, self.camera)[..., 3]
        iou = soft_iou_loss(sil, self.target_sil)
        loss = (iou + cfg["lambda_lap"] * laplacian_loss(v, self.L)
                + cfg["lambda_flat"] * flatten_loss(v, self.fedges))
        if not torch.isfinite(loss):
            return float("nan")
        self.opt.zero_grad()
        loss.backward()
        self.opt.step()
        if callback is not None:
            callback(step_index, v.detach(), sil.detach(), float(loss.detach()))
        return float(iou.detach())


def run_shape(config: dict | None = None, *, callback=None, backend_options=None, **overrides) -> dict:
    """Run one shape optimisation. ``config`` (merged over :data:`SHAPE_DEFAULTS`, then ``overrides``).

    ``callback(step, vertices, silhouettes, loss)`` is called every step (e.g. to record a GIF).
    ``backend_options``: see :class:`ShapeProblem`.
    Returns a dict: ``metric`` (final hard IoU loss, lower is better), ``soft_loss_first``,
    ``soft_loss_last``, ``hard_iou_loss_initial``, ``seconds``, ``vertices`` is *not* included
    (pass a callback to get the mesh).
    """
    t0 = time.perf_counter()
    prob = ShapeProblem(config, backend_options=backend_options, **overrides)
    _, hard0 = prob.hard_iou_loss()
    losses = []
    nonfinite = False
    for step in range(int(prob.cfg["steps"])):
        iou = prob.step(step, callback)
        if math.isnan(iou):
            nonfinite = True
            break
        losses.append(iou)
    v, hard = prob.hard_iou_loss()
    if nonfinite or not math.isfinite(hard):
        hard = float("nan")
    return {
        "metric": hard,
        "metric_name": "hard_iou_loss",
        "hard_iou_loss_initial": hard0,
        "soft_loss_first": losses[0] if losses else float("nan"),
        "soft_loss_last": losses[-1] if losses else float("nan"),
        "steps_done": len(losses),
        "nonfinite": nonfinite,
        "instance_label": prob.label,
        "renderer_tau": prob.tau,
        "seconds": time.perf_counter() - t0,
        "final_vertices": v.numpy(),
        "faces": prob.model.faces_np,
    }
