"""Shape optimisation (paper §5.1): deform a sphere until its soft silhouettes from 24 views match
the hard silhouettes of a target mesh.

Two named protocols (:data:`SHAPE_PRESETS`; docs/experiments.md lists them side by side with the
paper): ``quick`` (:data:`SHAPE_DEFAULTS`, cheap, built-in targets) and ``paper`` (every setting of
the paper's text and reference code; its meshes are user-supplied, ``paper:FILE``).

* target: a built-in scene (``airplane``, ``chair``, ...) or a mesh file (scaled into the unit ball
  unless ``normalize_target`` is false, as in the paper), rendered with the hard renderer (heaviside +
  logical or) from ``views`` azimuths spaced 360/views degrees apart at one ``elevation`` — one
  batched camera.
* model (as SoftRas' ``demo_deform``): a sphere template (``template``: ``"icosphere"`` with
  ``subdivisions``, or a mesh file) times ``template_scale`` (0.5) with per-vertex displacements ``δ``
  and a centre offset ``c`` (both start at 0). Vertices ``v = sigmoid(logit(|v₀|) + δ)·sign(v₀)``, then
  shifted towards ``tanh(c)`` while staying in [−1, 1]³: ``v' = relu(v)·(1 − tanh c) − relu(−v)·(1 + tanh c) + tanh c``.
* loss: soft IoU loss (per view, averaged over views) + ``lambda_lap``·Laplacian + ``lambda_flat``·flatten.
  Laplacian: Σ_v ||v − mean(neighbours)||² (uniform weights). Flatten: Σ_edges (cos θ + 1)² with θ the
  dihedral angle. Defaults 0.03 and 0.0003 — SoftRas' weights for the same losses (sums, not means).
* optimiser: Adam(lr, betas=(0.5, 0.95)) for ``steps`` steps (100).
* metric: the hard-renderer IoU loss (heaviside + or; per view, averaged): ``metric="final"`` of the
  final mesh, ``metric="best"`` (the paper's) the lowest over the meshes the steps rendered (states
  0 … steps−1, each before its update). Rows record both (``hard_iou_loss_final``, ``hard_iou_loss_best``).
"""
from __future__ import annotations

import math
import time

import numpy as np
import torch

import gendr

from gendr.errors import ParameterError

from .targets import is_images_target, load_image_target
from .common import (data_digests, finite_update, flatten_edges, flatten_loss, hard_renderer, instance_from_config,
                     laplacian_loss, load_target_mesh, load_template, make_renderer, mesh_laplacian, preset_config,
                     renderer_tau, soft_iou_loss, iou_loss_per_view)

__all__ = ["SHAPE_DEFAULTS", "SHAPE_PRESETS", "shape_config", "run_shape", "ShapeProblem", "SphereDeformer", "shape_cameras",
           "shape_target_views"]

SHAPE_DEFAULTS = dict(
    experiment="shape",
    protocol="quick",
    target="airplane",          # built-in scene, mesh file, "paper:FILE" (user-supplied) or "images:PATH.npz"
    normalize_target=True,      # scale a mesh file into the unit ball (the paper does not)
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
    template="icosphere",       # "icosphere" (with subdivisions) or a mesh file / "paper:sphere_642.obj"
    subdivisions=2,             # icosphere template: 2 -> 162 vertices, 3 -> 642
    template_scale=0.5,
    lambda_lap=0.03,
    lambda_flat=0.0003,
    metric="final",             # "final" hard IoU loss, or "best" over the steps (the paper's)
    seed=0,
    backend="torch",
    eps=1e-4,
    cutoff=None,                # the reference implementation's distance cut-off (dist_eps); None = exact
)

#: named protocols. ``paper``: the GenDR paper's §5.1 as its text and reference code run it
#: (docs/experiments.md, "Protocols", lists each setting and the remaining deviations); a sweep adds
#: its lr grid (10^-1.25, 10^-1.5, 10^-1.75), τ grid and the five elevations (−60 … 60).
SHAPE_PRESETS = {
    "quick": SHAPE_DEFAULTS,
    "paper": dict(SHAPE_DEFAULTS, protocol="paper", target="paper:airplane.obj", normalize_target=False,
                  lr=10 ** -1.5, distance=2.732, fov_y=30.0, template="paper:sphere_642.obj", subdivisions=3,
                  metric="best", eps=1e-6, cutoff=100.0, backend="drjit"),
}


