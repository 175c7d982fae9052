"""Opt-in fused per-pair chains for the torch backend (``Renderer(backend="torch", compile=True)``).

Eager PyTorch runs each elementwise operation of a block's per-pair chain as its own pass over
memory; ``torch.compile`` (Inductor: C++/OpenMP on CPU, Triton on CUDA) fuses the chain into a
few loops. Two chains are compiled per (distribution, T-conorm, eps, polygon size, device type):

* forward: gather the block's faces → signed distance → x → generator terms g (culled pairs 0),
  plus a finiteness check of the block;
* backward: tracked signed distance → ∂g/∂x by forward-mode AD (``torch.func.jvp``, elementwise)
  → per row and edge the four corner sums, and the block's ∂L/∂τ.

Everything else (plans, index_add, the per-pixel T-conorm) stays eager. Blocks the fused chains do
not cover run eagerly, with identical formulas: a block with a saturated pair (g infinite: the
eager path's masks handle it), learnable T-conorm / distribution parameters, max-type T-conorms,
RGB blends; and distributions whose F reaches 1 (a finite upper end of the support: uniform,
reversed one-sided, ...) aggregated other than by the mean are not compiled at all: nearly all
their blocks have a saturated pair. If compiling an instance fails (no C++ compiler, a formula
Dynamo or Inductor rejects) a ``RuntimeWarning`` says why and that instance renders eagerly from
then on; other errors propagate. Results equal eager up to float rounding (the compiler may
contract multiply-adds), see docs/performance.md.
"""
from __future__ import annotations

import math
import types
import warnings

import torch

from gendr.tconorms import MEAN

from .ops import torch_ops as ops

_COMPILED = {}  # key -> (forward, backward) compiled callables
_FAILED = {}  # key -> why compiling it failed (that instance renders eagerly)
_OVER_LIMIT = set()  # keys that hit Dynamo's recompile limit (warned once each)


def generator_chain(dist, tcn, eps, K):
    """The forward chain of one block, as a function of tensors only (what gets compiled)."""
    from .raster import Block, culling_argument, generator_unsaturated, signed_distance
    x_min = culling_argument(dist, eps)  # a constant of the compiled code

    def forward(geom, face, xnum, cnum, H, py, tau, x_cut):
        d = signed_distance(geom.index_select(1, face), K, Block.screen_x(xnum, cnum, H), py)
        return generator_unsaturated(dist, tcn, dist.argument(ops, d, tau), x_min, x_cut)
    return forward


def gradient_chain(dist, tcn, eps, K):
    """The backward chain of one block (no pair saturated in it): (corner sums [K, 4, R], ∂L/∂τ)."""
    from .raster import Block, culling_argument, edge_sums, keep_mask, pair_terms, signed_distance
    x_min = culling_argument(dist, eps)

    def backward(geom, face, xnum, cnum, H, py, tau, x_cut, w):
        d, k, t, ux, uy = signed_distance(geom.index_select(1, face), K, Block.screen_x(xnum, cnum, H), py, track=True)
        # torch.func.jvp only over the pair terms, of x alone: a tensor it did not make (τ, a mask)
        # combined inside it makes the compiled code specialise to one block size (torch 2.13)
        x = dist.argument(ops, d, tau)
        x_d, x_tau = dist.argument_derivative(ops, d, tau), -x / tau
        _, g_x = torch.func.jvp(lambda xx: pair_terms(dist, tcn, xx)[0], (x,), (torch.ones_like(x),))
        wg = w * g_x
        keep = keep_mask(x, x_min, x_cut)  # (outside the jvp, as any tensor it did not make)
        if keep is not None:
            wg = wg * keep
        return edge_sums(wg * x_d, k, t, ux, uy, K, py.shape), (wg * x_tau).sum()
    return backward


def _own_code(fn):
    """``fn`` with a code object of its own. Dynamo keeps compiled variants per code object and
    counts them against ``torch._dynamo.config.recompile_limit`` (8); the closures of one ``def``
    share it, so with ``fullgraph=True`` the 9th instance in a process failed. One code object per
    key keeps each instance's variants (dtype, cutoff) apart, on any torch (``torch.compile``'s
    ``isolate_recompiles`` is recent and still caps the entries of all its regions together)."""
    return types.FunctionType(fn.__code__.replace(), fn.__globals__, fn.__name__, fn.__defaults__,
                              fn.__closure__)


