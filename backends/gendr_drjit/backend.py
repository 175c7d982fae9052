"""The Dr.Jit backend object the :class:`gendr.Renderer` facade talks to.

Inputs may be Dr.Jit tensors (``TensorXf``/``TensorXf64`` of the chosen device; AD through Dr.Jit),
NumPy arrays, or torch tensors. With any torch tensor among the inputs (vertices, colours, τ, camera
parameters) the render runs through ``dr.wrap(source="torch", target="drjit")``: the image is a torch
tensor and gradients flow back into torch. Otherwise the image is a Dr.Jit tensor [B, H, W, 4].
The image has the vertices' dtype (float32 or float64).
"""
from __future__ import annotations

import contextlib
import sys

import numpy as np
import drjit as dr

from gendr.cameras import VEC3
from gendr.errors import BackendUnavailableError, DTypeError, ParameterError, ShapeError, refuse_second_derivatives
from gendr.renderer import check_colour_dtype, host_array, int64_indices

from . import raster
from .ops import DrJitOps

DEVICES = ("llvm", "cuda")


def _torch():
    return sys.modules.get("torch")


def _is_torch(x):
    t = _torch()
    return t is not None and isinstance(x, t.Tensor)


def _is_drjit(x):
    return isinstance(x, dr.ArrayBase)


class Input:
    """A validated input array: the original object, its shape and dtype, a detached NumPy copy."""

    def __init__(self, kind, data, np_value, dtype):
        self.kind, self.data, self.np, self.dtype = kind, data, np_value, dtype
        self.shape = tuple(np_value.shape)

    def __repr__(self):
        return f"Input({self.kind}, shape={self.shape}, dtype={self.dtype})"


def _drjit_dtype(x):
    vt = dr.type_v(x)
    return {dr.VarType.Float32: "float32", dr.VarType.Float64: "float64"}.get(vt, str(vt).split(".")[-1].lower())


def _drjit_numpy(x):
    return np.asarray(dr.detach(x).numpy())


_BRIDGE = None


def _module(device):
    """Dr.Jit's AD types module of a device ("llvm" or "cuda")."""
    if device == "cuda":
        import drjit.cuda.ad as module
    else:
        import drjit.llvm.ad as module
    return module


def _device_of(x):
    """The device ("llvm" or "cuda") of a Dr.Jit array."""
    return "cuda" if dr.backend_v(x) == dr.JitBackend.CUDA else "llvm"


def _check_available(device, what):
    if not dr.has_backend(dr.JitBackend.CUDA if device == "cuda" else dr.JitBackend.LLVM):
        raise BackendUnavailableError(
            f"drjit backend {what}{device!r}: Dr.Jit's {device.upper()} backend is not available on this machine "
            f"(available: {[d for d in DEVICES if dr.has_backend(getattr(dr.JitBackend, d.upper()))]})")


def _check_device(x, T, name):
    """A Dr.Jit input ``x`` must live on the render's device (Dr.Jit refuses to convert between them)."""
    if _device_of(x) != T.device:
        raise ParameterError(f"{name} is a Dr.Jit {_device_of(x).upper()} array but this render runs on "
                             f"{T.device.upper()} (the vertices' device, or the backend's device=): make every "
                             f"Dr.Jit input with drjit.{T.device}.ad")


def exact_math(T):
    """A context for Dr.Jit work on the types ``T``: on CUDA in float64, Dr.Jit's FastMath off.

    With FastMath on (Dr.Jit's default), the CUDA backend computes float64 ``rcp``, ``rsqrt``,
    ``tan``, ``tanh`` and the derivatives of division, ``sqrt``, ``log``, ``atan`` and powers with
    PTX's approximate instructions: relative errors ~1e-6 (measured on an H100), which a float64
    render would carry into its image and gradients. Float32 and the LLVM backend are left as they
    are (there the approximations are within float32 rounding, or not used).
    """
    if _exact_math_needed(T):
        return dr.scoped_set_flag(dr.JitFlag.FastMath, False)
    return contextlib.nullcontext()


