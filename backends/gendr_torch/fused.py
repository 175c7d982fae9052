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
RGB blends. If compilation fails (no C++ compiler, an unsupported formula) a ``RuntimeWarning``
says why and this process renders eagerly from then on. Results equal eager up to float rounding
(the compiler may contract multiply-adds), see docs/performance.md.
"""
from __future__ import annotations

import warnings

import torch

from .ops import torch_ops as ops

_COMPILED = {}  # key -> (forward, backward) compiled callables
_BROKEN = []  # the reason compilation failed in this process (then everything runs eager)


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


class FusedChains:
    """The compiled chains of one renderer instance, or eager fallbacks (``None`` results)."""

    def __init__(self, dist, tcn, eps, K, device_type):
        self.key = (dist, tcn, float(eps), int(K), device_type)
        self.ok = not (_BROKEN or dist.learnable or tcn.learnable or not tcn.streams)
        self._unsaturated = set()  # ids of the blocks whose forward ran fused (no pair saturated)

    def _chains(self):
        if self.key not in _COMPILED:
            dist, tcn, eps, K, _ = self.key
            _COMPILED[self.key] = tuple(torch.compile(f(dist, tcn, eps, K), dynamic=True, fullgraph=True)
                                        for f in (generator_chain, gradient_chain))
        return _COMPILED[self.key]

    def _call(self, which, *args):
        if not self.ok or _BROKEN:
            return None
        try:
            return self._chains()[which](*args)
        except Exception as e:  # compiler missing or a formula the compiler rejects: render eagerly
            _BROKEN.append(f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}")
            warnings.warn(f"gendr torch backend: compile=True failed ({_BROKEN[0]}); rendering eagerly "
                          "in this process", RuntimeWarning, stacklevel=4)
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
    """None while compilation works in this process, else why it failed (renders run eagerly)."""
    return _BROKEN[0] if _BROKEN else None
