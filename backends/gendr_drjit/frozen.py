"""Frozen renders (``gendr.Renderer(..., backend="drjit", freeze=True)``): ``dr.freeze`` replays.

A render of the same shapes (same instance and settings, image size, camera kind, B, V, F, colour
kind, dtype) is traced once and then *replayed*: Dr.Jit relaunches the recorded kernels with the
new inputs (vertices, camera parameters, τ, colours, faces), with no Python tracing.

What makes a render freezable (everything data-dependent is a Dr.Jit input, nothing is read back):

- the binning is on the device (:class:`raster.Bins`: per-tile face bit masks of a size fixed by
  (B, H, W, F));
- the culling radius, which follows τ, is an opaque Dr.Jit scalar input (computed outside from the
  spec's culling distance);
- near-plane clipping (K = 3 or 4 polygon corners) is part of the recording's key: the replay
  assumes the key's K and returns the device-side flag "every face in front of the near plane",
  which is checked after the replay (one host read); if K = 3 was wrong the render is redone
  with K = 4 (a second recording).

AD: Dr.Jit 1.5 cannot propagate gradients *through* a frozen function (a frozen function is an
isolated gradient scope; "all gradient backpropagation has to start within the recorded function",
docs/freeze.rst). So the frozen render is wrapped in a ``dr.CustomOp``: its forward is one frozen
function (no AD), its backward a second frozen function that re-creates the inputs as AD leaves,
renders, back-propagates the incoming image gradient *inside* the recording and returns the
input gradients. Both replay without tracing; the caller's AD graph (vertices -> ..., τ, camera
parameters) is unaffected. The forward replay returns residuals — the per-pixel generator sums S
(and the saturation counts) of the archimedean T-conorms, the arg-max faces of max, and the tiles'
face masks and order — so the backward replay re-runs neither the forward loop nor the binning
(the RGB blends recompute their loops there).
"""
from __future__ import annotations

import contextlib
import dataclasses
import gc
import math

import drjit as dr

from gendr.renderer import check_screen_reach

from . import raster


class _Static:
    """The Python-side objects of one recording key (settings, camera, faces as NumPy, ...)."""

    def __init__(self, settings, camera, T, ops, Bc, Bv, V, faces_np, cb, per_face, clip, finite):
        self.settings, self.camera, self.T, self.ops = settings, camera, T, ops
        self.Bc, self.Bv, self.V, self.faces_np, self.cb, self.per_face = Bc, Bv, V, faces_np, cb, per_face
        self.clip, self.finite = clip, finite


def settings_key(s):
    """Every setting but τ (an input): each may shape the traced code. Spec parameters are exact
    (their labels round to 6 digits), and new settings are covered without a word here (cutoff
    was missing: a renderer sharing this backend replayed the recording made without one)."""
    rest = tuple((f.name, repr(getattr(s, f.name))) for f in dataclasses.fields(s)
                 if f.name not in ("tau", "distribution", "tconorm"))
    return _spec_key(s.distribution), _spec_key(s.tconorm), rest


def _spec_key(spec):
    return (type(spec).__name__, spec.name, tuple((k, repr(float(v))) for k, v in spec.params),
            *(repr(getattr(spec, a, None)) for a in ("shift", "reversed", "squared")))


def camera_key(camera):
    return (type(camera).__name__, camera.near, camera.far, camera.orthographic,
            tuple(sorted(camera.array_params())))


def _render(st, inp, cull, faces_u, resid=None):
    col = None if inp["col"] is None else (inp["col"], st.cb)
    out, _, fc = raster.render_parts(st.settings, st.camera, st.ops, st.T, inp["P"], st.Bc, inp["v"], st.Bv, st.V,
                                     st.faces_np, col, st.per_face, inp["tau"],
                                     cull_r=cull if st.finite else None, clip=st.clip, faces_u=faces_u, resid=resid)
    return out, (fc.all_inside, fc.reach), fc.resid