def _exact_math_needed(T):
    return T.double and T.device == "cuda"


def _handoff(torch, device):
    """Hand the arrays over between torch and Dr.Jit (either way), at both ends of the bridge's
    forward and backward.

    Torch runs the backward of CUDA tensors on its own device thread, and Dr.Jit keeps
    per-thread state: as ``dr.wrap`` does, each handoff starts a new Dr.Jit scope (without it Dr.Jit
    refuses to compile "r22 (scope 65) depends on r541 (scope 141)"). On CUDA the two also queue
    work on different streams: both are synchronised, so that neither reads memory the other
    has not finished writing.
    """
    for backend in (dr.JitBackend.LLVM, dr.JitBackend.CUDA):
        if dr.has_backend(backend):
            dr.detail.new_scope(backend)
    if device is not None and device.type == "cuda":
        torch.cuda.current_stream(device).synchronize()
        dr.sync_thread()


def _bridge():
    """A torch.autograd.Function running a Dr.Jit function (built on first use: torch is optional).

    Like ``dr.wrap(source="torch", target="drjit")``, but re-entrant: the Dr.Jit AD graph is kept
    (``ClearInterior`` only), so torch may call backward several times (``retain_graph=True``,
    ``torch.autograd.gradcheck``); ``dr.wrap`` 1.5 clears the graph after the first backward and
    then returns zero gradients.
    """
    global _BRIDGE
    if _BRIDGE is None:
        torch = _torch()

        class DrJitFunction(torch.autograd.Function):
            @staticmethod
            def forward(ctx, fn, T, *tensors):
                ctx.device = tensors[0].device if tensors else None
                _handoff(torch, ctx.device)
                inputs = []
                for x in tensors:
                    d = T.Tensor(x.detach().contiguous())
                    if x.requires_grad:
                        dr.enable_grad(d)
                    inputs.append(d)
                with torch.enable_grad():
                    out = fn(*inputs)
                ctx.inputs, ctx.output, ctx.T = inputs, out, T
                res = dr.detach(out).torch()
                # (differentiable even where no gradient reaches the inputs — heaviside with "or"
                # and no RGB, an empty mesh —, as the torch backend's: backward then gives zeros)
                ctx.shapes = [(x.shape, x.dtype, x.device) for x in tensors]
                _handoff(torch, ctx.device)
                return res.to(ctx.device) if ctx.device is not None else res

            @staticmethod
            def backward(ctx, grad):
                if torch.is_grad_enabled():  # create_graph=True (once_differentiable gave a first derivative
                    refuse_second_derivatives((grad,))  # whose derivative autograd took as 0)
                T, inputs = ctx.T, ctx.inputs
                if not dr.grad_enabled(ctx.output):  # zeros, as the torch backend's graph gives
                    return (None, None, *[torch.zeros(shape, dtype=dt, device=dev) if need else None
                                          for need, (shape, dt, dev) in zip(ctx.needs_input_grad[2:], ctx.shapes)])
                _handoff(torch, ctx.device)
                for x in inputs:
                    if dr.grad_enabled(x):
                        dr.clear_grad(x)
                with exact_math(T):  # (flags are per thread: this may be torch's device thread)
                    dr.set_grad(ctx.output, T.Tensor(grad.detach().contiguous().to(dtype=grad.dtype)))
                    dr.enqueue(dr.ADMode.Backward, ctx.output)
                    dr.traverse(dr.ADMode.Backward, dr.ADFlag.ClearInterior | dr.ADFlag.ClearInput)
                    outs = []
                    for x in inputs:
                        if dr.grad_enabled(x):
                            g = dr.grad(x).torch()
                            outs.append(g.to(ctx.device) if ctx.device is not None else g)
                            dr.clear_grad(x)
                        else:
                            outs.append(None)
                _handoff(torch, ctx.device)
                return (None, None, *outs)

        _BRIDGE = DrJitFunction
    return _BRIDGE


