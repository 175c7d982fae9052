"""The :class:`Renderer` facade: validated settings + a backend plug-in that does the work."""
from __future__ import annotations

import copy
import inspect
import math
import numbers
from dataclasses import dataclass, replace
from functools import lru_cache
from importlib import metadata
from typing import Any

import numpy as np

from .cameras import Camera
from .distributions import Distribution, distribution as make_distribution
from .gbuffer import GBuffer
from .textures import check_settings as _check_texture_settings, check_textured_inputs
from .errors import (BackendUnavailableError, DTypeError, InputValueError, ParameterError,
                     ShapeError, UnknownNameError, require_finite)
from .params import plain_number
from .tconorms import TConorm, tconorm as make_tconorm

BLENDS = ("softmax", "hard", None)
ENTRY_POINT_GROUP = "gendr.backends"
#: Lambert's kink max(0, n·(−l)): both backends treat |n·(−l)| <= LAMBERT_KINK_ULPS·(machine eps of
#: the dtype) as exactly 0, where the clamp's gradient passes (torch.clamp semantics). A mesh with
#: vertices on a plane of symmetry perpendicular to the light (an icosphere's z = 0 equator under the
#: default light (0, 0, −1)) has n·(−l) = 0 there up to the rounding of the vertex-normal sums, whose
#: sign depends on the summation order (the backends' orders differ); without the snap, each backend
#: picked a different one-sided derivative. Colours change by at most diffuse·LAMBERT_KINK_ULPS·eps.
LAMBERT_KINK_ULPS = 256

#: a face whose world edges e1, e2 have |e1 × e2| <= ZERO_AREA_ULPS·(machine eps)·|e1|·|e2| (corners
#: collinear within rounding; sin of its angle <= 7.6e-6 in float32) has no normal: its cross product
#: is rounding noise of either sign (FMA or not, summation order), so it lit such a face or left it
#: dark by chance, differently per backend and device. Its face normal is 0 in both backends: flat
#: shading gives it the ambient term only, and it adds nothing to its vertices' normals (coverage
#: does not use it)
ZERO_AREA_ULPS = 64

#: near-plane clipped renders: an edge from a corner farther than this from the image centre (screen
#: units, max norm) to a nearer corner is measured from the nearer one, in both backends alike (the
#: rounding of a pixel's distance to an edge is ~ulp of the corner it is measured from; clipped
#: corners lie at ~x/near). Closer corners keep the plain rule, so unclipped renders are unchanged
FAR_CORNER = 4.0


def softmax_min_coverage(dtype: str) -> float:
    """The smallest coverage p that the softmax blend weighs (``dtype`` "float32" or "float64"); a
    smaller p counts as 0. It is the dtype's smallest normal number over its epsilon (~1e-292 in
    float64, ~1e-31 in float32): below it, a weight times a colour can fall into the subnormal
    range, which Dr.Jit's kernels may flush to 0 (a colour channel of a pixel far from every face
    came out 0 at eps = 0); above it, what flushing can lose is below one ulp of the colour."""
    fi = np.finfo(dtype)
    return float(fi.tiny / fi.eps)


def check_screen_reach(reach: float, dtype: str) -> None:
    """InputValueError where a face's projected corner lies so far out (``reach``: the largest
    |X| or |Y|, screen units) that its squared edge lengths overflow ``dtype`` ("float32" or
    "float64"): the backends would render garbage, each its own. Reached by absurd scales (float32
    vertices ~1e20, fov_y ~1e-30°) or a near plane ~1e-18 of the scene's size."""
    limit = math.sqrt(np.finfo(dtype).max) / 16.0  # (2·limit)² · 2 stays finite
    if not reach <= limit:
        raise InputValueError(f"a face projects to {reach:.3g} screen units, beyond what {dtype} edge lengths "
                              f"can hold ({limit:.3g}): render in float64, or bring the mesh, the field of view "
                              f"or the near plane into range")


