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

__all__ = ["SHAPE_DEFAULTS", "run_shape", "SphereDeformer", "shape_cameras"]

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


def run_shape(config: dict | None = None, *, callback=None, **overrides) -> dict:
    """Run one shape optimisation. ``config`` (merged over :data:`SHAPE_DEFAULTS`, then ``overrides``).

    ``callback(step, vertices, silhouettes, loss)`` is called every step (e.g. to record a GIF).
    Returns a dict: ``metric`` (final hard IoU loss, lower is better), ``soft_loss_first``,
    ``soft_loss_last``, ``hard_iou_loss_initial``, ``seconds``, ``vertices`` is *not* included
    (pass a callback to get the mesh).
    """
    cfg = dict(SHAPE_DEFAULTS)
    cfg.update(config or {})
    cfg.update(overrides)
    torch.manual_seed(int(cfg["seed"]))
    t0 = time.perf_counter()
    size = int(cfg["image_size"])
    cam = shape_cameras(cfg)
    target = load_target_mesh(cfg["target"])
    tv = torch.tensor(target.vertices, dtype=torch.float32)
    tf = torch.tensor(target.faces)
    target_sil = hard_silhouettes(tv, tf, cam, size, cfg["backend"])

    dist, tcn, label = instance_from_config(cfg)
    tau = renderer_tau(cfg["tau"], dist.squared)
    renderer = make_renderer(dist, tcn, tau, size, backend=cfg["backend"], eps=float(cfg["eps"]))
    model = SphereDeformer(int(cfg["subdivisions"]))
    L = mesh_laplacian(model.base.shape[0], model.faces_np)
    fedges = flatten_edges(model.faces_np)
    opt = torch.optim.Adam(model.parameters(), lr=float(cfg["lr"]), betas=(0.5, 0.95))
    hard0 = float(iou_loss_per_view(hard_silhouettes(model().detach(), model.faces, cam, size, cfg["backend"]),
                                    target_sil).mean())
    losses = []
    nonfinite = False
    for step in range(int(cfg["steps"])):
        v = model()
        sil = renderer.render(v, model.faces, cam)[..., 3]
        iou = soft_iou_loss(sil, target_sil)
        loss = iou + cfg["lambda_lap"] * laplacian_loss(v, L) + cfg["lambda_flat"] * flatten_loss(v, fedges)
        if not torch.isfinite(loss):
            nonfinite = True
            break
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(iou.detach()))
        if callback is not None:
            callback(step, v.detach(), sil.detach(), float(loss.detach()))
    with torch.no_grad():
        v = model()
    hard = float(iou_loss_per_view(hard_silhouettes(v, model.faces, cam, size, cfg["backend"]), target_sil).mean())
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
        "instance_label": label,
        "renderer_tau": tau,
        "seconds": time.perf_counter() - t0,
        "final_vertices": v.numpy(),
        "faces": model.faces_np,
    }
