"""Frozen Dr.Jit renders (``backend="drjit", freeze=True``): replays give the same images and
gradients as unfrozen renders, an optimisation loop records once (no Python re-tracing), and a
change of shapes (F, image size, clipping) records anew; plus the hand-written backward of the
archimedean alpha sum against Dr.Jit's generic reverse-mode loop, and the device-side binning."""
from __future__ import annotations

import math
import numpy as np
import pytest

dr = pytest.importorskip("drjit", reason="the Dr.Jit backend needs drjit (pip install gendr[drjit])")

import gendr  # noqa: E402
from gendr.scenes import icosphere  # noqa: E402
import gendr_drjit.raster as R  # noqa: E402

MESH = icosphere(1)
FACES = MESH.faces


def _renderer(freeze, tau=0.05, size=(24, 20), **kw):
    kw.setdefault("blend", None)
    return gendr.Renderer("logistic", "probabilistic", tau=tau, image_size=size, eps=1e-4, backend="drjit",
                          device="llvm", freeze=freeze, **kw)


def _fwd_bwd(r, verts, faces=FACES, eye=(0.1, 0.05, 3.0), fov=40.0, tau_grad=False, double=True, w_seed=0, near=0.1):
    """(image, grad vertices, grad eye, grad fov, grad tau) of sum(image * w), all through Dr.Jit."""
    from drjit.llvm.ad import Float64, TensorXf, TensorXf64, Float
    Ten, Fl = (TensorXf64, Float64) if double else (TensorXf, Float)
    v = Ten(np.asarray(verts, np.float64 if double else np.float32))
    e = Ten(np.asarray(eye, np.float64 if double else np.float32))
    f = Fl(fov)
    for x in (v, e, f):
        dr.enable_grad(x)
    tau = None
    if tau_grad:
        tau = Ten(np.array(r.settings.tau_value))
        dr.enable_grad(tau)
        be = r.backend
        r = gendr.Renderer(r.settings.distribution, r.settings.tconorm, tau=tau, image_size=r.settings.image_size,
                           eps=r.settings.eps, blend=r.settings.blend, backend="drjit")
        r.backend = be
    img = r.render(v, faces, gendr.PerspectiveCamera(eye=e, fov_y=f, near=near))
    w = np.random.default_rng(w_seed).standard_normal(img.shape)
    dr.backward(dr.sum((img * Ten(w.astype(np.float64 if double else np.float32))).array))
    out = [img.numpy(), dr.grad(v).numpy(), dr.grad(e).numpy(), dr.grad(f).numpy()]
    out.append(dr.grad(tau).numpy() if tau_grad else None)
    return out


def _close(a, b, tol=1e-10):
    for x, y in zip(a, b):
        if x is None:
            assert y is None
            continue
        assert np.abs(np.asarray(x) - np.asarray(y)).max() <= tol * max(1.0, np.abs(np.asarray(y)).max())


def test_freeze_option():
    r = _renderer(True)
    assert r.backend.frozen is not None
    with pytest.raises(gendr.ParameterError, match="freeze"):
        _renderer("yes")


@pytest.mark.parametrize("double", [True, False])
def test_replay_matches_unfrozen_after_tau_vertex_and_camera_changes(double):
    rng = np.random.default_rng(1)
    first = _renderer(True)  # with_tau shares its backend object: its frozen functions see every call
    shared = first.backend
    for step, (tau, eye, fov) in enumerate([(0.05, (0.1, 0.05, 3.0), 40.0), (0.03, (0.0, 0.2, 2.8), 44.0),
                                           (0.08, (-0.1, 0.0, 3.2), 38.0), (0.05, (0.1, 0.05, 3.0), 40.0)]):
        verts = MESH.vertices * (1.0 + 0.05 * rng.standard_normal(MESH.vertices.shape))
        frozen = first.with_tau(tau)
        assert frozen.backend is shared
        plain = _renderer(False, tau=tau)
        a = _fwd_bwd(frozen, verts, eye=eye, fov=fov, double=double)
        b = _fwd_bwd(plain, verts, eye=eye, fov=fov, double=double)
        # float32: frozen and plain replays run Dr.Jit's multi-threaded scatter-adds, which sum in a
        # varying order (rounding ~1e-7 of the largest value, summed over the faces)
        tol = 1e-10 if double else 2e-5
        _close(a, b, tol)
        assert np.abs(a[1]).max() > 0
    fz = shared.frozen
    # one recording per function (+1 at most: Dr.Jit re-records once when an input changes from
    # mapped NumPy memory to a device array)
    assert fz.forward_recordings <= 2 and fz.backward_recordings <= 2


