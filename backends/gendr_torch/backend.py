"""The torch backend object the :class:`gendr.Renderer` facade talks to."""
from __future__ import annotations

import numpy as np
import torch

from gendr.errors import BackendUnavailableError, DTypeError, ParameterError
from gendr.renderer import check_colour_dtype, host_array, int64_indices

from . import raster
from .ops import torch_ops

_FLOATS = (torch.float32, torch.float64)


def torch_device(device) -> torch.device:
    """``device`` as a torch.device this torch can use: ParameterError for a bad name, and
    BackendUnavailableError for a device this build or machine lacks (at construction, not at the
    first render)."""
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ParameterError(f"torch backend parameter device={device!r} is not a torch device "
                             f"(e.g. 'cpu', 'cuda', 'cuda:1')") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise BackendUnavailableError(f"torch backend device={device!r}: this torch ({torch.__version__}) "
                                      f"has no CUDA device here (torch.cuda.is_available() is False)")
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        raise BackendUnavailableError(f"torch backend device={device!r}: only {torch.cuda.device_count()} "
                                      f"CUDA device(s) here")
    if dev.type not in ("cpu", "cuda"):
        raise ParameterError(f"torch backend parameter device={device!r}: gendr's torch backend renders "
                             f"on 'cpu' or 'cuda'")
    return dev


class TorchBackend:
    """Renders with PyTorch on the device of the inputs (or ``device=`` for NumPy inputs).

    compile : fuse the per-pair chains of the soft alpha with ``torch.compile`` (see
        :mod:`gendr_torch.fused`): several times faster per render after a compilation of tens of
        seconds per renderer instance; needs a C++ compiler on CPU (else a warning, and eager).
    """

    name = "torch"
    ops = torch_ops

    def __init__(self, device=None, compile=False):
        if not isinstance(compile, bool):
            raise ParameterError(f"torch backend parameter compile={compile!r} must be True or False")
        self.device = None if device is None else torch_device(device)
        self.compile = compile

    def float_array(self, x, name, like=None):
        if isinstance(x, torch.Tensor):
            t = x
            if like is not None:
                check_colour_dtype(t.dtype, name)
        else:
            a = host_array(x, name)
            # colours (cast to the vertices' dtype) may be given as integers; geometry may not
            if not (a.dtype in (np.float32, np.float64) or (like is not None and a.dtype.kind in "iu")):
                raise DTypeError(f"{name} must be float32 or float64, got dtype {a.dtype}")
            # torch warns on read-only memory and refuses negative strides (a[::-1]); a copy, so
            # that nothing writes into the caller's array
            if not a.flags.writeable or any(st < 0 for st in a.strides):
                a = np.array(a, order="C")
            t = torch.as_tensor(a, device=self.device)
        if like is not None:
            return t.to(dtype=like.dtype, device=like.device)
        if t.dtype not in _FLOATS:
            raise DTypeError(f"{name} must be float32 or float64, got {t.dtype}")
        return t

    def index_array(self, x, name):
        if not isinstance(x, torch.Tensor):
            a = host_array(x, name)
            if a.dtype.kind not in "iu":  # (None, strings: torch.as_tensor's TypeError; floats, bools)
                raise DTypeError(f"{name} must be an integer array, got {a.dtype}")
            return torch.as_tensor(int64_indices(a, name), device=self.device)
        if x.dtype.is_floating_point or x.dtype == torch.bool or x.dtype.is_complex:
            raise DTypeError(f"{name} must be an integer array, got {x.dtype}")
        if x.dtype == torch.uint64:  # (.long() would wrap an index beyond int64 negative)
            return torch.as_tensor(int64_indices(x.cpu().numpy(), name), device=x.device)
        return x.long()

    def first_nonfinite(self, t):
        bad = ~torch.isfinite(t)
        if not bool(bad.any()):
            return None
        idx = tuple(int(i) for i in bad.nonzero()[0])
        return idx, float(t[idx])

    def index_range(self, t):
        return int(t.min()), int(t.max())

    def render(self, settings, verts, faces, camera, colors, per_face, texture=None):
        tau = settings.tau
        if not isinstance(tau, (torch.Tensor, int, float)):  # (a Dr.Jit τ: float() of it is a TypeError)
            raise ParameterError(f"Renderer parameter tau={tau!r} of type {type(tau).__name__}: the torch backend "
                                 f"takes a number or a torch tensor")
        for spec in (settings.tconorm, settings.distribution):
            for k, v in spec.learnable.items():  # (float() of a Dr.Jit array: a TypeError, and no gradient)
                if not isinstance(v, torch.Tensor):
                    raise ParameterError(f"{spec.label()} parameter {k} is a {type(v).__name__}: the torch backend "
                                         f"takes learnable parameters as torch tensors")
        faces = faces.to(verts.device)
        if texture is not None:
            tex, uv, uvf = texture
            texture = (tex.to(verts.device), uv.to(verts.device), uvf.to(verts.device))
        return raster.render(settings, camera, verts, faces, colors, per_face, texture, self.compile)

    def rasterize(self, settings, verts, faces, camera):
        """(face_id int64, bary, depth, normal) tensors, see gendr.GBuffer."""
        return raster.rasterize(settings, camera, verts, faces.to(verts.device))

    def to_numpy(self, image):
        return image.detach().cpu().numpy()