class FrozenRenderer:
    """The two frozen functions of one backend object and the registry of their static parts."""

    def __init__(self):
        self.static = {}
        self._faces_cache = None
        self._frozen_forward = dr.freeze(self._forward, warn_after=20)
        self._frozen_backward = dr.freeze(self._backward, warn_after=20)

    def forward(self, *args):
        with _no_gc():
            return self._frozen_forward(*args)

    def backward(self, *args):
        with _no_gc():
            return self._frozen_backward(*args)

    # (``key`` is a string naming everything static: a new key records anew, an old one replays)
    def _forward(self, inp, cull, faces_u, key):
        # (the residuals are outputs too: one loop kernel computes them with the image)
        return _render(self.static[key], inp, cull, faces_u)

    def _backward(self, inp, cull, faces_u, resid, grad_out, need, key):
        st = self.static[key]
        leaves = _copy(inp)  # fresh AD leaves (None entries stay None)
        for path in need:
            dr.enable_grad(_at(leaves, path))
        out, _, _ = _render(st, leaves, cull, faces_u, resid)
        if dr.grad_enabled(out):
            dr.set_grad(out, grad_out)
            dr.enqueue(dr.ADMode.Backward, out)
            dr.traverse(dr.ADMode.Backward)
        return [_grad_or_zero(_at(leaves, path)) for path in need]

    def _faces(self, T, faces_np):
        """The faces as a device array (not mapped NumPy memory, whose alignment would decide between
        recordings), reused while the topology is unchanged."""
        c = self._faces_cache
        if c is None or c[0] is not T.UInt32 or c[1].shape != faces_np.shape or not (c[1] == faces_np).all():
            u = T.UInt32(faces_np.reshape(-1).astype("uint32"))
            u = u + dr.opaque(T.UInt32, 0, 1)
            dr.eval(u)
            c = self._faces_cache = (T.UInt32, faces_np.copy(), u)
        return c[2]

    @property
    def n_recordings(self):
        """Recordings (Python traces) made so far by the forward and backward frozen functions."""
        return self.forward_recordings + self.backward_recordings

    @property
    def forward_recordings(self):
        return self._frozen_forward.n_recordings

    @property
    def backward_recordings(self):
        return self._frozen_backward.n_recordings

    def render(self, settings, camera, T, ops, P, Bc, vflat, Bv, V, faces_np, col, per_face, tau):
        """The image (flat [B·H·W·4]) and B, through the frozen functions (see the module docstring)."""
        H, W = settings.image_size
        F = faces_np.shape[0]
        B = max(Bv, Bc)
        r = raster.culling_radius(settings, settings.tau_value)
        finite = math.isfinite(r)
        cull = dr.opaque(T.Float, r if finite else 0.0, 1)
        faces_u = self._faces(T, faces_np)
        cflat, cb = (None, 0) if col is None else col
        inp = {"v": vflat, "tau": tau, "P": P, "col": cflat}
        # inputs as fresh device arrays: width-1 values (τ, camera scalars) may be literals, which a
        # recording would bake in (or re-record once to make opaque), and arrays that map NumPy
        # memory re-record when their alignment differs from the recording's (AD follows the copy)
        inp = _map(inp, _device_copy)
        need = tuple(path for path, x in _leaves(inp) if dr.grad_enabled(x))

        for clip in (False, True):
            # one string (with the same tuple as the key, a change of only the clipping flag replayed the
            # old recording here; a minimal example re-recorded correctly, so the cause is open)
            key = repr((settings_key(settings), camera_key(camera), T.device, T.double, Bc, Bv, V, F, cb, per_face, clip,
                        finite, raster.wide_layout(r), raster.face_major_backward(r, H), raster.deal_blocks(T)))
            if key not in self.static:
                self.static[key] = _Static(settings, camera, T, ops, Bc, Bv, V, faces_np, cb, per_face, clip, finite)
            st = self.static[key]
            # (equivalent objects; only a recording reads them, and τ never: it is an input)
            st.settings, st.camera, st.faces_np = settings, camera, faces_np
            if need:
                ctx = _OpCtx(self, key, need)
                out = dr.custom(_FrozenOp, inp, cull, faces_u, ctx)
                all_inside, reach = ctx.checks
            else:
                out, (all_inside, reach), _ = self.forward(_detach(inp), cull, faces_u, key)
            if clip or bool(all_inside[0] if dr.width(all_inside) else True):
                # (the unfrozen render checks this before rendering; a replay can only check after)
                check_screen_reach(float(reach[0]), "float64" if T.double else "float32")
                return out, B
        raise AssertionError("unreachable")