def test_tau_gradient_frozen():
    verts = MESH.vertices * 1.02
    a = _fwd_bwd(_renderer(True), verts, tau_grad=True)
    b = _fwd_bwd(_renderer(False), verts, tau_grad=True)
    _close(a, b)
    assert abs(float(a[4])) > 0


def test_optimisation_loop_records_once():
    """100 forward+backward steps on changing vertices (a training loop on Dr.Jit arrays): the
    frozen functions are recorded once each and replayed afterwards (no Python tracing); the
    result equals the unfrozen loop."""
    from drjit.llvm.ad import TensorXf
    finals = []
    for freeze in (True, False):
        r = _renderer(freeze, size=(32, 32))
        cam = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=40.0)
        target = _renderer(False, size=(32, 32)).render(MESH.vertices.astype(np.float32) * 1.2, FACES, cam)
        v = TensorXf(MESH.vertices.astype(np.float32))
        v = TensorXf(v * 1.0)  # a device array from the start (see the recording bound above)
        counts = []
        for _ in range(100):
            dr.enable_grad(v)
            img = r.render(v, FACES, cam)
            loss = dr.sum(dr.square(img - target).array)
            dr.backward(loss)
            v = TensorXf(dr.detach(v) - 2e-3 * dr.grad(v))
            dr.eval(v)
            if freeze:
                counts.append((r.backend.frozen.forward_recordings, r.backend.frozen.backward_recordings))
        finals.append(v.numpy())
        if freeze:
            assert counts[0] == (1, 1) and counts[-1] == (1, 1), counts
    # 100 float32 steps, each frozen vs plain only in the order of multi-threaded sums (see above)
    assert np.abs(finals[0] - finals[1]).max() <= 1e-4


def test_shape_changes_record_anew():
    r = _renderer(True)
    fz = r.backend.frozen
    big = icosphere(2)
    cases = [(MESH, (24, 20)), (big, (24, 20)), (MESH, (16, 30)), (MESH, (24, 20)), (big, (24, 20))]
    seen = []
    for mesh, size in cases:
        rr = _renderer(True, size=size)
        rr.backend = r.backend
        a = _fwd_bwd(rr, mesh.vertices, faces=mesh.faces)
        b = _fwd_bwd(_renderer(False, size=size), mesh.vertices, faces=mesh.faces)
        _close(a, b)
        seen.append(fz.forward_recordings)
    # three distinct shapes recorded; the repeats replay
    assert seen[:3] == [1, 2, 3] and seen[3:] == [3, 3]


def test_every_setting_and_exact_spec_parameters_key_the_recording():
    """Renderers sharing one frozen backend: a cut-off (not in the key before) and a T-conorm
    parameter that rounds to the same 6-digit label each record anew, so each matches its own
    unfrozen render (the shared replay returned the first renderer's image, 0.69 off)."""
    r = _renderer(True)
    fz = r.backend.frozen
    variants = [dict(), dict(cutoff=0.1), dict(tcn=gendr.tconorm("yager", p=1.0)),
                dict(tcn=gendr.tconorm("yager", p=1.0000004)), dict()]
    seen = []
    for kw in variants:
        tcn = kw.pop("tcn", "probabilistic")
        make = (lambda freeze: gendr.Renderer("logistic", tcn, tau=0.05, image_size=(24, 20), eps=1e-4, blend=None,
                                              backend="drjit", device="llvm", freeze=freeze, **kw))
        rr = make(True)
        rr.backend = r.backend
        _close(_fwd_bwd(rr, MESH.vertices), _fwd_bwd(make(False), MESH.vertices))
        seen.append(fz.forward_recordings)
    assert seen == [1, 2, 3, 4, 4]