@dataclass(frozen=True, eq=False)
class RenderSettings:
    """Everything that defines an image besides the mesh and the camera (validated, frozen).

    Distances (and τ) are in screen units: one unit = H/2 pixels, NDC for square images (DESIGN.md §3).
    Built by :class:`Renderer` (its ``settings``) from its arguments; the fields mirror them.

    >>> import gendr
    >>> s = gendr.Renderer(tau=0.02, image_size=(8, 6), backend="torch").settings
    >>> s.image_size, s.tau_value, s.distribution.label(), s.tconorm.label()
    ((8, 6), 0.02, 'logistic', 'probabilistic')
    """

    distribution: Distribution
    tconorm: TConorm
    tau: Any  # float > 0, or a 0-d backend tensor (may require grad)
    image_size: tuple[int, int]
    eps: float
    blend: str | None
    gamma: float
    background_eps: float
    background: tuple[float, float, float]
    ambient: float
    diffuse: float
    light_direction: tuple[float, float, float]
    cull_backfaces: bool
    max_pairs: int
    cutoff: float | None = None
    texture_filter: str = "bilinear"
    texture_wrap: str = "repeat"

    @property
    def tau_value(self) -> float:
        return _scalar(self.tau)

    def culling_distance(self, tau_value: float) -> float:
        """Distance outside a face beyond which it contributes nothing (screen units; ``inf``:
        none): the distribution's eps radius, or the reference cut-off sqrt(cutoff·τ) if smaller."""
        r = self.distribution.culling_distance(self.eps, tau_value)
        return r if self.cutoff is None else min(r, math.sqrt(self.cutoff * tau_value))

    def cutoff_argument(self, ops, tau):
        """The argument x = d/τ (or −d²/τ, squared) at the reference cut-off distance
        d = −sqrt(cutoff·τ): pairs with x <= this are dropped (None: no cut-off). ``tau``: a
        backend scalar, so that a new τ changes a value, not the code."""
        if self.cutoff is None:
            return None
        return -self.cutoff if self.distribution.squared else -ops.sqrt(self.cutoff / tau)