@contextlib.contextmanager
def _no_gc():
    """No cyclic garbage collection while a frozen function records or replays: collecting an
    unrelated Dr.Jit array that maps external (NumPy / torch) memory enqueues a host callback, which
    Dr.Jit 1.5 cannot record ("RecordThreadState::enqueue_host_func(): this function cannot be
    recorded!", thrown from a destructor: the process aborts). Collected after, not during."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


class _OpCtx:  # (not a PyTree: dr.custom passes it through as is)
    def __init__(self, frozen, key, need):
        self.frozen, self.key, self.need, self.checks = frozen, key, need, None


class _FrozenOp(dr.CustomOp):
    def eval(self, inp, cull, faces_u, ctx):
        self.inp, self.cull, self.faces_u, self.ctx = inp, cull, faces_u, ctx
        out, ctx.checks, self.resid = ctx.frozen.forward(inp, cull, faces_u, ctx.key)
        return out

    def forward(self):
        raise NotImplementedError("forward-mode AD of a frozen Dr.Jit render is not implemented")

    def backward(self):
        ctx = self.ctx
        grads = ctx.frozen.backward(self.inp, self.cull, self.faces_u, self.resid, _device_copy(self.grad_out()),
                                    ctx.need, ctx.key)
        gin = _zeros_like_tree(self.inp)
        for path, g in zip(ctx.need, grads):
            _set(gin, path, g)
        self.set_grad_in("inp", _tuples(gin))

    def name(self):
        return "gendr frozen render"


# --- small PyTree helpers (dicts / tuples of Dr.Jit arrays, None leaves) ----------------------------
def _leaves(tree, path=()):
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(tree, tuple):
        for i, v in enumerate(tree):
            yield from _leaves(v, path + (i,))
    elif tree is not None:
        yield path, tree


def _at(tree, path):
    for p in path:
        tree = tree[p]
    return tree


def _set(tree, path, value):
    for p in path[:-1]:
        tree = tree[p]
    tree[path[-1]] = value


def _map(tree, fn):
    if isinstance(tree, dict):
        return {k: _map(v, fn) for k, v in tree.items()}
    if isinstance(tree, tuple):
        return tuple(_map(v, fn) for v in tree)
    return None if tree is None else fn(tree)


def _copy(tree):
    return _map(tree, lambda x: type(x)(dr.detach(x)))


def _detach(tree):
    return _map(tree, dr.detach)


def _zeros_like_tree(tree):
    """Like ``tree`` with zero leaves; tuples become lists so that leaves can be set."""
    if isinstance(tree, dict):
        return {k: _zeros_like_tree(v) for k, v in tree.items()}
    if isinstance(tree, tuple):
        return [_zeros_like_tree(v) for v in tree]
    return None if tree is None else dr.zeros(type(tree), dr.width(tree))


def _device_copy(x):
    return x + dr.opaque(type(x), 0.0, 1)


def _tuples(tree):
    """Lists back to tuples (the structure of the op's input)."""
    if isinstance(tree, dict):
        return {k: _tuples(v) for k, v in tree.items()}
    if isinstance(tree, list):
        return tuple(_tuples(v) for v in tree)
    return tree


def _grad_or_zero(x):
    g = dr.grad(x)
    return g if dr.width(g) == dr.width(x) else dr.zeros(type(x), dr.width(x)) + g