def test_frozen_renders_check_the_screen_reach():
    """A face projected beyond what float32 edge lengths hold is an InputValueError frozen too (the
    frozen path skipped the check: a finite, empty image), on a recording and on a replay."""
    from gendr.errors import InputValueError
    v = MESH.vertices.astype(np.float32)
    for first in ("bad", "good"):
        r = _renderer(True)
        if first == "good":  # then the bad camera replays this recording
            r.render(v, FACES, gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=40.0))
        with pytest.raises(InputValueError, match="beyond what float32 edge lengths can hold"):
            r.render(v, FACES, gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=1e-30))
    assert r.backend.frozen.forward_recordings == 1


def test_backward_layout_follows_the_radius_and_records_anew(monkeypatch):
    """The alpha sums' backward is face-major up to FACE_MAJOR_RADIUS_PX pixels of culling radius
    and pixel-major beyond; the layout is part of the frozen recording key (a τ that crosses the
    threshold records anew, going back replays), and both equal the unfrozen result."""
    calls = []
    for name in ("_face_loop", "_pixel_loop"):
        orig = getattr(R.AlphaSum, name)
        monkeypatch.setattr(R.AlphaSum, name, lambda self, *a, _o=orig, _n=name: calls.append(_n) or _o(self, *a))
    size = (64, 48)  # 16 px = 0.5 screen units: τ 0.08 is beyond it, yet not a wide layout (< 1 unit)
    shared = _renderer(True, size=size).backend
    seen = []
    for tau, traced in ((0.02, "_face_loop"), (0.08, "_pixel_loop"), (0.02, None), (0.08, None)):
        r = _renderer(True, tau=tau, size=size)
        r.backend = shared
        radius = R.culling_radius(r.settings, tau)
        assert R.face_major_backward(radius, size[0]) == (tau == 0.02) and not R.wide_layout(radius)
        calls.clear()
        a = _fwd_bwd(r, MESH.vertices)
        assert calls == ([traced] if traced else [])  # traced while recording; replays run no Python
        _close(a, _fwd_bwd(_renderer(False, tau=tau, size=size), MESH.vertices))
        seen.append(shared.frozen.backward_recordings)
    assert seen == [1, 2, 2, 2]


def test_near_plane_clipping_records_k4():
    """Faces crossing the near plane: the K = 3 replay detects it (device flag) and re-renders with
    the clipped (K = 4) recording; same image and gradients as unfrozen. At 1.25 the crossing faces
    have no index divisible by 4: Dr.Jit 1.5 replays a frozen dr.all from every 4th lane only, so
    the flag read 'all in front' there (image off by 0.25) until it became a UInt32 max."""
    r = _renderer(True, size=(20, 24))
    fz = r.backend.frozen
    counts = []
    for dist in (3.0, 1.25, 1.15, 1.12, 3.0, 1.25):
        cam_eye = (0.0, 0.0, dist)
        a = _fwd_bwd(r, MESH.vertices, eye=cam_eye, fov=70.0, near=0.3)
        b = _fwd_bwd(_renderer(False, size=(20, 24)), MESH.vertices, eye=cam_eye, fov=70.0, near=0.3)
        _close(a, b)
        counts.append(fz.forward_recordings)
    assert len(fz.static) == 2  # K = 3 and K = 4 recordings
    assert counts == [1, 2, 2, 2, 2, 2]


