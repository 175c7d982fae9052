"""Shared pieces of the experiments: instance selection, meshes, losses, geometry, provenance.

Everything here works on torch tensors on the CPU (or the device of the inputs); the renderer is
the public :class:`gendr.Renderer` with any registered backend (default ``"torch"``).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import platform
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

import gendr
from gendr.errors import InputValueError, ParameterError

__all__ = ["instance_from_config", "grid_instance", "make_renderer", "hard_renderer", "renderer_tau",
           "load_target_mesh", "soft_iou_loss", "iou_loss_per_view", "mesh_laplacian", "laplacian_loss", "flatten_edges",
           "flatten_loss", "rotation_angle_deg", "axis_angle_to_matrix", "config_hash", "versions",
           "log_tau_schedule", "PAPER_DATA_ENV", "paper_data_dir", "resolve_data_path", "load_template",
           "source_hash", "cpu_info", "provenance", "file_digest", "data_digests", "preset_config", "check_config",
           "CONFIG_DOMAINS", "set_threads"]


# ------------------------------------------------------------------------------------------------
# instances
# ------------------------------------------------------------------------------------------------

@lru_cache(maxsize=1)
def _grid():
    return gendr.paper_grid()


def grid_instance(index: int):
    """Instance ``index`` of :func:`gendr.paper_grid` (0 <= index < 1242)."""
    g = _grid()
    # (a bool is an int to Python: True would be instance 1)
    if not (isinstance(index, (int, np.integer)) and not isinstance(index, bool) and 0 <= index < len(g)):
        raise ParameterError(f"instance index {index!r} must be an integer in [0, {len(g) - 1}]")
    return g[int(index)]


def instance_from_config(cfg: dict):
    """``(distribution, tconorm, label)`` from a config: ``instance`` (a grid index) or
    ``distribution`` / ``tconorm`` as dicts of :func:`gendr.distribution` / :func:`gendr.tconorm`
    keyword arguments (``{"name": "logistic", "squared": true}``) or plain names."""
    if cfg.get("instance") is not None:
        inst = grid_instance(cfg["instance"])  # (int() made 3.7, "12" and True instances 3, 12 and 1)
        return inst.distribution, inst.tconorm, inst.name
    d, t = cfg.get("distribution", "logistic"), cfg.get("tconorm", "probabilistic")
    dist = gendr.distribution(**d) if isinstance(d, dict) else gendr.distribution(d)
    tcn = gendr.tconorm(**t) if isinstance(t, dict) else gendr.tconorm(t)
    return dist, tcn, f"{dist.label()}|{tcn.label()}"


def renderer_tau(width: float, squared: bool) -> float:
    """The Renderer's ``tau`` for a blur *width* in screen units: ``width`` for plain distributions,
    ``width**2`` for squared ones (their argument is d·|d|/τ), so both blur over the same distance."""
    return float(width) ** 2 if squared else float(width)


def preset_config(experiment: str, presets: dict, config: dict | None, overrides: dict) -> dict:
    """The full config of a run: the preset named by ``protocol`` (in ``overrides`` or ``config``;
    default ``"quick"``), then ``config``, then ``overrides``. Unknown protocols or keys are a
    :class:`~gendr.errors.ParameterError`."""
    given = dict(config or {}, **overrides)
    name = given.get("protocol", "quick")
    if name not in presets:
        raise ParameterError(f"unknown {experiment} protocol {name!r}; known: {sorted(presets)}")
    cfg = dict(presets[name])
    bad = sorted(set(given) - set(cfg))
    if bad:
        raise ParameterError(f"unknown {experiment} config keys {bad}; known: {sorted(cfg)}")
    cfg.update(given)
    check_config(experiment, cfg)
    return cfg


def _is_int(v):
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


#: config key -> (test, what it must be): checked for every run before it starts (a value outside
#: would end in an error row, or worse, in a "result" of 0 steps)
CONFIG_DOMAINS = {
    **{k: (lambda v: _is_int(v) and v >= 1, "an integer >= 1")
       for k in ("steps", "views", "image_size", "pairs")},
    **{k: (lambda v: _is_int(v) and v >= 0, "an integer >= 0") for k in ("subdivisions", "seed")},
    **{k: (lambda v: _is_num(v) and v > 0, "a finite number > 0")
       for k in ("lr", "tau", "tau_start", "tau_end", "distance", "template_scale", "success_degrees",
                 "distance_min", "distance_max", "init_distance_min", "init_distance_max")},
    **{k: (lambda v: _is_num(v) and v >= 0, "a finite number >= 0") for k in ("lambda_lap", "lambda_flat")},
    **{k: (lambda v: _is_num(v) and 0 < v < 180, "in (0, 180) degrees") for k in ("fov_y", "fov_min", "fov_max")},
    **{k: (lambda v: _is_num(v) and 0 <= v <= 180, "in [0, 180] degrees")
       for k in ("angle_min", "angle_max", "init_view_angle_min", "init_view_angle_max")},
    "elevation": (_is_num, "a finite number (degrees)"),
    "instance": (lambda v: v is None or (_is_int(v) and v >= 0), "None or an integer >= 0 (a grid index)"),
    "eps": (lambda v: _is_num(v) and 0 <= v < 1, "in [0, 1)"),
    "cutoff": (lambda v: v is None or (_is_num(v) and v > 0), "None or a number > 0"),
    "metric": (lambda v: v in ("final", "best"), "'final' or 'best'"),
}


def check_config(experiment: str, cfg: dict) -> None:
    """:class:`~gendr.errors.ParameterError` naming the first setting of ``cfg`` outside its domain
    (:data:`CONFIG_DOMAINS`), or a range whose minimum exceeds its maximum."""
    for k, (ok, want) in CONFIG_DOMAINS.items():
        if k in cfg and not ok(cfg[k]):
            raise ParameterError(f"{experiment} setting {k}={cfg[k]!r} must be {want}")
    for lo, hi in (("angle_min", "angle_max"), ("distance_min", "distance_max"), ("fov_min", "fov_max"),
                   ("init_distance_min", "init_distance_max"), ("init_view_angle_min", "init_view_angle_max")):
        if lo in cfg and hi in cfg and cfg[lo] > cfg[hi]:
            raise ParameterError(f"{experiment} settings {lo}={cfg[lo]!r} > {hi}={cfg[hi]!r}: not a range")


def make_renderer(dist, tcn, tau, image_size, *, backend="torch", eps=1e-4, cutoff=None, **backend_options):
    """A silhouette-only renderer (``blend=None``): alpha in channel 3. ``cutoff``: the GenDR reference's
    distance cut-off (``Renderer(cutoff=...)``; None = exact). ``backend_options`` go to the backend.
    Dr.Jit renders are frozen unless ``freeze=False`` is given: an experiment renders the same shapes
    every step, and a replay skips the Python tracing of the loops (same kernels, so the same numbers;
    shape runs of the paper protocol 4–16 % faster, docs/performance.md)."""
    if backend == "drjit":
        backend_options.setdefault("freeze", True)
    return gendr.Renderer(dist, tcn, tau=tau, image_size=image_size, backend=backend, eps=eps, blend=None,
                          cutoff=cutoff, **backend_options)


def hard_renderer(image_size, backend="torch", *, freeze=False):
    """The exact silhouette renderer (heaviside + or, alpha in channel 3). ``freeze`` (Dr.Jit only):
    replay its renders, for a renderer used every step (the shape step's hard IoU); a one-off
    render (a reference silhouette) would only pay for the recording."""
    return make_renderer("heaviside", "or", 1.0, image_size, backend=backend, eps=0.0,
                         **({"freeze": freeze} if backend == "drjit" else {}))


# ------------------------------------------------------------------------------------------------
# data: built-in scenes, mesh files, the paper's user-supplied files ("paper:NAME")
# ------------------------------------------------------------------------------------------------

#: environment variable naming the directory that holds the paper's data files (airplane.obj,
#: teapot.obj, sphere_642.obj, cameras.npy, ... of the GenDR repository's ``experiments/data``)
PAPER_DATA_ENV = "GENDR_PAPER_DATA"
PAPER_PREFIX = "paper:"


def paper_data_dir() -> Path:
    """``$GENDR_PAPER_DATA``, else ``~/.cache/gendr/paper_data``. gendr never ships or downloads these
    files: the user copies them there (see docs/experiments.md)."""
    env = os.environ.get(PAPER_DATA_ENV)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "gendr" / "paper_data"


def resolve_data_path(name: str) -> Path:
    """``"paper:FILE"`` -> the file in :func:`paper_data_dir`; anything else is a path. Raises
    :class:`~gendr.errors.InputValueError` naming the file and the directory when it is missing."""
    if name.startswith(PAPER_PREFIX):
        d = paper_data_dir()
        p = d / name[len(PAPER_PREFIX):]
        if not p.is_file():
            raise InputValueError(
                f"{name!r}: {p} does not exist. The paper's meshes are user-supplied: copy the GenDR "
                f"repository's experiments/data files into {d} (or point ${PAPER_DATA_ENV} at them); "
                f"see docs/experiments.md")
        return p
    return Path(name)


def file_digest(path) -> str:
    """sha256 (first 16 hex digits) of a file's bytes: which data a row was computed on."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def load_target_mesh(name_or_path: str, normalize: bool = True):
    """A built-in scene (``gendr.scenes.SCENES``) or a mesh file (a path or ``"paper:FILE"``), scaled
    into the unit ball when ``normalize`` (the paper uses its meshes as they are: ``normalize=False``)."""
    from gendr import scenes
    if name_or_path in scenes.SCENES:
        return scenes.get_scene(name_or_path)
    path = resolve_data_path(name_or_path)
    if not path.exists() and not path.suffix:
        # (a mistyped scene name read as a missing mesh file)
        raise InputValueError(f"target {name_or_path!r} is neither a built-in scene ({', '.join(sorted(scenes.SCENES))}) "
                              f"nor an existing mesh file")
    mesh = scenes.merge_vertices(scenes.load_mesh(path))
    return scenes.normalize(mesh) if normalize else mesh


def data_digests(cfg: dict) -> dict:
    """sha256 prefixes of the data files a config reads (``target``, ``template``; built-in scenes
    and the icosphere template have none)."""
    from gendr import scenes
    from .targets import images_path, is_images_target
    out = {}
    if is_images_target(cfg.get("target")):
        out["target"] = file_digest(images_path(cfg["target"]))
    for key in ("target", "template"):
        name = cfg.get(key)
        if key in out:
            continue
        if isinstance(name, str) and name not in scenes.SCENES and name != "icosphere":
            out[key] = file_digest(resolve_data_path(name))
    return out


def load_template(spec: str, scale: float):
    """The shape experiment's template: ``"icosphere:S"`` (gendr's icosphere, subdivisions S) or a
    mesh file (``"paper:sphere_642.obj"``), vertices merged, times ``scale``."""
    from gendr.scenes import Mesh, icosphere
    if spec.startswith("icosphere:"):
        m = icosphere(int(spec.split(":", 1)[1]))
    else:
        m = load_target_mesh(spec, normalize=False)
    return Mesh(np.asarray(m.vertices) * float(scale), np.asarray(m.faces))


# ------------------------------------------------------------------------------------------------
# losses
# ------------------------------------------------------------------------------------------------

def finite_update(opt, loss: torch.Tensor) -> bool:
    """Backward and one update of ``opt``, unless the loss or a gradient is not finite (Adam would
    turn the parameters into NaN): then nothing is updated. Returns whether ``opt`` stepped."""
    if not torch.isfinite(loss):
        return False
    opt.zero_grad()
    loss.backward()
    if not all(bool(torch.isfinite(p.grad).all()) for g in opt.param_groups for p in g["params"]):
        return False
    opt.step()
    return True


def iou_loss_per_view(pred: torch.Tensor, target: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """``[B]`` soft IoU loss 1 − Σ(a·t)/Σ(a + t − a·t) of each view (sums over H, W)."""
    dims = tuple(range(1, pred.dim()))
    inter = (pred * target).sum(dims)
    union = (pred + target - pred * target).sum(dims) + eps
    return 1.0 - inter / union


def soft_iou_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Soft IoU loss of silhouettes ``[B, H, W]``, computed per view and averaged over the views
    (as SoftRas' ``neg_iou_loss``, which the paper's shape experiment uses)."""
    return iou_loss_per_view(pred, target).mean()


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """``[E, 2]`` unique undirected edges (i < j) of a triangle mesh."""
    f = np.asarray(faces)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = np.sort(e, axis=1)
    return np.unique(e, axis=0)


def mesh_laplacian(num_vertices: int, faces: np.ndarray, dtype=torch.float32) -> torch.Tensor:
    """Uniform graph Laplacian L = I − D⁻¹A as a dense ``[V, V]`` tensor (templates are small)."""
    e = mesh_edges(faces)
    A = np.zeros((num_vertices, num_vertices))
    A[e[:, 0], e[:, 1]] = 1.0
    A[e[:, 1], e[:, 0]] = 1.0
    deg = A.sum(1, keepdims=True)
    L = np.eye(num_vertices) - A / np.where(deg > 0, deg, 1.0)
    return torch.tensor(L, dtype=dtype)


def laplacian_loss(vertices: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
    """Σ_v ||(L x)_v||² (sum over vertices and coordinates; mean over a leading batch)."""
    d = L @ vertices if vertices.dim() == 2 else torch.matmul(L, vertices)
    return d.pow(2).sum((-1, -2)).mean()


def flatten_edges(faces: np.ndarray):
    """For every interior edge (shared by exactly two faces): ``(v0, v1, a, b)`` index arrays, the
    edge's end points and the two opposite vertices."""
    f = np.asarray(faces)
    opp = {}
    for tri in f:
        for k in range(3):
            i, j, o = int(tri[k]), int(tri[(k + 1) % 3]), int(tri[(k + 2) % 3])
            opp.setdefault((min(i, j), max(i, j)), []).append(o)
    rows = [(i, j, o[0], o[1]) for (i, j), o in opp.items() if len(o) == 2]
    r = np.array(rows, dtype=np.int64).reshape(-1, 4)
    return tuple(torch.tensor(r[:, k]) for k in range(4))


def flatten_loss(vertices: torch.Tensor, edges, eps: float = 1e-6) -> torch.Tensor:
    """Σ_edges (cos θ + 1)², θ the dihedral angle at the edge measured between the two faces (θ = π,
    cos θ = −1, for a flat neighbourhood), as SoftRas' ``FlattenLoss``. ``vertices``: [V,3] or [B,V,3]."""
    v0, v1, a, b = edges
    x = vertices
    p0, p1, pa, pb = x[..., v0, :], x[..., v1, :], x[..., a, :], x[..., b, :]
    e = p1 - p0
    e_len2 = (e * e).sum(-1, keepdim=True) + eps
    # components of (pa − p0) and (pb − p0) orthogonal to the edge
    ua, ub = pa - p0, pb - p0
    ua = ua - (ua * e).sum(-1, keepdim=True) / e_len2 * e
    ub = ub - (ub * e).sum(-1, keepdim=True) / e_len2 * e
    cos = (ua * ub).sum(-1) / (ua.norm(dim=-1) * ub.norm(dim=-1) + eps)
    out = (cos + 1.0).pow(2).sum(-1)
    return out.mean() if out.dim() else out


# ------------------------------------------------------------------------------------------------
# rotations
# ------------------------------------------------------------------------------------------------

class _Rodrigues(torch.autograd.Function):
    """R = exp([ω]×) = cos θ·I + (sin θ/θ)·[ω]× + ((1 − cos θ)/θ²)·ωωᵀ, θ = |ω|, and its gradient in
    closed form, both evaluated in float64 on the host (Python floats) and rounded once to the
    input's dtype: one autograd node, ~0.1 ms forward + backward where kornia's ~90 small ops took
    ~1 ms in the pose step, and correctly rounded in float32 (kornia errs by up to 8e-8)."""

    @staticmethod
    def forward(ctx, w):
        x, y, z = w.detach().reshape(3).tolist()
        t2 = x * x + y * y + z * z
        if t2 < 0.0025:   # θ < 0.05: Taylor series (a, h to θ⁸, da, dh to θ⁶; the closed forms cancel near 0)
            a = 1.0 - t2 / 6 * (1.0 - t2 / 20 * (1.0 - t2 / 42 * (1.0 - t2 / 72)))       # sin θ / θ
            h = 0.5 * (1.0 - t2 / 12 * (1.0 - t2 / 30 * (1.0 - t2 / 56 * (1.0 - t2 / 90))))  # (1 − cos θ)/θ²
            da = -1 / 3 + t2 * (1 / 30 + t2 * (-1 / 840 + t2 / 45360))              # a'(θ)/θ
            dh = -1 / 12 + t2 * (1 / 180 + t2 * (-1 / 6720 + t2 / 453600))          # h'(θ)/θ
            cos = 1.0 - h * t2
        else:
            t = math.sqrt(t2)
            sin, cos = math.sin(t), math.cos(t)
            a, h = sin / t, 2.0 * (math.sin(0.5 * t) / t) ** 2
            da, dh = (t * cos - sin) / (t2 * t), (t * sin - 2.0 * (1.0 - cos)) / (t2 * t2)
        ctx.coefficients = (x, y, z, t2, a, h, da, dh)
        ctx.shape = w.shape
        R = [[cos + h * x * x, h * x * y - a * z, h * x * z + a * y],
             [h * y * x + a * z, cos + h * y * y, h * y * z - a * x],
             [h * z * x - a * y, h * z * y + a * x, cos + h * z * z]]
        return torch.tensor(R, dtype=w.dtype, device=w.device)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_R):
        x, y, z, t2, a, h, da, dh = ctx.coefficients
        w = (x, y, z)
        G = grad_R.detach().tolist()  # Python floats: float64 arithmetic below on any dtype and device
        # ⟨G, ∂R/∂ω_k⟩ with ∂[ω]×/∂ω_k = [e_k]× and ⟨G, [v]×⟩ = v·g, g = (G₃₂ − G₂₃, G₁₃ − G₃₁, G₂₁ − G₁₂)
        g = (G[2][1] - G[1][2], G[0][2] - G[2][0], G[1][0] - G[0][1])
        trace = G[0][0] + G[1][1] + G[2][2]
        Gw = [G[i][0] * x + G[i][1] * y + G[i][2] * z for i in range(3)]
        GTw = [G[0][i] * x + G[1][i] * y + G[2][i] * z for i in range(3)]
        radial = da * (x * g[0] + y * g[1] + z * g[2]) + dh * (x * Gw[0] + y * Gw[1] + z * Gw[2] - t2 * trace)
        grad_w = [radial * w[k] + a * g[k] + h * (Gw[k] + GTw[k] - 2.0 * trace * w[k]) for k in range(3)]
        return torch.tensor(grad_w, dtype=grad_R.dtype, device=grad_R.device).reshape(ctx.shape)


def axis_angle_to_matrix(w: torch.Tensor) -> torch.Tensor:
    """Rotation vector ``w`` [3] (axis · angle in radians) -> ``[3, 3]`` rotation matrix (Rodrigues'
    formula), differentiable, finite gradient at ω = 0; same dtype and device as ``w``."""
    return _Rodrigues.apply(w)


def rotation_angle_deg(Ra, Rb) -> float:
    """Angular distance between two rotations: the angle of ``Ra·Rbᵀ``, arccos((tr − 1)/2), in degrees
    (the geodesic distance on SO(3), 0..180)."""
    Ra = np.asarray(Ra.detach().cpu() if isinstance(Ra, torch.Tensor) else Ra, dtype=np.float64)
    Rb = np.asarray(Rb.detach().cpu() if isinstance(Rb, torch.Tensor) else Rb, dtype=np.float64)
    c = (np.trace(Ra @ Rb.T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly distributed rotation matrix (from a random unit quaternion w, x, y, z)."""
    from kornia.geometry.conversions import quaternion_to_rotation_matrix
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return quaternion_to_rotation_matrix(torch.tensor(q[None], dtype=torch.float64))[0].numpy()


def rotation_about(axis, degrees: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    return axis_angle_to_matrix(torch.tensor(a * math.radians(degrees), dtype=torch.float64)).numpy()


def log_tau_schedule(step: int, steps: int, start: float, end: float) -> float:
    """τ at ``step`` of ``steps``, decayed logarithmically (geometrically) from ``start`` to ``end``."""
    if steps <= 1:
        return float(start)
    t = step / (steps - 1)
    return float(math.exp(math.log(start) + t * (math.log(end) - math.log(start))))


# ------------------------------------------------------------------------------------------------
# provenance
# ------------------------------------------------------------------------------------------------

def config_hash(cfg: dict) -> str:
    """Stable 16-hex-digit key of a config (canonical JSON: sorted keys, no whitespace)."""
    text = json.dumps(cfg, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@lru_cache(maxsize=1)
def versions() -> dict:
    import gendr_experiments
    out = {"gendr": gendr.__version__, "gendr_experiments": gendr_experiments.__version__,
           "torch": torch.__version__, "numpy": np.__version__, "python": platform.python_version()}
    try:
        import drjit
        out["drjit"] = drjit.__version__
    except ImportError:  # pragma: no cover - drjit is optional
        pass
    return out


def _package_dir(module: str) -> Path:
    import importlib.util
    spec = importlib.util.find_spec(module)
    if spec is None or not spec.submodule_search_locations:
        raise ParameterError(f"cannot locate the source of package {module!r}")
    return Path(list(spec.submodule_search_locations)[0])


@lru_cache(maxsize=None)
def source_hash(backend: str = "torch") -> str:
    """16 hex digits of sha256 over the Python source that computes a result: the packages ``gendr``,
    the backend's package (from its entry point) and ``gendr_experiments`` (every ``*.py``, by
    relative path and bytes). Any edit to that code changes it; docs, tests and benchmarks do not.
    Read from disk once per process (:func:`read_source_hash` reads it again)."""
    return read_source_hash(backend)


def read_source_hash(backend: str = "torch") -> str:
    """:func:`source_hash` read from the files now, not cached: a run compares it with the hash its
    sweep started with, so that an edit made while it ran cannot go unnoticed."""
    eps = gendr.available_backends()
    if backend not in eps:
        raise ParameterError(f"unknown backend {backend!r}; registered: {sorted(eps)}")
    h = hashlib.sha256()
    for module in ("gendr", eps[backend].value.split(":")[0].split(".")[0], "gendr_experiments"):
        root = _package_dir(module)
        for f in sorted(root.rglob("*.py")):
            h.update(f"{module}/{f.relative_to(root).as_posix()}\0".encode())
            h.update(f.read_bytes())
            h.update(b"\0")
    return h.hexdigest()[:16]


@lru_cache(maxsize=1)
def git_commit() -> str | None:
    """The git commit of the checkout gendr runs from (``+dirty`` with uncommitted changes to the
    tracked code of gendr, the backends or the experiments), or None outside a git checkout. A convenience beside :func:`source_hash`, which
    is what resume and verify compare."""
    import subprocess
    root = _package_dir("gendr").parent
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()
        # dirty = uncommitted changes to the code source_hash covers (results files being appended
        # to by a running sweep are not code)
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no", "--",
                                "gendr", "backends", "experiments/gendr_experiments"],
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("+dirty" if dirty else "")


def set_threads(backend: str, threads: int | None) -> None:
    """Give ``threads`` compute threads to the backend that renders (None: its default). With
    ``backend="drjit"`` torch runs one thread: its share of a step (losses, Adam) is small, and its
    idle OpenMP workers spin-wait after each op, taking cores from Dr.Jit's kernels (paper shape
    step, τ = 0.003, Dr.Jit 2 threads: 72.7 ms/step beside 2 torch threads, 53.5 ms beside 1)."""
    if threads is not None and threads < 1:
        raise ParameterError(f"threads must be a positive integer, got {threads!r}")
    if backend == "drjit":
        torch.set_num_threads(1)
        if threads is not None:
            import drjit
            drjit.set_thread_count(threads)
    elif threads is not None:
        torch.set_num_threads(threads)


@lru_cache(maxsize=1)
def cpu_info() -> dict:
    """The CPU a run used: ``model`` (its name, as the OS reports it) and ``simd``, torch's CPU
    capability ("AVX512", "AVX2", ...). The SIMD level decides the vector width that Dr.Jit's LLVM
    backend compiles for and the kernels torch picks, so it changes float32 summation orders: a run is
    bit-reproducible only on the same level (code, threads and versions equal)."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            model = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), model)
    except OSError:  # not Linux
        pass
    return {"model": model, "simd": torch.backends.cpu.get_cpu_capability()}


def provenance(backend: str, device: str = "cpu", code_hash: str | None = None) -> dict:
    """What a result row records about the code and machine that made it: versions, the source hash
    (``code_hash``, default :func:`source_hash`), backend, device ("cpu", or "cuda" with the GPU's
    name), dtype, thread counts and the CPU (:func:`cpu_info`)."""
    out = {"code_hash": code_hash or source_hash(backend), "backend": backend, "device": device, "dtype": "float32",
           "torch_threads": torch.get_num_threads(), "machine": platform.machine(), "cpu": cpu_info(),
           "git_commit": git_commit(), "versions": versions()}
    if backend == "drjit":
        import drjit
        out["drjit_threads"] = drjit.thread_count()
    if device == "cuda":
        out["gpu"] = torch.cuda.get_device_name() if torch.cuda.is_available() else None
    return out