class DrJitBackend:
    """Renders with Dr.Jit: one fused per-pixel loop kernel per pass (see :mod:`gendr_drjit.raster`).

    device : "llvm" (CPU), "cuda", or None: the inputs' — Dr.Jit tensors' own backend, LLVM for
        torch tensors on the CPU and CUDA for torch tensors on a GPU (as the torch backend renders
        on the vertices' device); with NumPy vertices the first other input that has a device
        decides, and with none CUDA when available, else LLVM. Torch tensors on another device than
        ``device`` are copied there (differentiably) and the image comes back on the vertices'
        device (torch vertices), else on the render's. One GPU: Dr.Jit's current CUDA device and
        torch's current one.
    freeze : replay renders of the same shapes with ``dr.freeze`` instead of re-tracing them
        (see :mod:`gendr_drjit.frozen`; gradients work through a custom op).
    """

    name = "drjit"

    def __init__(self, device=None, freeze=False):
        if not isinstance(freeze, bool):
            raise ParameterError(f"drjit backend parameter freeze={freeze!r} must be True or False")
        if device is not None and device not in DEVICES:
            raise ParameterError(f"drjit backend parameter device={device!r} must be one of {DEVICES} or None")
        if device is not None:
            _check_available(device, "device=")
        self.device = device
        self._types = {}
        self.frozen = None
        if freeze:
            from .frozen import FrozenRenderer
            self.frozen = FrozenRenderer()

    def types(self, device, double):
        """(raster.Types, DrJitOps) of a device ("llvm" or "cuda") and precision."""
        if (device, double) not in self._types:
            T = raster.Types(_module(device), double)
            self._types[device, double] = T, DrJitOps(T.Float)
        return self._types[device, double]

    def device_for(self, inputs):
        """The device ("llvm" or "cuda") a render runs on: ``device=``, else that of the first of
        ``inputs`` (the render's arrays, vertices first) that has one — a Dr.Jit array's backend, a
        torch tensor's device —, else CUDA when available (all NumPy)."""
        if self.device is not None:
            return self.device
        for x in inputs:
            if _is_drjit(x):
                return _device_of(x)
            if _is_torch(x):
                device = "cuda" if x.device.type == "cuda" else "llvm"
                _check_available(device, f"inputs on {x.device}: device ")
                return device
        return "cuda" if dr.has_backend(dr.JitBackend.CUDA) else "llvm"

    # --- the facade's protocol ----------------------------------------------------------------
    def float_array(self, x, name, like=None):
        if _is_torch(x):
            torch = _torch()
            dt = str(x.dtype).replace("torch.", "")
            if like is None and x.dtype not in (torch.float32, torch.float64):
                raise DTypeError(f"{name} must be float32 or float64, got {x.dtype}")
            if like is not None:
                check_colour_dtype(x.dtype, name)
            # (colours, like=...: any torch dtype is cast to the vertices' dtype, as the torch backend does)
            a = x.detach().cpu().to(torch.float64).numpy()
            return Input("torch", x, a, like.dtype if like is not None else dt)
        if _is_drjit(x):
            dt = _drjit_dtype(x)
            if like is None and dt not in ("float32", "float64"):
                raise DTypeError(f"{name} must be float32 or float64, got {dt}")
            if not dr.is_tensor_v(x):
                raise DTypeError(f"{name}: Dr.Jit inputs must be tensors (e.g. drjit.llvm.ad.TensorXf), "
                                 f"got {type(x).__name__}")
            return Input("drjit", x, _drjit_numpy(x).astype(np.float64), like.dtype if like is not None else dt)
        a = host_array(x, name)
        if not (a.dtype in (np.float32, np.float64) or (like is not None and a.dtype.kind in "iu")):
            raise DTypeError(f"{name} must be float32 or float64, got dtype {a.dtype}")
        return Input("numpy", a, a.astype(np.float64), like.dtype if like is not None else a.dtype.name)

    def index_array(self, x, name):
        if _is_torch(x):
            torch = _torch()
            if x.dtype.is_floating_point or x.dtype == torch.bool or x.dtype.is_complex:
                raise DTypeError(f"{name} must be an integer array, got {x.dtype}")
            return int64_indices(x.detach().cpu().numpy(), name)
        if _is_drjit(x):
            vt = dr.type_v(x)
            if vt not in (dr.VarType.Int32, dr.VarType.UInt32, dr.VarType.Int64, dr.VarType.UInt64):
                raise DTypeError(f"{name} must be an integer array, got {vt}")
            return int64_indices(np.asarray(x.numpy()), name)
        a = host_array(x, name)
        if a.dtype.kind not in "iu":
            raise DTypeError(f"{name} must be an integer array, got {a.dtype}")
        return int64_indices(a, name)

    def first_nonfinite(self, t):
        with np.errstate(over="ignore"):  # the values as rendered: 1e300 is inf in float32
            a = t.np.astype(np.float32) if t.dtype == "float32" else t.np
        bad = ~np.isfinite(a)
        if not bad.any():
            return None
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        return idx, float(a[idx])

    def index_range(self, t):
        return int(t.min()), int(t.max())

    def to_numpy(self, image):
        if _is_torch(image):
            return image.detach().cpu().numpy()
        return np.asarray(dr.detach(image).numpy())

    # --- rendering ----------------------------------------------------------------------------
    def render(self, settings, verts, faces, camera, colors, per_face, texture=None, gbuffer=False):
        """The image [B, H, W, 4]; with ``gbuffer`` (then colors and texture are None) the packed
        G-buffer [B, H, W, 8] of :func:`raster.rasterize`. ``texture``: (texture Input, uvs Input,
        uv_faces int64 NumPy) from gendr.textures.check_textured_inputs.

        On CUDA, float64 renders run with Dr.Jit's FastMath off (:func:`exact_math`), their backward
        through torch too. A backward that Dr.Jit inputs start outside (``dr.backward``) runs under
        the caller's flags: turn ``dr.JitFlag.FastMath`` off there for float64 gradients."""
        cam = camera.array_params()
        arrays = [verts.data, colors.data if colors is not None else None, settings.tau,
                  *settings.tconorm.learnable.values(), *settings.distribution.learnable.values(),
                  *(v for v, _ in cam.values()), *((texture[0].data, texture[1].data) if texture is not None else ())]
        device = self.device_for(arrays)
        T, ops = self.types(device, verts.dtype == "float64")
        with exact_math(T):
            out = self._render_inputs(T, ops, cam, settings, verts, faces, camera, colors, per_face, texture, gbuffer)
            if _exact_math_needed(T) and not _is_torch(out):
                dr.eval(out)  # (kernels are assembled under the flags in force when they are evaluated)
            return out

    def _render_inputs(self, T, ops, cam, settings, verts, faces, camera, colors, per_face, texture, gbuffer):
        tau = settings.tau
        # every torch tensor goes through dr.wrap (gradients flow back into torch)
        slots = {}
        if verts.kind == "torch":
            slots["vertices"] = verts.data
        if colors is not None and colors.kind == "torch":
            slots["colors"] = colors.data
        if texture is not None:
            for name, inp in (("texture", texture[0]), ("uvs", texture[1])):
                if inp.kind == "torch":
                    slots[name] = inp.data
        if _is_torch(tau):
            slots["tau"] = tau
        for prefix, spec in (("tcn:", settings.tconorm), ("dist:", settings.distribution)):
            for k, v in spec.learnable.items():  # learnable T-conorm / distribution parameters
                if _is_torch(v):
                    slots[prefix + k] = v.reshape(())
        for k, (v, _) in cam.items():
            if _is_torch(v):
                slots["cam:" + k] = v
        args0 = (settings, camera, T, ops, verts, faces, colors, per_face, cam, tau)
        if not slots:
            return self._render(*args0, {}, texture, gbuffer)
        torch = _torch()
        names = list(slots)
        out_dtype = torch.float64 if T.double else torch.float32
        # one dtype for everything (torch's .to is differentiable); CPU tensors for the LLVM device
        dev = "cuda" if T.device == "cuda" else "cpu"
        if dev == "cuda" and not torch.cuda.is_available():
            raise BackendUnavailableError("drjit backend: this render runs on CUDA (device='cuda', or Dr.Jit CUDA "
                                          "inputs) but this torch build has no CUDA, so its tensors cannot go there")
        args = [slots[n].to(dtype=out_dtype, device=dev) for n in names]

        def fn(*dj):
            return self._render(*args0, dict(zip(names, dj)), texture, gbuffer)
        home = verts.data.device if verts.kind == "torch" else torch.device(dev)
        return _bridge().apply(fn, T, *args).to(home)

    def _render(self, settings, camera, T, ops, verts, faces, colors, per_face, cam, tau, wrapped, texture=None,
                gbuffer=False):
        """Everything in Dr.Jit; ``wrapped`` holds Dr.Jit versions of the torch inputs."""
        vflat = self._flat(wrapped.get("vertices", verts.data if verts.kind != "torch" else None), verts, T, "vertices")
        Bv, V = (verts.shape[0], verts.shape[1]) if len(verts.shape) == 3 else (1, verts.shape[0])
        col = None
        if colors is not None:
            cflat = self._flat(wrapped.get("colors", colors.data if colors.kind != "torch" else None), colors, T, "colors")
            col = (cflat, colors.shape[0] if len(colors.shape) == 3 else 1)
        P, Bc, values = {}, 1, {}
        for name, (value, kind) in cam.items():
            v = wrapped.get("cam:" + name, value)
            arr, shape = self._param(v, T, f"camera parameter {name}")
            if kind == VEC3:
                if shape == (3,):
                    shape = (1, 3)
                if len(shape) != 2 or shape[1] != 3:
                    raise ShapeError(f"camera parameter {name} must have shape [3] or [B, 3], got {list(shape)}")
            else:
                if shape == ():
                    shape = (1,)
                if len(shape) != 1:
                    raise ShapeError(f"camera parameter {name} must be a scalar or have shape [B], got {list(shape)}")
            values[name] = np.asarray(dr.detach(arr).numpy(), dtype=np.float64).reshape(shape)
            n = shape[0]
            if n != 1:
                if Bc not in (1, n):
                    raise ShapeError(f"camera parameter {name} has batch size {n}, others have {Bc}")
                Bc = n
            if kind == VEC3:
                idx = dr.arange(T.UInt32, n) * 3
                P[name] = tuple(self._opaque(dr.gather(T.Float, arr, idx + c), T) for c in range(3))
            else:
                P[name] = self._opaque(arr, T)
        camera.check_values(values)  # the spec's checks: non-finite, lens domains, eye on at, up along the view
        if Bv != 1 and Bc != 1 and Bv != Bc:
            raise ShapeError(f"vertex batch size {Bv} and camera batch size {Bc} do not match")
        t = wrapped.get("tau", tau)
        tau_arr = self._opaque(self._param(t, T, "tau")[0], T)
        learn = settings.tconorm.learnable or settings.distribution.learnable
        if learn:  # the learnable parameters as width-1 AD arrays of the render dtype
            from dataclasses import replace

            def arrays(prefix, spec):
                return {k: self._opaque(self._param(wrapped.get(prefix + k, v), T, prefix + k)[0], T)
                        for k, v in spec.learnable.items()}
            settings = replace(settings, tconorm=settings.tconorm.with_arrays(arrays("tcn:", settings.tconorm)),
                               distribution=settings.distribution.with_arrays(arrays("dist:", settings.distribution)))
        H, W = settings.image_size
        if gbuffer:
            out, B = raster.rasterize(settings, camera, ops, T, P, Bc, vflat, Bv, V, faces)
            return T.Tensor(out, shape=(B, H, W, raster.GBUFFER_CHANNELS))
        tex = None
        if texture is not None:
            ti, ui, uvf = texture
            tflat = self._flat(wrapped.get("texture", ti.data if ti.kind != "torch" else None), ti, T, "texture")
            uflat = self._flat(wrapped.get("uvs", ui.data if ui.kind != "torch" else None), ui, T, "uvs")
            Bt, Ht, Wt, C = (1, *ti.shape) if len(ti.shape) == 3 else ti.shape  # (batches 1 or B: the facade checked)
            Bu, Tn = (1, ui.shape[0]) if len(ui.shape) == 2 else ui.shape[:2]
            tex = (tflat, Bt, Ht, Wt, C, uflat, Bu, Tn, T.UInt32(np.asarray(uvf).reshape(-1).astype(np.uint32)))
            out, B = raster.render(settings, camera, ops, T, P, Bc, vflat, Bv, V, faces, col, per_face, tau_arr, tex)
            return T.Tensor(out, shape=(B, H, W, 4))
        if self.frozen is not None and faces.shape[0] > 0 and not learn:  # (frozen: p and the shape are constants)
            out, B = self.frozen.render(settings, camera, T, ops, P, Bc, vflat, Bv, V, faces, col, per_face, tau_arr)
        else:
            out, B = raster.render(settings, camera, ops, T, P, Bc, vflat, Bv, V, faces, col, per_face, tau_arr)
        return T.Tensor(out, shape=(B, H, W, 4))

    def rasterize(self, settings, verts, faces, camera):
        """(face_id, bary, depth, normal): torch tensors (face_id int64) when any input is a torch
        tensor, else Dr.Jit tensors (face_id TensorXi, int32); see gendr.GBuffer."""
        g = self.render(settings, verts, faces, camera, None, False, gbuffer=True)
        if _is_torch(g):
            return g[..., 7].round().long(), g[..., 0:3], g[..., 3], g[..., 4:7]
        fid = _module(_device_of(g)).TensorXi(g[..., 7])
        return fid, g[..., 0:3], g[..., 3], g[..., 4:7]

    def _flat(self, x, inp, T, name):
        """A flat AD array of ``T.Float`` from a Dr.Jit tensor (keeps AD) or the NumPy copy."""
        if x is not None and _is_drjit(x):
            _check_device(x, T, name)
            a = x.array if dr.is_tensor_v(x) else x
            return a if type(a) is T.Float else T.Float(a)
        return T.Float(inp.np.reshape(-1).astype(np.float64 if T.double else np.float32))

    def _param(self, v, T, name):
        """(flat AD array, shape) of a camera parameter / τ of any supported kind."""
        if _is_drjit(v) and dr.type_v(v) == dr.VarType.Bool:  # (τ; gendr.cameras refuses bool camera values)
            raise ParameterError(f"{name} must be a real array, got a Dr.Jit {type(v).__name__}")
        if _is_drjit(v):
            _check_device(v, T, name)
            if dr.is_tensor_v(v):
                a, shape = v.array, tuple(v.shape)
            elif dr.depth_v(v) > 1:  # e.g. Array3f: components -> a flat row-major [n, 3] array (keeps AD)
                n = max(dr.width(c) for c in v)
                lane = dr.arange(T.UInt32, n * len(v))
                row, comp = lane // len(v), lane % len(v)
                a = dr.zeros(T.Float, n * len(v))
                for i, c in enumerate(v):
                    c = T.Float(c)
                    a = dr.select(comp == i, c if dr.width(c) == 1 else dr.gather(T.Float, c, row), a)
                shape = (len(v),) if n == 1 else (n, len(v))
            else:
                a = v
                shape = () if dr.width(v) == 1 else (dr.width(v),)
            return (a if type(a) is T.Float else T.Float(a)), shape
        if _is_torch(v):
            v = v.detach().cpu().numpy()
        a = np.asarray(v, dtype=np.float64)
        return T.Float(a.reshape(-1).astype(np.float64 if T.double else np.float32)), a.shape

    @staticmethod
    def _opaque(a, T):
        """Width-1 constants become opaque (not literals): new values do not recompile kernels."""
        if dr.width(a) == 1 and not dr.grad_enabled(a):
            return dr.opaque(T.Float, dr.detach(a)[0], 1)
        if not dr.grad_enabled(a):
            dr.make_opaque(a)
        return a