@pytest.mark.parametrize("blend,tcn", [("softmax", "probabilistic"), ("hard", "max"), (None, "or"),
                                       ("softmax", "yager")])
def test_torch_inputs_frozen_match_torch_backend(blend, tcn):
    """torch tensors in (the bridge), RGB blends and non-archimedean T-conorms (no residuals: the
    backward replay recomputes): frozen Dr.Jit equals the torch backend in float64."""
    torch = pytest.importorskip("torch")
    from test_renderer_reference import FACES_SOFTMAX, H, W, make_camera, scene_vertices, vertex_colors
    tconorm = gendr.tconorm(tcn, **({"p": 2.0} if tcn == "yager" else {}))
    outs = []
    for be, kw in (("torch", {}), ("drjit", {"freeze": True}), ("drjit", {"freeze": True})):
        v = scene_vertices().requires_grad_(True)
        tau = torch.tensor(0.1, dtype=torch.float64, requires_grad=True)
        cam, P = make_camera("orbit")
        cols = vertex_colors().requires_grad_(True)
        r = gendr.Renderer("logistic", tconorm, tau=tau, image_size=(H, W), eps=1e-3, blend=blend, backend=be,
                           **kw)
        img = r.render(v, FACES_SOFTMAX, cam, vertex_colors=cols)
        w = torch.randn(img.shape, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
        ins = [v, tau, cols, *P.values()]
        if img.requires_grad:
            gs = torch.autograd.grad((img * w).sum(), ins, allow_unused=True)
        else:
            gs = [None] * len(ins)
        outs.append([img.detach()] + [torch.zeros_like(x) if g is None else g for x, g in zip(ins, gs)])
    for ref, got in ((outs[0], outs[1]), (outs[0], outs[2])):
        for x, y in zip(ref, got):
            assert float((x - y).abs().max()) <= 1e-9


@pytest.mark.parametrize("layout", ["face-major", "face-major 2 chunks", "face-major row chunks", "pixel-major"])
@pytest.mark.parametrize("dist,tcn", [("logistic", "probabilistic"), ("gaussian", "einstein"),
                                      ("gamma", "frank"), ("cauchy", "dombi"), ("uniform", "yager")])
def test_custom_backward_matches_generic_reverse_loop(monkeypatch, dist, tcn, layout):
    """AlphaSum's hand-written backward, in each layout, gives Dr.Jit's generic reverse-mode
    derivatives (vertices, camera, τ), float64."""
    tkw = {"frank": {"p": 10.0}, "dombi": {"p": 2.0}, "yager": {"p": 2.0}}.get(tcn, {})
    dkw = {"gamma": {"shape": 2.0}}.get(dist, {})
    monkeypatch.setattr(R, "FACE_MAJOR_RADIUS_PX", -1.0 if layout == "pixel-major" else math.inf)
    # lanes per face (chunks, summed after the loop): 1, 2, or one per image row
    chunks = {"face-major": 1, "face-major 2 chunks": 2, "face-major row chunks": 1 << 20}.get(layout, 1)
    monkeypatch.setattr(R, "FACE_LANES", chunks * len(MESH.faces))
    res = []
    for custom in (True, False):
        monkeypatch.setattr(R, "CUSTOM_BACKWARD", custom)
        r = gendr.Renderer(gendr.distribution(dist, **dkw), gendr.tconorm(tcn, **tkw), tau=0.05,
                           image_size=(24, 20), eps=1e-3, blend=None, backend="drjit", device="llvm")
        res.append(_fwd_bwd(r, MESH.vertices * 1.01, tau_grad=True))
    _close(res[0], res[1])


@pytest.mark.parametrize("tile", [4, 8, 16, 32])
def test_tile_sizes_agree(monkeypatch, tile):
    """Any tile size (and the bit-mask budget that picks it) gives the same image and gradients:
    a tile only decides which pairs are evaluated, and culled pairs add exactly 0."""
    r0 = _fwd_bwd(_renderer(False, size=(37, 29)), MESH.vertices)
    monkeypatch.setattr(R, "TILE", tile)
    r1 = _fwd_bwd(_renderer(False, size=(37, 29)), MESH.vertices)
    _close(r0, r1, 1e-12)


def test_mask_budget_picks_larger_tiles(monkeypatch):
    assert R.tile_size(1, 256, 256, 1280) == 4
    monkeypatch.setattr(R, "MASK_BYTES", 200_000)
    assert R.tile_size(1, 256, 256, 1280) == 8
    assert R.tile_size(1, 1024, 1024, 20480) == 32


def test_wide_radius_picks_wide_tiles():
    """A culling radius of half the image height or more (heavy tails) takes tiles of at least
    WIDE_TILE pixels (the pair loops then use WIDE_STRIP rows; same results: test_tile_masks_any_tile_size)."""
    assert R.tile_size(24, 64, 64, 1280, radius=0.55) == 4
    assert R.tile_size(24, 64, 64, 1280, radius=1.0) == R.WIDE_TILE == 16
    assert R.tile_size(24, 64, 64, 1280, radius=math.inf) == 16
    assert R.wide_layout(math.inf) and not R.wide_layout(0.99)


def test_tile_order_sorts_tiles_by_face_count():
    """tile_order: a permutation of the tiles and its inverse; a tile placed earlier has at least
    4/5 of the (face count + 1) of any later one (classes a quarter octave wide), and tiles with
    equal counts keep their index order (stable: deterministic lanes)."""
    from types import SimpleNamespace
    import drjit.llvm.ad as L
    rng = np.random.default_rng(3)
    F, n = 200, 500
    nw = -(-F // 32)
    bits = rng.random((n, F)) < rng.choice([0.0, 0.02, 0.1, 0.5, 1.0], size=(n, 1))
    words = np.zeros((n, nw), np.uint64)
    for f in range(F):
        words[:, f // 32] |= bits[:, f].astype(np.uint64) << np.uint64(f % 32)
    bins = SimpleNamespace(mask=L.UInt32(words.astype(np.uint32).ravel()), nw=nw, F=F, mask_tiles=n)
    order, slot = (np.asarray(a) for a in R.tile_order(R.Types(L, False), bins))
    assert sorted(order) == list(range(n)) and (slot[order] == np.arange(n)).all()
    v = bits.sum(1)[order] + 1  # in the new order
    assert (5 * np.minimum.accumulate(v) > 4 * v).all()
    for c in np.unique(v):
        tiles = order[v == c]
        assert (np.diff(tiles) > 0).all()
    assert v[0] == F + 1 and v[-1] == 1


def test_tile_order_changes_no_value(monkeypatch):
    """Lanes in tile_order give the images and gradients of row-major lanes (each pixel still visits
    its tile's faces in ascending order; only the gradient scatter order differs)."""
    calls, order = [], R.tile_order
    monkeypatch.setattr(R, "tile_order", lambda T, bins, *a: calls.append(1) or order(T, bins, *a))
    r0 = _fwd_bwd(_renderer(False, size=(37, 29)), MESH.vertices, tau_grad=True)
    assert calls  # the strips of the probabilistic sum were ordered
    monkeypatch.setattr(R, "tile_order", lambda T, bins, *a: None)
    r1 = _fwd_bwd(_renderer(False, size=(37, 29)), MESH.vertices, tau_grad=True)
    assert np.array_equal(r0[0], r1[0])
    _close(r0, r1, 1e-12)


@pytest.mark.parametrize("n,group", [(6144, 4), (4097, 4), (7, 4), (1000, 1), (37, 16), (16, 16)])
def test_interleave_deals_whole_groups_evenly(n, group):
    """_interleave is a permutation of 0..n−1 that moves groups of ``group`` consecutive ranks
    (a packet's tiles) as one, aligned, a partial last group last; and any stretch of a quarter of
    the positions (a thread's block) holds about a quarter of every quartile of the ranks."""
    from drjit.llvm import UInt32
    T = R.Types(dr.llvm, False)
    pos = np.asarray(R._interleave(T, dr.arange(UInt32, n), n, group))
    assert sorted(pos) == list(range(n))
    full = n // group
    for g in range(full):
        p = pos[g * group:(g + 1) * group]
        assert p[0] % group == 0 and list(p) == list(range(p[0], p[0] + group))
    assert list(pos[full * group:]) == list(range(full * group, n))
    if full >= 64:
        rank_at = np.argsort(pos)
        q = full * group // 4
        for start in (0, q // 3, q, 2 * q + 5):
            quartiles = rank_at[start:start + q] * 4 // (full * group)
            assert np.all(np.abs(np.bincount(quartiles, minlength=4) / q - 0.25) <= 0.05), quartiles


@pytest.mark.parametrize("layout", ["face-major", "pixel-major"])
@pytest.mark.parametrize("tcn", ["probabilistic", "or"])
def test_dealt_lanes_change_no_value(monkeypatch, layout, tcn):
    """Pixel lanes dealt out for several threads (deal_blocks: the tile order interleaved) give the
    images of the plain order bit for bit, and the gradients up to the order of the pixel-major
    scatters (the face-major backward does not read the lane order). One thread: with two, Dr.Jit's
    scatter-adds into the vertices vary in order from run to run."""
    monkeypatch.setattr(R, "FACE_MAJOR_RADIUS_PX", -1.0 if layout == "pixel-major" else math.inf)
    monkeypatch.setattr(R, "FACE_LANES", 2 * len(MESH.faces))  # two chunks per face
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        res = []
        for deal in (False, True):
            monkeypatch.setattr(R, "deal_blocks", lambda T, _d=deal: _d)
            r = gendr.Renderer("logistic", tcn, tau=0.05, image_size=(64, 56), eps=1e-4, blend=None,
                               backend="drjit", device="llvm")
            if tcn == "or":  # (not differentiable)
                res.append([r.render(MESH.vertices, FACES, gendr.PerspectiveCamera(eye=(0.1, 0.05, 3.0))).numpy()])
            else:
                res.append(_fwd_bwd(r, MESH.vertices, tau_grad=True))
    finally:
        dr.set_thread_count(threads)
    assert np.array_equal(res[0][0], res[1][0]) and res[0][0].max() > 0
    if layout == "face-major" and tcn != "or":
        assert np.array_equal(res[0][1], res[1][1])
    _close(res[0], res[1], 1e-12)


@pytest.mark.parametrize("double", [True, False])
@pytest.mark.parametrize("size", [(24, 20), (20, 21)])
def test_face_major_pixel_groups_change_no_value(monkeypatch, size, double):
    """The face-major backward walks a row in groups of FACE_GROUP pixels read with one packet
    gather, starting at multiples of the group (the columns left of the box lie beyond the culling
    radius, so the pair's culling test drops them); an odd image width walks single pixels. Groups
    of 2 and 4 give the images and gradients of single pixels bit for bit (the live pairs are
    visited in the same order; 1 thread)."""
    monkeypatch.setattr(R, "FACE_MAJOR_RADIUS_PX", math.inf)
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        res = {}
        for group in (1, 2, 4):
            monkeypatch.setattr(R, "FACE_GROUP", group)
            res[group] = _fwd_bwd(_renderer(False, tau=0.02, size=size), MESH.vertices, double=double)
    finally:
        dr.set_thread_count(threads)
    assert res[1][0].max() > 0 and np.abs(res[1][1]).max() > 0
    for group in (2, 4):
        for a, b in zip(res[group], res[1]):
            assert (a is None and b is None) or np.array_equal(a, b), group


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("dist,tcn", [("logistic", "probabilistic"), ("cauchy", "max"), ("uniform", "einstein")])
def test_select_minima_of_the_pair_distance_change_no_value(monkeypatch, dist, tcn, dtype):
    """The pair distance's minima and maxima as compare-and-select (R._min, R._max: one x86
    instruction each) give the images and gradients of Dr.Jit's IEEE minimum and maximum bit for
    bit, on the parity scene (a zero-area face, a face crossing the near plane, one behind the
    camera: ties between edges and ±0). One thread: the order of the sums is then fixed."""
    torch = pytest.importorskip("torch")
    from test_drjit_parity import run
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        res = []
        for fns in ((R._min, R._max), (lambda a, b: dr.minimum(a, b), lambda a, b: dr.maximum(a, b))):
            monkeypatch.setattr(R, "_min", fns[0])
            monkeypatch.setattr(R, "_max", fns[1])
            res.append(run("drjit", gendr.distribution(dist), gendr.tconorm(tcn), dtype=getattr(torch, dtype)))
    finally:
        dr.set_thread_count(threads)
    assert torch.equal(res[0][0], res[1][0]) and float(res[0][0][..., 3].max()) > 0
    assert res[0][1].keys() == res[1][1].keys()
    for k in res[0][1]:
        assert torch.equal(res[0][1][k], res[1][1][k]), k


@pytest.mark.parametrize("dist,eps", [(("cauchy", {}), 0.0), (("gaussian", {"squared": True}), 1e-3),
                                      (("gamma", {"shape": 2.0, "reversed": True}), 1e-4)])
def test_replay_heavy_tails_squared_and_eps0(dist, eps):
    """No culling radius (eps = 0, heavy tails) and squared distributions replay correctly too."""
    res = []
    for freeze in (True, False):
        r = gendr.Renderer(gendr.distribution(dist[0], **dist[1]), gendr.tconorm("einstein"), tau=0.02,
                           image_size=(20, 18), eps=eps, blend=None, backend="drjit", freeze=freeze)
        out = [_fwd_bwd(r, MESH.vertices * s, tau_grad=True) for s in (1.0, 1.05, 0.95)]
        res.append(out)
    for a, b in zip(*res):
        _close(a, b)


@pytest.mark.parametrize("tcn", [("hamacher", {"p": 0.0}), ("dombi", {"p": 1.0}), ("schweizer_sklar", {"p": -1.0})])
def test_custom_backward_zero_gradient_where_the_generator_derivative_overflows(monkeypatch, tcn):
    """Reversed squared levy with generators like p/(1 − p), on the parity scene: next to a face
    ∂g/∂x overflows float64 where the pixel's sum saturates (∂A/∂S = 0); the hand-written backward
    gives 0 there, like the generic reverse loop (found by the whole-grid parity run, instances
    1218, 1235, 1240: the τ gradient was inf/NaN)."""
    pytest.importorskip("torch")
    from test_drjit_parity import run
    dist = gendr.distribution("levy", reversed=True, squared=True)
    res = []
    for custom in (True, False):
        monkeypatch.setattr(R, "CUSTOM_BACKWARD", custom)
        res.append(run("drjit", dist, gendr.tconorm(tcn[0], **tcn[1]), eps=1e-3))
    for k, g in res[0][1].items():
        assert bool(g.isfinite().all()), k
        assert float((g - res[1][1][k]).abs().max()) <= 1e-9 * max(1.0, float(res[1][1][k].abs().max())), k


@pytest.mark.parametrize("layout", ["face-major", "face-major 2 chunks", "face-major row chunks"])
@pytest.mark.parametrize("dist,blend,eye,double", [("heaviside", None, (0.1, 0.05, 3.0), False),
                                                   ("heaviside", None, (0.0, 0.0, 2.1), True),   # near 0.95: clipped, K = 4
                                                   ("logistic", None, (0.3, -0.2, 2.5), False),
                                                   # covers beyond the face (F(x) >= 1/2 from x ~ -2.7): the box margin
                                                   (("gamma", 3.0), None, (0.3, -0.2, 2.5), False),
                                                   ("heaviside", "hard", (0.1, 0.05, 3.0), False)])
def test_hard_or_face_major_equals_pixel_major(monkeypatch, layout, dist, blend, eye, double):
    """The hard "or" walks each face's box (alpha_or_faces) up to FACE_MAJOR_RADIUS_PX of culling
    radius: the same image, bit for bit, as the pixel-major loop over the tiles' face lists; without
    an RGB blend it builds no bins."""
    rng = np.random.default_rng(3)
    mesh = icosphere(2)
    verts = mesh.vertices * (1.0 + 0.3 * rng.standard_normal((len(mesh.vertices), 1)))  # uneven face sizes
    chunks = {"face-major": 1, "face-major 2 chunks": 2, "face-major row chunks": 1 << 20}[layout]
    monkeypatch.setattr(R, "FACE_LANES", chunks * len(mesh.faces))
    calls = []
    for name in ("alpha_or_faces", "Bins"):
        orig = getattr(R, name)
        monkeypatch.setattr(R, name, lambda *a, _o=orig, _n=name, **k: calls.append(_n) or _o(*a, **k))
    soft = dist != "heaviside"
    if isinstance(dist, tuple):
        dist = gendr.distribution(dist[0], shape=dist[1], reversed=True)
    imgs = []
    for radius_px in (math.inf, -1.0):
        monkeypatch.setattr(R, "FACE_MAJOR_RADIUS_PX", radius_px)
        r = gendr.Renderer(dist, "or", tau=0.02 if soft else 1.0, image_size=(37, 45), eps=1e-4 if soft else 0.0,
                           blend=blend, backend="drjit", device="llvm")
        from drjit.llvm.ad import TensorXf, TensorXf64
        Ten, dt = (TensorXf64, np.float64) if double else (TensorXf, np.float32)
        cam = gendr.PerspectiveCamera(eye=Ten(np.asarray(eye, dt)), fov_y=60.0, near=0.95 if eye[2] < 2.2 else 0.3)
        imgs.append(r.render(Ten(verts.astype(dt)), mesh.faces, cam).numpy())
    assert calls == (["alpha_or_faces"] if blend is None else ["Bins", "alpha_or_faces"]) + ["Bins"]
    cover = imgs[0][..., 3]
    assert set(np.unique(cover)) == {0.0, 1.0} and 0.05 < cover.mean() < 0.95
    assert np.array_equal(imgs[0], imgs[1])


@pytest.mark.parametrize("tcn,blend", [("probabilistic", None), ("max", None), ("probabilistic", "softmax")])
def test_backward_replay_reuses_the_forward_bins(monkeypatch, tcn, blend):
    """The frozen forward returns the tiles' face masks (and order) with its residuals: the backward
    recording builds no bins of its own (the binning loop ran twice per step before), and the
    result equals the unfrozen render."""
    built = []
    orig = R.Bins.__init__

    def spy(self, *a, mask=None, **k):
        built.append("reused" if mask is not None else "binned")
        orig(self, *a, mask=mask, **k)

    monkeypatch.setattr(R.Bins, "__init__", spy)
    r = gendr.Renderer("logistic", tcn, tau=0.05, image_size=(24, 20), eps=1e-4, blend=blend, backend="drjit",
                       device="llvm", freeze=True)
    a = _fwd_bwd(r, MESH.vertices)
    assert built == ["binned", "reused"]
    monkeypatch.setattr(R.Bins, "__init__", orig)
    _close(a, _fwd_bwd(gendr.Renderer("logistic", tcn, tau=0.05, image_size=(24, 20), eps=1e-4, blend=blend,
                                      backend="drjit", device="llvm"), MESH.vertices))