def _errors():
    """(Dynamo's recompile limit hit, the errors that mean "this could not be compiled": no or a
    broken C++ compiler, a formula Dynamo or Inductor rejects). Anything else, e.g. running out of
    memory in the compiled code, propagates as it would eagerly."""
    from torch._dynamo import exc
    from torch._inductor.exc import CppCompileError, InvalidCxxCompiler
    limit = getattr(exc, "FailOnRecompileLimitHit", ())  # (absent from old torch)
    return limit, (exc.TorchDynamoException, InvalidCxxCompiler, CppCompileError)


def _saturates(dist, tcn):
    """F reaches 1 (a finite upper end of the support: uniform, heaviside, reversed one-sided ...)
    and the aggregation is not the mean: p = 1 (log(1 − p) infinite) is a saturated pair, so the
    blocks inside faces rerun eagerly and compiling would cost the compile and a wasted fused pass
    per block for nothing."""
    return tcn.kind != MEAN and dist.support()[1] < math.inf


class FusedChains:
    """The compiled chains of one renderer instance, or eager fallbacks (``None`` results)."""

    def __init__(self, dist, tcn, eps, K, device_type):
        self.key = (dist, tcn, float(eps), int(K), device_type)
        self.ok = not (dist.learnable or tcn.learnable or not tcn.streams or _saturates(dist, tcn))
        self._unsaturated = set()  # ids of the blocks whose forward ran fused (no pair saturated)

    def _label(self):
        return f"{self.key[0].label()} + {self.key[1].label()}"

    def _chains(self):
        if self.key not in _COMPILED:
            dist, tcn, eps, K, _ = self.key
            _COMPILED[self.key] = tuple(torch.compile(_own_code(f(dist, tcn, eps, K)), dynamic=True, fullgraph=True)
                                        for f in (generator_chain, gradient_chain))
        return _COMPILED[self.key]

    def _fail(self, e):
        _FAILED[self.key] = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
        warnings.warn(f"gendr torch backend: compile=True failed for {self._label()} ({_FAILED[self.key]}); "
                      "rendering it eagerly", RuntimeWarning, stacklevel=5)

    def _call(self, which, *args):
        if not self.ok or self.key in _FAILED:
            return None
        try:
            chains = self._chains()
        except RuntimeError as e:  # torch.compile itself refuses (e.g. torch 2.13 on Python 3.15+)
            self._fail(e)
            return None
        try:
            return chains[which](*args)
        except _errors()[0]:  # a new variant of this instance: the compiled ones still run fused
            if self.key not in _OVER_LIMIT:
                _OVER_LIMIT.add(self.key)
                warnings.warn(f"gendr torch backend: compile=True: {self._label()} reached "
                              f"torch._dynamo.config.recompile_limit ({torch._dynamo.config.recompile_limit}); "
                              "its further variants (dtype, cutoff) render eagerly", RuntimeWarning, stacklevel=4)
            return None
        except _errors()[1] as e:
            self._fail(e)
            return None

    def forward(self, geom, blk, tau, x_cut):
        """Generator terms g (shaped as the block's arrays) of raster.Block ``blk``, or None: run it
        eagerly (also when a pair saturated: the eager path's masks handle that, in the backward
        too)."""
        out = self._call(0, geom, blk.face, blk.xnum, blk.cnum, blk.H, blk.py, tau, x_cut)
        if out is None or not bool(torch.isfinite(out[1])):
            return None
        self._unsaturated.add(id(blk))
        return out[0]

    def backward(self, geom, blk, tau, x_cut, w):
        """(corner sums [K, 4, R], ∂L/∂τ) of ``blk`` given ∂L/∂S per pair ``w`` (the block's shape),
        or None: run it eagerly (so do the blocks whose forward did)."""
        if id(blk) not in self._unsaturated:
            return None
        return self._call(1, geom, blk.face, blk.xnum, blk.cnum, blk.H, blk.py, tau, x_cut, w)


def compile_status():
    """None while no compilation failed in this process, else why the first failed (the instances
    that failed render eagerly, the others fused)."""
    return next(iter(_FAILED.values()), None)