def _number(owner, name, value, *, positive=False, nonneg=False, integer=False):
    """``value`` (a Python or NumPy number) as a Python int/float, checked; ParameterError naming it."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral if integer else numbers.Real):
        kind = "an integer" if integer else "a number"
        raise ParameterError(f"{owner} parameter {name}={value!r} must be {kind}")
    v = int(value) if integer else float(value)
    if not math.isfinite(v) or (positive and v <= 0) or (nonneg and v < 0):
        want = "> 0" if positive else (">= 0" if nonneg else "finite")
        raise ParameterError(f"{owner} parameter {name}={value!r} is out of domain: expected {want}")
    return v


def _triple(owner, name, value):
    try:
        t = tuple(plain_number(v) for v in value)
    except TypeError:
        t = ()
    t = () if None in t else t
    if len(t) != 3 or not all(math.isfinite(v) for v in t):
        raise ParameterError(f"{owner} parameter {name}={value!r} must be 3 finite numbers")
    return t


def _render_batch(verts, camera) -> int:
    """B of a render: the broadcast of the vertex batch and the camera batch (ShapeError if they differ)."""
    Bv = verts.shape[0] if len(verts.shape) == 3 else 1
    Bc = camera.batch_size()
    if Bv != 1 and Bc != 1 and Bv != Bc:
        raise ShapeError(f"vertex batch size {Bv} and camera batch size {Bc} do not match")
    return max(Bv, Bc)


def _dtype_name(value, name: str) -> str:
    """"int64", "float32", ... of a NumPy, torch or Dr.Jit array, or of what NumPy makes of a list."""
    dtype = getattr(value, "dtype", None)
    if dtype is None:
        dtype = host_array(value, name).dtype
    return str(dtype).rsplit(".", 1)[-1].lower()  # torch.int64, VarType.Int32 -> int64, int32


def check_colour_dtype(dtype, name: str) -> None:
    """DTypeError unless colours of ``dtype`` (a torch dtype; the backends' rule for colour tensors)
    may be cast to the vertices' dtype: float32/64 or integers, as for NumPy colours; not complex
    (the cast drops the imaginary part), bool or half precision."""
    kind = str(dtype).rsplit(".", 1)[-1]
    if not (kind in ("float32", "float64") or kind.startswith(("int", "uint"))):
        raise DTypeError(f"{name} must be float32, float64 or integers, got {dtype}")


def host_array(x, name: str) -> np.ndarray:
    """``x`` (a list, NumPy array, anything ``np.asarray`` reads) as a NumPy array for a backend's
    input checks; a ragged nesting is a ShapeError (NumPy raises a bare ValueError). Big-endian
    numbers come back in native byte order (the same values: '>f8' was refused as not float64)."""
    try:
        a = np.asarray(x)
    except ValueError as exc:
        raise ShapeError(f"{name} must be a regular array (equal-length rows), got a ragged nesting: {exc}") from None
    return a.astype(a.dtype.newbyteorder("=")) if a.dtype.kind in "fiub" and not a.dtype.isnative else a


def int64_indices(a: np.ndarray, name: str) -> np.ndarray:
    """The integer array ``a`` as int64; InputValueError where a uint64 one holds an index beyond
    int64, which the cast would wrap negative."""
    if a.dtype == np.uint64 and a.size and int(a.max()) > np.iinfo(np.int64).max:
        raise InputValueError(f"{name} holds index {int(a.max())}, beyond int64 (indices must lie in [0, count − 1])")
    return a.astype(np.int64)


def image_size_pair(image_size, owner: str) -> tuple[int, int]:
    """(H, W) of an ``image_size`` given as an int or a pair of ints (>= 1); ParameterError naming
    the value otherwise (strings, floats, bools)."""
    if isinstance(image_size, numbers.Integral) and not isinstance(image_size, bool):
        image_size = (image_size, image_size)
    try:
        H, W = image_size
    except (TypeError, ValueError):
        raise ParameterError(f"{owner} parameter image_size={image_size!r} must be (H, W) or an int") from None
    return tuple(_number(owner, n, v, positive=True, integer=True) for n, v in (("image height", H), ("image width", W)))


def tau_floor(dtype: str) -> float:
    """The smallest τ (screen units) a ``dtype`` render accepts: 16·sqrt(smallest normal number),
    ~1.7e-18 in float32 and ~2.4e-153 in float64. Below it −d/τ² (the argument's derivative in τ)
    overflows for distances d of a few screen units, and 0·inf made dL/dτ NaN (float32 τ = 3e-20,
    float64 1e-156), even where no pixel depends on τ."""
    return 16.0 * math.sqrt(float(np.finfo(dtype).tiny))


def _check_params_fit(settings, dtype: str, tau_value: float) -> None:
    """ParameterError for τ or a distribution or T-conorm parameter (a number) that a float32 render
    cannot hold: beyond float32's range or below its smallest normal number in magnitude (frank
    p = 1e40 rendered alpha −inf, p = 1e-39 +inf; gamma shape = 1e-40 is a subnormal float32;
    τ = 1e-39 gave gamma NaN gradients), and a τ below :func:`tau_floor` of either dtype."""
    floor = tau_floor(dtype)
    if not tau_value >= floor:
        raise ParameterError(f"Renderer parameter tau={tau_value:g} is below {floor:.3g}, the smallest τ whose "
                             f"gradient ∂(d/τ)/∂τ = −d/τ² stays finite in {dtype} (it gave NaN gradients)"
                             + ("; render in float64 (float64 vertices)" if dtype == "float32" else ""))
    if dtype != "float32":
        return
    info = np.finfo(np.float32)
    for owner, setting in (("distribution", settings.distribution), ("tconorm", settings.tconorm)):
        for name, value in setting.params:
            if isinstance(value, numbers.Real) and value != 0 and not float(info.tiny) <= abs(value) <= float(info.max):
                raise ParameterError(f"{owner} {setting.name!r} parameter {name}={value:g} is beyond what float32 "
                                     f"holds (normal numbers {info.tiny:.3g} ... {info.max:.3g} in magnitude): "
                                     f"render in float64 (float64 vertices)")
    if not tau_value <= float(info.max):
        raise ParameterError(f"Renderer parameter tau={tau_value:g} is beyond what float32 holds (at most "
                             f"{info.max:.3g}): render in float64 (float64 vertices)")
    shift = settings.distribution.shift
    if isinstance(shift, numbers.Real) and not abs(shift) <= float(info.max):
        raise ParameterError(f"distribution {settings.distribution.name!r} parameter shift={shift:g} is beyond what "
                             f"float32 holds ({info.max:.3g}): render in float64 (float64 vertices)")


def _check_batch(name, shape, batched_ndim, B):
    """An input with a leading batch (``len(shape) == batched_ndim``) must have 1 or the render's B."""
    if len(shape) == batched_ndim and shape[0] not in (1, B):
        raise ShapeError(f"{name} has batch size {shape[0]}, the render has B = {B} (the broadcast of the "
                         f"vertex and camera batch sizes); give " + (f"1 or {B}" if B > 1 else "no batch or 1"))


def _scalar(t) -> float:
    """float() of a Python number or a 0-d array/tensor (torch: detached first, no autograd
    warning; Dr.Jit arrays have no __float__, so go through .numpy())."""
    if hasattr(t, "detach"):
        t = t.detach()
    elif hasattr(t, "numpy"):
        t = t.numpy().reshape(-1)[0]
    return float(t)


def _tau_value(tau, shown=None) -> float:
    """The value of τ (a tensor: one read of the device), checked against its domain (an optimizer
    may have moved a tensor τ out of it); ``shown``: what the error names (default ``tau``)."""
    v = _scalar(tau)
    if not (math.isfinite(v) and v > 0):
        raise ParameterError(f"Renderer parameter tau={tau if shown is None else shown!r} is out of domain: "
                             f"expected finite and > 0")
    return v


def _check_tau(tau):
    """``tau`` checked: a number or a NumPy scalar/[1] array (returned as a float), or a 0-d/[1]
    backend tensor (returned as is, so it keeps its gradient)."""
    raw = tau
    if not (hasattr(tau, "detach") or hasattr(tau, "numpy")):  # not a torch / Dr.Jit array
        if getattr(tau, "size", 1) != 1:
            raise ShapeError(f"Renderer parameter tau must be a scalar, got shape {tuple(tau.shape)}")
        tau = plain_number(tau)
        if tau is None:
            raise ParameterError(f"Renderer parameter tau={raw!r} must be a number > 0")
    shape = getattr(tau, "shape", ())
    if tuple(shape) not in ((), (1,)):
        raise ShapeError(f"Renderer parameter tau must be a scalar, got shape {tuple(shape)}")
    try:
        v = _scalar(tau)
    except (TypeError, ValueError):
        raise ParameterError(f"Renderer parameter tau={tau!r} must be a number > 0") from None
    _tau_value(v, shown=raw)  # (the domain check; v is a float: no second read)
    return tau


@lru_cache(maxsize=None)
def available_backends() -> dict[str, metadata.EntryPoint]:
    """Backends registered under the ``gendr.backends`` entry-point group (name -> entry point).

    Registered is not importable: :class:`Renderer` raises
    :class:`~gendr.errors.BackendUnavailableError` for a backend whose dependencies are missing.

    >>> import gendr
    >>> "torch" in gendr.available_backends()
    True
    """
    return {ep.name: ep for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)}