class SphereDeformer(torch.nn.Module):
    """SoftRas' deformation model: bounded per-vertex displacements of a sphere plus a centre offset.
    ``template``: a :class:`gendr.scenes.Mesh` with every coordinate |v| < 1 (the parametrisation is a
    sigmoid of logit|v|; a coordinate that is exactly 0 stays 0, as in SoftRas), or an icosphere level
    (int) scaled by 0.5."""

    def __init__(self, template=2, dtype=torch.float32):
        super().__init__()
        if isinstance(template, int):
            template = load_template(f"icosphere:{template}", 0.5)
        v0 = torch.tensor(template.vertices, dtype=dtype)
        if not bool((v0.abs() < 1).all()):
            raise ValueError(f"the template's vertex coordinates must satisfy |v| < 1 (the deformation is "
                             f"a sigmoid of logit|v|), max |v| = {float(v0.abs().max()):g}; scale it (template_scale)")
        self.register_buffer("faces", torch.tensor(template.faces))
        self.register_buffer("base", torch.log(v0.abs() / (1 - v0.abs())))
        self.register_buffer("sign", torch.sign(v0))
        self.displace = torch.nn.Parameter(torch.zeros_like(v0))
        self.center = torch.nn.Parameter(torch.zeros(1, 3, dtype=dtype))
        self.faces_np = template.faces

    def forward(self) -> torch.Tensor:
        c = torch.tanh(self.center)
        v = torch.sigmoid(self.base + self.displace) * self.sign
        v = torch.relu(v) * (1 - c) - torch.relu(-v) * (1 + c)
        return v + c


def shape_config(config: dict | None = None, **overrides) -> dict:
    """The full config of a run: the preset named by ``protocol`` (in ``overrides`` or ``config``;
    default ``"quick"``), then ``config``, then ``overrides``. Unknown keys are an error."""
    return preset_config("shape", SHAPE_PRESETS, config, overrides)


def shape_cameras(cfg: dict):
    """The ``views`` azimuths 0, 360/views, ... at ``elevation`` (degrees) as one batched camera. The
    paper's cameras.npy lists azimuths 0, −15, …, −345: the same 24 positions in another order, and
    the metric averages over views, so the order does not matter."""
    n = int(cfg["views"])
    az = torch.arange(n, dtype=torch.float32) * (360.0 / n)
    return gendr.orbit_camera(az, float(cfg["elevation"]), float(cfg["distance"]), fov_y=float(cfg["fov_y"]))


def shape_target_views(cfg: dict, *, silhouettes: bool = True):
    """``(camera, target silhouettes [B, H, W] or None, (H, W))`` of a config: a mesh target (a built-in
    scene or a mesh file) rendered hard from :func:`shape_cameras`, or an ``images:PATH.npz`` target's
    own silhouettes and cameras (:mod:`gendr_experiments.targets`)."""
    if is_images_target(cfg["target"]):
        cam, sil = load_image_target(cfg["target"])
        return cam, sil, tuple(sil.shape[1:])
    size = int(cfg["image_size"])
    cam = shape_cameras(cfg)
    if not silhouettes:
        return cam, None, (size, size)
    target = load_target_mesh(cfg["target"], normalize=bool(cfg["normalize_target"]))
    tv = torch.tensor(target.vertices, dtype=torch.float32)
    tf = torch.tensor(target.faces)
    return cam, hard_silhouettes(tv, tf, cam, size, cfg["backend"]), (size, size)


def hard_silhouettes(vertices, faces, camera, image_size, backend="torch", renderer=None) -> torch.Tensor:
    """[B, H, W] exact silhouettes; ``renderer``: a :func:`hard_renderer` to reuse (default: a new one)."""
    r = renderer if renderer is not None else hard_renderer(image_size, backend)
    with torch.no_grad():
        return r.render(vertices, faces, camera)[..., 3]


def shape_template(cfg: dict):
    """The template mesh of ``cfg`` (before the deformation model's parametrisation)."""
    spec = cfg["template"]
    if spec == "icosphere":
        spec = f"icosphere:{int(cfg['subdivisions'])}"
    return load_template(spec, float(cfg["template_scale"]))


