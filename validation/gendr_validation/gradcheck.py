"""Gradient check: reverse-mode derivatives vs central finite differences, in float64 (DESIGN.md §6).

For an instance of ``gendr.paper_grid()`` and a parameter family θ (vertex positions, camera pose and
field of view, per-vertex colours, τ), a random unit direction u gives a one-parameter image f(t) = render(θ + t·u). We compare

* per pixel (all 4 channels): the AD directional derivative J·u with the Richardson-extrapolated
  central difference (4·D(h/2) − D(h))/3, D(k) = (f(t + k/2) − f(t − k/2)) / k (fourth order);
* a scalar loss L = Σ w ⊙ f with fixed random weights w: ∇L·u by AD vs the same difference of L.

Error metric: |a − r| / max(|r|, floor) (Mitsuba's AD tests), with thresholds on the mean and the
max over pixels (:data:`THRESHOLDS`). The step sizes are recorded with every result.

Per-pixel AD derivatives from reverse mode: the renderer's batch dimension holds one copy of the
scene per (pixel, channel) output; copy b is moved by its own scalar t_b and contributes only its
output b to the loss, so ONE backward pass gives every per-pixel derivative ∂f_b/∂t_b (vertices and
camera pose batch; τ is a single scalar per render, so its per-pixel derivatives take one backward
pass per output — done on a few sampled outputs only).

Gradients are backend specific: :data:`ADAPTERS` holds one adapter per backend (torch now). A backend
without an adapter is skipped with a note.

The T-conorm parameter p (param ``"p"``) and the distribution's shape (param ``"shape"``, gamma)
are checked like τ: a relative step (f(p·(1 + t))), the AD side from ``gendr.tconorm(name,
p=tensor)`` / ``gendr.distribution("gamma", shape=tensor)`` (learnable), per-pixel derivatives on a
few sampled outputs. Only instances with such a parameter get the check, except hamacher(p=0),
which sits on the boundary of its domain (a central difference would step to p < 0).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

import gendr
from gendr.scenes import icosphere

H_DEFAULT, W_DEFAULT = 8, 12
TAU = 0.08          # screen units (1 unit = H/2 px): ~0.3 px at 8 px high
TAU_SQUARED = TAU ** 2
# h, in units of the direction (τ: relative); the reference derivative is Richardson-extrapolated
# from central differences with steps h and h/2 (:func:`richardson`). Camera: at 1e-5 degrees the loss
# FD is round-off bound (#649 exponential+rev|probabilistic). τ: at 1e-7 small losses were round-off
# bound (#1207 levy+rev|dombi(0.5): loss error 7.7e-5 at h = 1e-7, 6e-8 at 1e-4).
STEPS = {"vertices": 1e-6, "vertices_unlit": 1e-6, "camera": 1e-4, "vertex_colors": 1e-4, "tau": 1e-5, "p": 1e-5,
         "shape": 1e-5}
FLOOR = 1e-3
THRESHOLDS = {"pixel_mean": 1e-4, "pixel_max": 1e-2, "loss": 1e-5}
#: "camera": the orbit's azimuth, elevation, distance and fov_y along one direction; "vertex_colors":
#: per-vertex albedo (the image is linear in it: this checks the path of colour gradients to the
#: vertices' colours through the blend and the barycentrics)
PARAMS = ("vertices", "vertices_unlit", "camera", "vertex_colors", "tau", "p", "shape")
CAMERA_KEYS = ("azimuth", "elevation", "distance", "fov_y")
#: the checked parameters of the specs: name -> where it lives
SPEC_PARAMS = {"p": "tconorm", "shape": "distribution"}
#: shading per checked parameter: "vertices_unlit" moves vertices with ambient=1, diffuse=0 (no
#: normal-dependent colour), separating silhouette/blend gradients from the Lambert-shading path
UNLIT = {"ambient": 1.0, "diffuse": 0.0}
#: lit checks use a light in general position: with the default light (0, 0, −1) the scene's vertices
#: on its z = 0 plane of symmetry have normals exactly on the Lambert kink max(0, n·l) = 0, where
#: autograd returns a one-sided derivative and central differences the average of both sides
LIT = {"light_direction": (0.31, -0.47, -0.83)}
TAU_SAMPLES = 12  # per-pixel τ derivatives: outputs sampled (one backward pass each)
PIXEL_SAMPLES = 16  # per-pixel checks use the outputs with the largest |FD| (half) + random ones


def grid_scene():
    """The gradient-check scene: an icosphere (80 faces) slightly squashed, off-centre."""
    m = icosphere(1)
    return gendr.scenes.Mesh(m.vertices * np.array([0.9, 0.75, 0.8]) + np.array([0.08, -0.05, 0.0]), m.faces)


def rel_error(a, r, floor=FLOOR):
    return np.abs(a - r) / np.maximum(np.abs(r), floor)


# ------------------------------------------------------------------------------------------------
class TorchAdapter:
    """Reverse-mode derivatives through torch autograd: the torch backend, or any backend that takes
    and returns torch tensors with gradients (the drjit backend does, through ``dr.wrap``)."""

    def __init__(self, backend="torch"):
        import torch
        self.torch = torch
        self.name = backend

    def _renderer(self, inst, tau, H, W, shading=None, spec=None):
        dist, tcn = with_spec_param(inst, *(spec or (None, None)))
        return gendr.Renderer(dist, tcn, tau=tau, image_size=(H, W), backend=self.name,
                              eps=0.0, blend="softmax", gamma=0.05, max_pairs=1 << 20, **(shading or {}))

    def render(self, inst, mesh, cam_params, tau, H, W, verts=None, shading=None, spec=None, colors=None):
        """Image [H, W, 4] as NumPy float64 (no gradients); ``spec``: (name, value) of a spec
        parameter (:data:`SPEC_PARAMS`) to set (None: the instance's); ``colors``: per-vertex albedo."""
        torch = self.torch
        r = self._renderer(inst, tau, H, W, shading, spec)
        v = mesh.vertices if verts is None else verts
        img = r.render(torch.as_tensor(v, dtype=torch.float64), mesh.faces, _camera(cam_params),
                       vertex_colors=None if colors is None else torch.as_tensor(colors, dtype=torch.float64))
        return img.detach().numpy()[0]

    def per_pixel(self, inst, mesh, cam_params, tau, H, W, param, direction, index, shading=None):
        """d image.flat[index] / dt along ``direction`` for param vertices|camera|vertex_colors (one
        backward pass)."""
        torch = self.torch
        n = len(index)
        t = torch.zeros(n, dtype=torch.float64, requires_grad=True)
        v0 = torch.as_tensor(mesh.vertices, dtype=torch.float64)
        r = self._renderer(inst, tau, H, W, shading)
        colors = None
        if param.startswith("vertices"):
            u = torch.as_tensor(direction, dtype=torch.float64)
            verts = v0[None] + t[:, None, None] * u[None]
            cam = _camera(cam_params)
        elif param == "vertex_colors":
            u = torch.as_tensor(direction, dtype=torch.float64)
            colors = torch.as_tensor(base_colors(mesh))[None] + t[:, None, None] * u[None]
            verts, cam = v0[None].expand(n, -1, -1), _camera(cam_params)
        else:
            verts = v0
            cam = _camera({k: cam_params[k] + t * direction[i] for i, k in enumerate(CAMERA_KEYS)})
        img = r.render(verts, mesh.faces, cam, vertex_colors=colors)  # [n, H, W, 4]: copy b -> output index[b]
        sel = img.reshape(n, -1)[torch.arange(n), torch.as_tensor(np.asarray(index), dtype=torch.long)]
        sel.sum().backward()
        return t.grad.numpy().copy()

    def loss_grad(self, inst, mesh, cam_params, tau, H, W, weights, param, direction, shading=None):
        """∇L · direction for L = Σ weights ⊙ image."""
        torch = self.torch
        v = torch.tensor(mesh.vertices, dtype=torch.float64, requires_grad=param.startswith("vertices"))
        cp = {k: torch.tensor(float(val), dtype=torch.float64, requires_grad=(param == "camera"))
              for k, val in cam_params.items()}
        col = torch.tensor(base_colors(mesh), requires_grad=True) if param == "vertex_colors" else None
        tt = torch.tensor(float(tau), dtype=torch.float64, requires_grad=(param == "tau"))
        pp = None
        if param in SPEC_PARAMS:
            pp = torch.tensor(spec_value(inst, param), dtype=torch.float64, requires_grad=True)
        r = self._renderer(inst, tt, H, W, shading, (param, pp) if pp is not None else None)
        img = r.render(v, mesh.faces, _camera(cp), vertex_colors=col)
        L = (img[0] * torch.as_tensor(weights)).sum()
        L.backward()
        if param.startswith("vertices"):
            return float((v.grad.numpy() * direction).sum())
        if param == "camera":
            return float(sum(cp[k].grad.item() * direction[i] for i, k in enumerate(CAMERA_KEYS)))
        if param == "vertex_colors":
            return float((col.grad.numpy() * direction).sum())
        if param in SPEC_PARAMS:
            return float(pp.grad.item() * direction)
        return float(tt.grad.item() * direction)

    def tau_outputs(self, inst, mesh, cam_params, tau, H, W, index, shading=None, wrt="tau"):
        """d image[index] / dτ (``wrt="p"`` or ``"shape"``: / dθ of that spec parameter) for a few flat
        output indices (one backward each)."""
        torch = self.torch
        out = []
        if wrt in SPEC_PARAMS:
            tt = torch.tensor(spec_value(inst, wrt), dtype=torch.float64, requires_grad=True)
            r = self._renderer(inst, float(tau), H, W, shading, (wrt, tt))
        else:
            tt = torch.tensor(float(tau), dtype=torch.float64, requires_grad=True)
            r = self._renderer(inst, tt, H, W, shading)
        img = r.render(torch.as_tensor(mesh.vertices, dtype=torch.float64), mesh.faces, _camera(cam_params))
        flat = img[0].reshape(-1)
        for k in index:
            g, = torch.autograd.grad(flat[int(k)], tt, retain_graph=True)
            out.append(float(g))
        return np.array(out)


def spec_value(inst, name):
    """The instance's value (a float) of the spec parameter ``name`` (:data:`SPEC_PARAMS`)."""
    return float(getattr(inst, SPEC_PARAMS[name]).kwargs[name])


def with_spec_param(inst, name, value):
    """(distribution, T-conorm) of the instance, with the spec parameter ``name`` set to ``value``
    (a float or a tensor; ``name`` None: unchanged)."""
    dist, tcn = inst.distribution, inst.tconorm
    if name == "p":
        tcn = gendr.tconorm(tcn.name, p=value)
    elif name == "shape":
        dist = gendr.distribution(dist.name, reversed=dist.reversed, shift=dist.shift, squared=dist.squared,
                                  shape=value)
    return dist, tcn


def has_spec_param(inst, name):
    """Whether the check of spec parameter ``name`` applies: the instance has it, not on its domain's
    boundary (hamacher p = 0)."""
    if name not in getattr(inst, SPEC_PARAMS[name]).kwargs:
        return False
    return not (name == "p" and inst.tconorm.name == "hamacher" and spec_value(inst, "p") == 0.0)


def _camera(p):
    return gendr.orbit_camera(p["azimuth"], p["elevation"], p["distance"], fov_y=p["fov_y"])


def base_colors(mesh):
    """Per-vertex albedo of the colour check: smooth, in [0.2, 0.8], different per channel."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    return 0.5 + 0.3 * np.sin(3.0 * v + np.array([0.0, 1.0, 2.0]))


ADAPTERS = {"torch": lambda: TorchAdapter("torch"), "drjit": lambda: TorchAdapter("drjit")}


# ------------------------------------------------------------------------------------------------
@dataclass
class GradResult:
    backend: str
    instance: int
    name: str
    param: str
    step: float
    pixel_mean: float
    pixel_max: float
    loss_ad: float
    loss_fd: float
    loss_err: float
    max_abs_fd: float
    seconds: float
    #: the sampled outputs the per-pixel metric compared (at most PIXEL_SAMPLES / TAU_SAMPLES of them):
    #: analytic and finite-difference derivative, same order; the report's AD-vs-FD scatter plots them
    ad_samples: tuple = field(default=(), repr=False)
    fd_samples: tuple = field(default=(), repr=False)

    @property
    def passed(self) -> bool:
        return (self.pixel_mean <= THRESHOLDS["pixel_mean"] and self.pixel_max <= THRESHOLDS["pixel_max"]
                and self.loss_err <= THRESHOLDS["loss"] and math.isfinite(self.loss_ad))


def richardson(at, h):
    """Reference derivative of s -> at(s) at 0: Richardson-extrapolated central differences,
    (4·D(h/2) − D(h))/3 with D(k) = (at(k/2) − at(−k/2))/k. Fourth order: the h² truncation term of
    one central difference (which made strongly curved instances, e.g. levy+sq|schweizer_sklar(−4),
    need steps so small that round-off dominated small losses) cancels. Returns (derivative,
    at(h/2), at(−h/2))."""
    fp, fm = at(h / 2), at(-h / 2)
    d_half = (at(h / 4) - at(-h / 4)) / (h / 2)
    return (4.0 * d_half - (fp - fm) / h) / 3.0, fp, fm


def check_instance(adapter, inst, *, H=H_DEFAULT, W=W_DEFAULT, seed=0, params=PARAMS, keep_images=False):
    """Gradient check of one grid instance; returns ([GradResult], images for the report or None)."""
    mesh = grid_scene()
    rng = np.random.default_rng(seed + 7919 * inst.index)
    tau = TAU_SQUARED if inst.distribution.squared else TAU
    cam = {"azimuth": 25.0, "elevation": 15.0, "distance": 3.0, "fov_y": 40.0}
    weights = rng.standard_normal((H, W, 4))
    results, images = [], {}
    for param in params:
        if param in SPEC_PARAMS and not has_spec_param(inst, param):
            continue
        t0 = time.perf_counter()
        h = STEPS[param]
        shading = UNLIT if param == "vertices_unlit" else LIT
        if param.startswith("vertices"):
            u = rng.standard_normal(mesh.vertices.shape)
            u /= np.abs(u).max()
            at = lambda s: adapter.render(inst, mesh, cam, tau, H, W, verts=mesh.vertices + s * u, shading=shading)
        elif param == "camera":
            u = rng.standard_normal(len(CAMERA_KEYS))
            u /= np.abs(u).max()
            u *= np.array([1.0, 1.0, 0.05, 1.0])  # degrees, degrees, world units, degrees
            at = lambda s: adapter.render(inst, mesh, {k: cam[k] + s * u[i] for i, k in enumerate(CAMERA_KEYS)},
                                          tau, H, W, shading=shading)
        elif param == "vertex_colors":
            u = rng.standard_normal(mesh.vertices.shape)
            u /= np.abs(u).max()
            at = lambda s: adapter.render(inst, mesh, cam, tau, H, W, shading=shading, colors=base_colors(mesh) + s * u)
        elif param in SPEC_PARAMS:
            u = spec_value(inst, param)  # relative step: d/dt f(θ + t·θ)
            at = lambda s: adapter.render(inst, mesh, cam, tau, H, W, shading=shading, spec=(param, u * (1 + s)))
        else:
            u = tau  # relative step: d/dt f(τ + t·τ)
            at = lambda s: adapter.render(inst, mesh, cam, tau * (1 + s), H, W, shading=shading)
        fd, fp, fm = richardson(at, h)
        if param == "tau" or param in SPEC_PARAMS:
            idx = np.argsort(-np.abs(fd).reshape(-1))[:TAU_SAMPLES]
            ad = _scatter(adapter.tau_outputs(inst, mesh, cam, tau, H, W, idx, shading, wrt=param) * u, idx, fd.shape)
        else:
            idx = _sample_outputs(fd, rng)
            ad = _scatter(adapter.per_pixel(inst, mesh, cam, tau, H, W, param, u, idx, shading), idx, fd.shape)
        mask = np.zeros(fd.size, dtype=bool)
        mask[np.asarray(idx).reshape(-1)] = True  # the sampled outputs, all of them: a NaN / inf AD
        mask = mask.reshape(fd.shape)             # derivative there is an error, not a skipped sample
        err = np.where(np.isfinite(ad[mask]), rel_error(ad[mask], fd[mask]), np.inf)
        loss_fd = float((fd * weights).sum())
        loss_ad = adapter.loss_grad(inst, mesh, cam, tau, H, W, weights, param, u, shading)
        loss_err = abs(loss_ad - loss_fd) / max(abs(loss_fd), FLOOR)
        dt = time.perf_counter() - t0
        results.append(GradResult(adapter.name, inst.index, inst.name, param, h, float(err.mean()), float(err.max()),
                                  loss_ad, loss_fd, float(loss_err), float(np.abs(fd).max()), dt,
                                  tuple(map(float, ad[mask])), tuple(map(float, fd[mask]))))
        if keep_images:
            images[param] = (fp, ad, fd)
    return results, (images if keep_images else None)


def _sample_outputs(fd, rng):
    flat = np.abs(fd).reshape(-1)
    k = min(PIXEL_SAMPLES // 2, flat.size)
    top = np.argsort(-flat, kind="stable")[:k]
    rest = np.setdiff1d(np.arange(flat.size), top)
    extra = rng.choice(rest, size=min(PIXEL_SAMPLES - k, rest.size), replace=False)
    return np.concatenate([top, extra])


def _scatter(values, idx, shape):
    out = np.full(int(np.prod(shape)), np.nan)
    out[idx] = values
    return out.reshape(shape)


def differentiable_instances():
    return [i for i in gendr.paper_grid() if i.distribution.differentiable and i.tconorm.differentiable]


#: the quick set: one instance per kind of distribution and aggregation that runs fast
QUICK_NAMES = ("uniform|max", "logistic|probabilistic", "gaussian|einstein", "cauchy|yager(p=2)",
               "exponential+rev|probabilistic", "uniform+sq|probabilistic",
               # the two that exposed coverage-precision bugs (docs/validation.md §5)
               "exponential+rev+sq|probabilistic", "gaussian|aczel_alsina(p=0.25)",
               # with the two above (yager, aczel_alsina), one of each parametric family for ∂/∂p
               "logistic|hamacher(p=4)", "gaussian|frank(p=10)", "laplace|dombi(p=2)",
               "logistic+sq|schweizer_sklar(p=-2)",
               # ∂/∂shape of the one parametric distribution (the paper's best instance family)
               "gamma(shape=0.5)+rev|probabilistic")


def instance_by_index(index):
    """The grid instance with this index (for worker processes, which get indices, not objects)."""
    return gendr.paper_grid()[index]


def select_instances(spec):
    """``spec``: "all", "quick" (a spread of distributions × T-conorms), or a list/comma string of indices."""
    grid = differentiable_instances()
    by_index = {i.index: i for i in grid}
    if spec in (None, "quick"):
        return [i for i in grid if i.name in QUICK_NAMES]
    if spec == "all":
        return grid
    if isinstance(spec, str):
        spec = [s for s in spec.split(",") if s.strip()]
    out = []
    for s in spec:
        try:
            k = int(s)
        except (TypeError, ValueError):
            raise gendr.ParameterError(f"instance {s!r} must be an integer index of gendr.paper_grid(), 'all' or 'quick'") from None
        if k not in by_index:
            raise gendr.ParameterError(f"instance index {k} is not a differentiable instance of gendr.paper_grid() (0..1241)")
        out.append(by_index[k])
    return out


PARITY_TOL = 1e-9  # float64 forward images of two backends


def backend_parity(backends, instances, H=H_DEFAULT, W=W_DEFAULT):
    """Forward images of every instance on every backend vs the first backend: max abs difference."""
    if len(backends) < 2:
        return []
    mesh = grid_scene()
    cam = gendr.orbit_camera(25.0, 15.0, 3.0)
    out = []
    for inst in instances:
        tau = TAU_SQUARED if inst.distribution.squared else TAU
        imgs = {}
        for b in backends:
            try:
                r = gendr.Renderer(inst.distribution, inst.tconorm, tau=tau, image_size=(H, W), backend=b, eps=0.0,
                                   blend="softmax", gamma=0.05)
                imgs[b] = np.asarray(r.to_numpy(r.render(mesh.vertices, mesh.faces, cam)), dtype=np.float64)
            except Exception as e:
                imgs[b] = f"{type(e).__name__}: {e}"[:300]
        ref = imgs[backends[0]]
        for b in backends[1:]:
            row = {"instance": inst.index, "name": inst.name, "backends": f"{backends[0]} vs {b}"}
            if isinstance(ref, str) or isinstance(imgs[b], str):
                row.update(max_abs_diff=float("nan"), error=ref if isinstance(ref, str) else imgs[b], passed=False)
            else:
                d = float(np.abs(imgs[b] - ref).max())
                row.update(max_abs_diff=d, passed=d <= PARITY_TOL)
            out.append(row)
    return out