def load_backend(name: str, **options):
    eps = available_backends()
    if name not in eps:
        raise UnknownNameError("backend", name, sorted(eps))
    try:
        cls = eps[name].load()
    except ImportError as exc:
        raise BackendUnavailableError(
            f"backend {name!r} is registered but cannot be imported ({exc}); install its extra, "
            f"e.g. `pip install gendr[{name}]`") from exc
    params = inspect.signature(cls).parameters.values()
    accepted = [p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    unknown = sorted(set(options) - set(accepted))
    if unknown and not any(p.kind == p.VAR_KEYWORD for p in params):
        raise ParameterError(f"backend {name!r} has no option {unknown[0]!r} (its options: {', '.join(accepted)})")
    return cls(**options)


class Renderer:
    """A differentiable mesh renderer: soft coverage p = F(d/τ) per face, aggregated by a T-conorm.

    Parameters
    ----------
    distribution : str or Distribution
        e.g. ``"logistic"`` or ``gendr.distribution("gamma", shape=0.5, reversed=True)``. A shape
        given as a scalar tensor that requires grad is learnable, like a T-conorm's p (below).
    tconorm : str or TConorm
        e.g. ``"probabilistic"`` or ``gendr.tconorm("yager", p=2)``. A parameter given as a scalar
        tensor that requires grad (``gendr.tconorm("yager", p=torch.tensor(2.0, requires_grad=True))``)
        is learnable: renders return ∂/∂p (both backends), and its current value is re-checked at
        every render (ParameterError naming it when an optimizer step left the domain).
    tau : float > 0 or 0-d tensor
        scale of the distribution, in screen units (1 unit = H/2 pixels; for ``squared``
        distributions in squared units, √τ the length: the default 0.01 is then a scale of 0.1,
        ten times the plain default's; ``gendr render --squared`` uses 1e-4, SoftRas' σ). A tensor
        that requires grad gets a gradient. A render refuses τ below :func:`tau_floor` of its
        dtype (~1.7e-18 in float32).
    image_size : (H, W) or int
    backend : str
        a registered backend (``gendr.available_backends()``), default ``"torch"``.
    eps : float, 0 <= eps < 1
        coverage culling threshold: a face contributes nothing to a pixel where its coverage is
        below ``eps``. ``eps=0`` disables culling (exact dense result). Heavy-tailed distributions
        (cauchy, reciprocal, levy reversed) have coverage >= eps far away from every face, so each
        face reaches most of the image: expect O(H·W·F) work (memory stays bounded by chunking).
    blend : "softmax", "hard" or None
        RGB: SoftRas' softmax over depth, the colour of the nearest covering face (z-buffer), or
        None for a silhouette only (RGB channels 0; fastest).
    gamma : float > 0, background_eps : float >= 0
        softmax blend temperature γ and background weight exp(ε/γ) (DESIGN.md §3).
    background : 3 floats, RGB where no face is.
    ambient, diffuse, light_direction : Lambert shading; ``light_direction`` is the direction the
        light travels, in world space. Colour = albedo·(ambient + diffuse·max(0, n·(−l))).
    cull_backfaces : bool
        drop faces whose projection is clockwise from the RGB blend (the silhouette always counts
        every face).
    max_pairs : int
        budget of (pixel, face) pairs processed at once (cache-sized bands are fastest on CPU);
        larger scenes are processed in row bands
        (memory stays O(pixels + faces + max_pairs)).
    cutoff : float > 0 or None
        the GenDR reference implementation's distance cut-off (its ``dist_eps``; its shape and pose
        experiments use 100): a face contributes nothing to a pixel outside it whose squared
        distance to it is >= ``cutoff``·τ (screen units, τ as given). Not exact: heavy tails
        (cauchy, reciprocal, levy reversed) lose the coverage beyond it (e.g. cauchy ≈ 0.003 at
        cutoff 100 for squared distributions), and coverage jumps to 0 there. None (default): no
        cut-off, only the ``eps`` culling. docs/performance.md measures what it changes.
    texture_filter : "bilinear" (default) or "nearest"; texture_wrap : "repeat" (default) or
        "clamp": how textures given to :meth:`render` are sampled (docs/conventions.md, Textures).
    backend_options : passed to the backend (e.g. ``device="cuda"``).

    Raises
    ------
    ParameterError (a setting out of its domain), UnknownNameError (distribution, T-conorm or
    backend name), ShapeError (a non-scalar ``tau``), BackendUnavailableError (a registered backend
    that cannot be imported): all from :mod:`gendr.errors`.

    Devices and differentiability: the renderer holds no arrays; :meth:`render` and
    :meth:`rasterize` return arrays of the backend on the inputs' device (torch: CPU or CUDA, as
    the vertices; Dr.Jit: its LLVM/CUDA variant) and are differentiable w.r.t. every float input
    given as a tensor that requires grad (vertices, colours, texture, uvs, camera parameters, a
    tensor ``tau``, a learnable T-conorm or distribution parameter).

    Examples
    --------
    >>> import torch, gendr
    >>> from gendr import scenes
    >>> mesh = scenes.icosphere(1)  # 42 vertices, 80 faces, radius 1
    >>> r = gendr.Renderer("logistic", "probabilistic", tau=0.01, image_size=8, backend="torch")
    >>> r
    Renderer(logistic, probabilistic, tau=0.01, image_size=(8, 8), backend='torch', eps=0.0001, blend='softmax')
    >>> verts = torch.tensor(mesh.vertices, dtype=torch.float32, requires_grad=True)
    >>> img = r.render(verts, mesh.faces, gendr.orbit_camera(30.0, 20.0, 3.0))
    >>> img.shape, img.dtype, img.device.type, round(float(img.detach()[0, 4, 4, 3]), 3)
    (torch.Size([1, 8, 8, 4]), torch.float32, 'cpu', 1.0)
    >>> img[..., 3].sum().backward(); verts.grad.shape
    torch.Size([42, 3])
    """

    def __init__(self, distribution="logistic", tconorm="probabilistic", tau=0.01, image_size=(256, 256),
                 backend="torch", eps=1e-4, *, blend="softmax", gamma=1e-4, background_eps=1e-3,
                 background=(0.0, 0.0, 0.0), ambient=0.5, diffuse=0.5, light_direction=(0.0, 0.0, -1.0),
                 cull_backfaces=False, max_pairs=262_144, cutoff=None, texture_filter="bilinear",
                 texture_wrap="repeat", **backend_options):
        dist = make_distribution(distribution)
        tcn = make_tconorm(tconorm)
        tau = _check_tau(tau)
        H, W = image_size_pair(image_size, "Renderer")
        eps = _number("Renderer", "eps", eps, nonneg=True)
        if eps >= 1:
            raise ParameterError(f"Renderer parameter eps={eps!r} is out of domain: expected 0 <= eps < 1")
        if blend not in BLENDS:
            raise ParameterError(f"Renderer parameter blend={blend!r} must be one of {BLENDS}")
        gamma = _number("Renderer", "gamma", gamma, positive=True)
        background_eps = _number("Renderer", "background_eps", background_eps, nonneg=True)
        ambient = _number("Renderer", "ambient", ambient, nonneg=True)
        diffuse = _number("Renderer", "diffuse", diffuse, nonneg=True)
        max_pairs = _number("Renderer", "max_pairs", max_pairs, positive=True, integer=True)
        if cutoff is not None:
            cutoff = _number("Renderer", "cutoff", cutoff, positive=True)
        if not isinstance(cull_backfaces, (bool, np.bool_)):
            raise ParameterError(f"Renderer parameter cull_backfaces={cull_backfaces!r} must be True or False")
        cull_backfaces = bool(cull_backfaces)
        _check_texture_settings(texture_filter, texture_wrap)
        light = _triple("Renderer", "light_direction", light_direction)
        if not any(light):
            raise ParameterError("Renderer parameter light_direction must not be the zero vector")
        self.settings = RenderSettings(
            dist, tcn, tau, (H, W), eps, blend, gamma, background_eps,
            _triple("Renderer", "background", background), ambient, diffuse, light,
            bool(cull_backfaces), max_pairs, cutoff, texture_filter, texture_wrap)
        self.backend = load_backend(backend, **backend_options)

    def __repr__(self):
        s = self.settings
        return (f"Renderer({s.distribution.label()}, {s.tconorm.label()}, tau={s.tau_value:g}, "
                f"image_size={s.image_size}, backend={self.backend.name!r}, eps={s.eps:g}, blend={s.blend!r}"
                + ("" if s.cutoff is None else f", cutoff={s.cutoff:g}") + ")")

    def with_tau(self, tau) -> "Renderer":
        """This renderer with scale ``tau`` (checked as in the constructor), sharing this one's
        backend object, so its caches (e.g. Dr.Jit's frozen recordings, which take τ as an input)
        serve both. For a τ schedule: cheaper than a new :class:`Renderer` per step, which would
        build a backend object each time.

        >>> import gendr
        >>> r = gendr.Renderer(tau=0.1, image_size=8, backend="torch")
        >>> r2 = r.with_tau(0.01)
        >>> r2.settings.tau_value, r.settings.tau_value, r2.backend is r.backend
        (0.01, 0.1, True)
        """
        tau = _check_tau(tau)
        new = copy.copy(self)
        new.settings = replace(self.settings, tau=tau)
        return new

    def render(self, vertices, faces, camera: Camera, *, vertex_colors=None, face_colors=None, texture=None,
               uvs=None, uv_faces=None):
        """Render a batch of meshes sharing one topology.

        vertices : [B, V, 3] or [V, 3] float32/float64, world units (backend array, or NumPy).
        faces : [F, 3] integer indices into V.
        camera : a :class:`~gendr.cameras.Camera`; batched parameters give one camera per batch
            element (B is the broadcast of the vertex and camera batch sizes).
        vertex_colors : [B, V, 3] or [V, 3], or face_colors : [B, F, 3] or [F, 3] (albedo in
            [0, 1]; default white; float, or integers 0 and 1 — uint8, and other integers beyond 0/1, are
            refused as 0..255). Not both.
        texture : [Ht, Wt, 3|4] or [B, Ht, Wt, 3|4] float32/float64 albedo (row 0 at the top; the
            alpha channel is not used), sampled at the interpolated ``uvs`` with the renderer's
            ``texture_filter`` / ``texture_wrap`` (docs/conventions.md, Textures); instead of
            vertex/face colours. Differentiable (a tensor that requires grad gets a gradient).
        uvs : [T, 2] or [B, T, 2] texture coordinates (u right, v up, OBJ convention);
            differentiable. uv_faces : [F, 3] integer indices into ``uvs`` per face corner (OBJ's
            separate ``vt`` indices); default ``faces`` (then T = V).

        Returns [B, H, W, 4] in the vertices' dtype: RGB, then alpha (the aggregated coverage).
        A backend array on the vertices' device (torch: CPU/CUDA tensor; the drjit backend: a torch
        tensor when any input but the index arrays (faces, uv_faces) is one — vertices, colours,
        texture, uvs, τ, a camera or spec parameter — else TensorXf/TensorXf64); NumPy inputs are converted to the
        backend (torch: CPU). Differentiable w.r.t.
        vertices, colours, texture, uvs, the camera's tensor parameters, a tensor ``tau`` and the
        learnable T-conorm and distribution parameters (whichever require grad); ``faces`` and ``uv_faces`` are not.
        Pixel (row i, column j) is sampled at its centre; row 0 is the top of the image.

        Raises (:mod:`gendr.errors`): ShapeError (shapes above; a colour, texture or uv batch other
        than 1 or B), DTypeError (integer vertices, uint8 colours or integer colours beyond 0/1,
        float indices), InputValueError (non-finite values, indices out of range, a face projecting
        beyond what the dtype holds: :func:`check_screen_reach`), ParameterError (both colour kinds,
        uvs without a texture, a camera that is not a gendr camera, a tensor ``tau`` or a learnable
        parameter out of its domain, a parameter float32 cannot hold in a float32 render),
        DegenerateCameraError (a camera tensor without a defined view).

        >>> import torch, gendr
        >>> from gendr import scenes
        >>> cube = scenes.cube(1.0)  # 8 vertices, 12 faces
        >>> r = gendr.Renderer(tau=0.01, image_size=8, backend="torch", blend="hard")
        >>> v = torch.tensor(cube.vertices)  # float64 in, float64 out
        >>> cams = gendr.orbit_camera(torch.tensor([0.0, 45.0]), 20.0, 3.0)  # a batch of 2 views
        >>> img = r.render(v, cube.faces, cams, face_colors=torch.ones(12, 3, dtype=torch.float64))
        >>> img.shape, img.dtype, round(float(img[1, 4, 4, 3]), 3), round(float(img[0, 0, 0, 3]), 3)
        (torch.Size([2, 8, 8, 4]), torch.float64, 1.0, 0.0)
        """
        if vertex_colors is not None and face_colors is not None:
            raise ParameterError("give vertex_colors or face_colors, not both")
        be = self.backend
        verts, faces_a = self._mesh_inputs(vertices, faces, camera)
        V = verts.shape[-2]
        B = _render_batch(verts, camera)
        if texture is not None and (vertex_colors is not None or face_colors is not None):
            raise ParameterError("give a texture or vertex_colors/face_colors, not both")
        if texture is None and (uvs is not None or uv_faces is not None):
            raise ParameterError("uvs/uv_faces were given without a texture")
        tex = None if texture is None else check_textured_inputs(be, verts, faces_a, texture, uvs, uv_faces)
        if tex is not None:
            _check_batch("texture", tex[0].shape, 4, B)
            _check_batch("uvs", tex[1].shape, 3, B)
        colors, per_face = None, False
        for name, value, n in (("vertex_colors", vertex_colors, V), ("face_colors", face_colors, faces_a.shape[0])):
            if value is None:
                continue
            dtype = _dtype_name(value, name)
            if dtype == "uint8":  # an 8-bit image's colours
                raise DTypeError(f"{name} are uint8 (0..255?): give float albedo in [0, 1] (divide by 255), "
                                 f"as for textures")
            if dtype.startswith(("int", "uint")):  # albedo 0/1 only: 0..255 would render 255 times too bright
                idx = be.index_array(value, name)
                lo, hi = be.index_range(idx) if math.prod(idx.shape) else (0, 0)
                if lo < 0 or hi > 1:
                    raise DTypeError(f"{name} are {dtype} in [{lo}, {hi}]: integer colours must be 0 or 1; give "
                                     f"float albedo in [0, 1] (e.g. divide by 255)")
            c = be.float_array(value, name, like=verts)
            if len(c.shape) not in (2, 3) or c.shape[-1] != 3 or c.shape[-2] != n:
                raise ShapeError(f"{name} must have shape [B, {n}, 3] or [{n}, 3], got {list(c.shape)}")
            _check_batch(name, c.shape, 3, B)
            require_finite(be, c, name)
            colors, per_face = c, name == "face_colors"
        settings = self.settings
        tau_value = settings.tau if isinstance(settings.tau, float) else _tau_value(settings.tau)
        if settings.tconorm.learnable or settings.distribution.learnable:  # re-read and re-check
            settings = replace(settings, tconorm=settings.tconorm.refreshed(),  # (an optimizer moves them)
                               distribution=settings.distribution.refreshed())
        _check_params_fit(settings, _dtype_name(verts, "vertices"), tau_value)  # (the values this render uses)
        if tex is not None:
            return be.render(settings, verts, faces_a, camera, colors, per_face, texture=tex)
        return be.render(settings, verts, faces_a, camera, colors, per_face)

    def rasterize(self, vertices, faces, camera: Camera) -> GBuffer:
        """The G-buffer of a batch of meshes: per pixel the visible face, its barycentrics, view
        depth and interpolated normal (:class:`~gendr.gbuffer.GBuffer`), as arrays of the backend.

        vertices : [B, V, 3] or [V, 3] float32/float64; faces : [F, 3]; camera as for :meth:`render`.
        Uses the image size, ``cull_backfaces`` and ``max_pairs`` of the settings; the coverage
        settings (distribution, τ, eps, blend) play no part. Differentiable w.r.t. vertices and
        camera (bary, depth, normal); face_id is piecewise constant.

        Returns a :class:`~gendr.gbuffer.GBuffer`: ``face_id`` [B, H, W] integer (−1: background),
        ``bary`` [B, H, W, 3], ``depth`` [B, H, W] (world units, positive in front), ``normal``
        [B, H, W, 3] (world space); floats in the vertices' dtype, on the vertices' device.
        Raises ShapeError, DTypeError, InputValueError, ParameterError as :meth:`render`.

        >>> import torch, gendr
        >>> from gendr import scenes
        >>> mesh = scenes.icosphere(1)
        >>> r = gendr.Renderer(image_size=8, backend="torch")
        >>> g = r.rasterize(torch.tensor(mesh.vertices), mesh.faces, gendr.orbit_camera(30.0, 20.0, 3.0))
        >>> g.face_id.shape, g.face_id.dtype, g.bary.shape, g.depth.dtype
        (torch.Size([1, 8, 8]), torch.int64, torch.Size([1, 8, 8, 3]), torch.float64)
        >>> round(float(g.depth[0, 4, 4]), 3), int(g.mask.sum())  # centre: ~3 − 1 from the eye
        (2.033, 45)
        """
        be = self.backend
        verts, faces_a = self._mesh_inputs(vertices, faces, camera)
        _render_batch(verts, camera)
        return GBuffer(*be.rasterize(self.settings, verts, faces_a, camera))

    def _mesh_inputs(self, vertices, faces, camera):
        """The backend's arrays of ``vertices`` [B?, V, 3] and ``faces`` [F, 3], checked (shapes,
        finite vertices, face indices in range, a gendr camera): typed errors naming the bad value."""
        if not isinstance(camera, Camera):
            raise ParameterError(f"camera must be a gendr camera (PerspectiveCamera, ...), got {type(camera).__name__}")
        be = self.backend
        verts = be.float_array(vertices, "vertices")
        if isinstance(faces, (list, tuple)) and len(faces) == 0:
            faces = np.zeros((0, 3), dtype=np.int64)  # no faces ([] is float64 to NumPy)
        faces_a = be.index_array(faces, "faces")
        vshape = tuple(verts.shape)
        if len(vshape) not in (2, 3) or vshape[-1] != 3 or vshape[-2] < 1 or (len(vshape) == 3 and vshape[0] < 1):
            raise ShapeError(f"vertices must have shape [B, V, 3] or [V, 3] (B, V >= 1), got {list(vshape)}")
        if len(faces_a.shape) != 2 or faces_a.shape[1] != 3:
            raise ShapeError(f"faces must have shape [F, 3], got {list(faces_a.shape)}")
        V = vshape[-2]
        require_finite(be, verts, "vertices")
        if faces_a.shape[0] > 0:
            lo, hi = be.index_range(faces_a)
            if lo < 0 or hi >= V:
                one_based = " (1-based, as in OBJ files? subtract 1)" if (lo, hi) == (1, V) else ""
                raise InputValueError(f"face indices must lie in [0, {V - 1}] (V = {V}), got range [{lo}, {hi}]"
                                      + one_based)
        return verts, faces_a

    def to_numpy(self, image):
        """The backend's image as a NumPy array (detached, on the CPU; same shape and dtype).

        >>> import numpy as np, gendr
        >>> r = gendr.Renderer(image_size=8, backend="torch")
        >>> tri = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]], dtype=np.float32)
        >>> a = r.to_numpy(r.render(tri, [[0, 1, 2]], gendr.PerspectiveCamera()))
        >>> type(a).__name__, a.shape, a.dtype
        ('ndarray', (1, 8, 8, 4), dtype('float32'))
        """
        return self.backend.to_numpy(image)