class ShapeProblem:
    """One shape optimisation, built once: target silhouettes, renderer, model, Laplacian, flatten
    edges and Adam. :meth:`step` runs one optimisation step (what :func:`run_shape` loops over and
    ``benchmarks/bench_step.py`` times).

    The config is :func:`shape_config` of ``config`` and ``overrides`` (a preset, ``protocol``, under
    them). ``backend_options`` go to the renderer's backend (e.g. ``{"freeze": False}``: Dr.Jit
    renders are frozen by default, :func:`~gendr_experiments.common.make_renderer`); they are
    run-time options, not part of the config (so results' config hashes do not change).
    """

    def __init__(self, config: dict | None = None, *, backend_options: dict | None = None, **overrides):
        self.cfg = cfg = shape_config(config, **overrides)
        torch.manual_seed(int(cfg["seed"]))
        self.camera, self.target_sil, (H, W) = shape_target_views(cfg)
        self.size = size = H if H == W else (H, W)

        dist, tcn, self.label = instance_from_config(cfg)
        self.tau = renderer_tau(cfg["tau"], dist.squared)
        self.backend_options = dict(backend_options or {})
        self.renderer = make_renderer(dist, tcn, self.tau, size, backend=cfg["backend"], eps=float(cfg["eps"]),
                                      cutoff=cfg["cutoff"], **self.backend_options)
        self.model = model = SphereDeformer(shape_template(cfg))
        self.L = mesh_laplacian(model.base.shape[0], model.faces_np)
        self.fedges = flatten_edges(model.faces_np)
        self.opt = torch.optim.Adam(model.parameters(), lr=float(cfg["lr"]), betas=(0.5, 0.95))
        if cfg["metric"] not in ("final", "best"):
            raise ParameterError(f"shape metric {cfg['metric']!r} must be 'final' or 'best'")
        #: hard IoU loss of the mesh each step rendered (only with ``metric="best"``)
        self.hard_losses: list[float] = []
        self._hard = None  # the hard renderer, made on first use

    def hard_iou_loss(self, vertices=None) -> tuple[torch.Tensor, float]:
        """``(vertices, hard IoU loss)`` of ``vertices`` (default: the current mesh); heaviside + or,
        per view, averaged."""
        if vertices is None:
            with torch.no_grad():
                vertices = self.model()
        if self._hard is None:
            self._hard = hard_renderer(self.size, self.cfg["backend"], freeze=self.backend_options.get("freeze", True))
        sil = hard_silhouettes(vertices, self.model.faces, self.camera, self.size, renderer=self._hard)
        return vertices, float(iou_loss_per_view(sil, self.target_sil).mean())

    def step(self, step_index: int, callback=None) -> float:
        """One step: render, loss, backward, Adam. Returns the soft IoU loss, or NaN (and makes no
        update) when the total loss or a gradient is not finite (Adam would turn the mesh into NaN).
        With ``metric="best"`` it first records the hard IoU loss of the mesh it renders.
        ``callback`` as in :func:`run_shape`."""
        cfg, model = self.cfg, self.model
        v = model()
        if cfg["metric"] == "best":
            self.hard_losses.append(self.hard_iou_loss(v.detach())[1])
        sil = self.renderer.render(v, model.faces, self.camera)[..., 3]
        iou = soft_iou_loss(sil, self.target_sil)
        loss = (iou + cfg["lambda_lap"] * laplacian_loss(v, self.L)
                + cfg["lambda_flat"] * flatten_loss(v, self.fedges))
        if not finite_update(self.opt, loss):
            return float("nan")
        if callback is not None:
            callback(step_index, v.detach(), sil.detach(), float(loss.detach()))
        return float(iou.detach())


def run_shape(config: dict | None = None, *, callback=None, backend_options=None, **overrides) -> dict:
    """Run one shape optimisation; the config is :func:`shape_config` of ``config`` and ``overrides``.

    ``callback(step, vertices, silhouettes, loss)`` is called every step (e.g. to record a GIF).
    ``backend_options``: see :class:`ShapeProblem`.
    Returns a dict: ``metric`` (the config's metric: ``hard_iou_loss_final`` or ``hard_iou_loss_best``,
    lower is better; a step whose loss or gradient is not finite ends the run, ``nonfinite``: the
    final loss is then NaN, the best the lowest of the meshes rendered before), ``best_step``, ``hard_iou_loss_initial``,
    ``soft_loss_first``, ``soft_loss_last``, ``seconds``, ``data`` (digests of the mesh files), and
    ``final_vertices`` / ``faces`` of the final mesh.
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
    best = min(prob.hard_losses) if prob.hard_losses else float("nan")
    best_step = int(np.argmin(prob.hard_losses)) if prob.hard_losses else None
    return {
        "metric": best if prob.cfg["metric"] == "best" else hard,
        "metric_name": f"hard_iou_loss_{prob.cfg['metric']}",
        "hard_iou_loss_final": hard,
        "hard_iou_loss_best": best,
        "best_step": best_step,
        "hard_iou_loss_initial": hard0,
        "soft_loss_first": losses[0] if losses else float("nan"),
        "soft_loss_last": losses[-1] if losses else float("nan"),
        "steps_done": len(losses),
        "nonfinite": nonfinite,
        "instance_label": prob.label,
        "renderer_tau": prob.tau,
        "data": data_digests(prob.cfg),
        "seconds": time.perf_counter() - t0,
        "final_vertices": v.numpy(),
        "faces": prob.model.faces_np,
    }
