"""UV textures and G-buffers: the NumPy reference sampler, backend parity, gradients vs finite
differences, typed errors, OBJ/MTL loading, and the reference-renderer checks (gendr_validation)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import gendr
from gendr import scenes
from gendr.textures import sample_numpy

BACKENDS = ["torch", "drjit"]
H, W = 24, 32
CAM = gendr.orbit_camera(35.0, 25.0, 3.0, fov_y=40.0)


def _backend_ok(name):
    try:
        gendr.Renderer(image_size=2, backend=name)
    except gendr.BackendUnavailableError:
        pytest.skip(f"backend {name} unavailable")


def _np(r, x):
    return np.asarray(r.to_numpy(x))


def _stretched_cube():
    """The textured cube with uvs spread over [-0.3, 1.3]: exercises the wrap modes."""
    m = scenes.textured_cube()
    return scenes.TexturedMesh(m.vertices, m.faces, uvs=m.uvs * 1.6 - 0.3, uv_faces=m.uv_faces, texture=m.texture)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("filt", ["bilinear", "nearest"])
@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_hard_blend_samples_like_the_numpy_reference(backend, filt, wrap):
    """Unlit hard blend = texture sampled at the uv interpolated from the G-buffer's barycentrics
    (gendr.textures.sample_numpy, float64): exact to rounding."""
    _backend_ok(backend)
    m = _stretched_cube()
    r = gendr.Renderer("heaviside", "or", tau=1.0, image_size=(H, W), backend=backend, blend="hard",
                       ambient=1.0, diffuse=0.0, texture_filter=filt, texture_wrap=wrap, background=(0.2, 0.3, 0.4))
    img = _np(r, r.render(m.vertices, m.faces, CAM, texture=m.texture, uvs=m.uvs, uv_faces=m.uv_faces))[0]
    g = r.rasterize(m.vertices, m.faces, CAM)
    fid, bary = _np(r, g.face_id)[0], _np(r, g.bary)[0]
    uv = (bary[..., None] * m.corner_uvs()[np.maximum(fid, 0)]).sum(-2)
    ref = np.where((fid >= 0)[..., None], sample_numpy(m.texture, uv, filt, wrap), (0.2, 0.3, 0.4))
    assert (fid >= 0).sum() > 150
    if filt == "nearest":  # texel index jumps at texel boundaries: leave out uv within 1e-9 texel of one
        x, y = uv[..., 0] * m.texture.shape[1], (1 - uv[..., 1]) * m.texture.shape[0]
        ok = np.minimum(np.abs(x - np.round(x)), np.abs(y - np.round(y))) > 1e-9
    else:
        ok = np.ones(fid.shape, bool)
    np.testing.assert_allclose(img[..., :3][ok], ref[ok], atol=1e-12)
    # uvs really leave [0, 1]: repeat and clamp must then differ somewhere
    assert ((uv < 0) | (uv > 1))[fid >= 0].any()


@pytest.mark.parametrize("blend", ["hard", "softmax"])
def test_backends_agree_lit_batched(blend):
    _backend_ok("drjit")
    m = scenes.textured_cube()
    cam = gendr.orbit_camera(np.array([35.0, -60.0]), 25.0, 3.0, fov_y=40.0)
    tex = np.stack([m.texture, m.texture[::-1]])  # one texture per batch element
    out = []
    for b in BACKENDS:
        r = gendr.Renderer("logistic", "probabilistic", tau=0.02, image_size=(H, W), backend=b, blend=blend,
                           light_direction=(0.3, -0.5, -1.0))
        out.append(_np(r, r.render(m.vertices, m.faces, cam, texture=tex, uvs=m.uvs, uv_faces=m.uv_faces)))
    assert out[0].shape == (2, H, W, 4)
    np.testing.assert_allclose(out[0], out[1], atol=1e-10)
    assert np.abs(out[0][0] - out[0][1]).max() > 0.1


def _fd_check(backend, blend, filt, wrt):
    """Directional derivative of a random-weighted loss: autograd vs central differences (float64)."""
    _backend_ok(backend)
    m = scenes.textured_cube()
    gen = torch.Generator().manual_seed(3)
    verts = torch.tensor(m.vertices) + 0.05 * torch.rand(m.vertices.shape, generator=gen, dtype=torch.float64)
    tex = torch.tensor(m.texture)
    r = gendr.Renderer("logistic", "probabilistic", tau=0.05, image_size=(12, 16), backend=backend, blend=blend, eps=0.0,
                       texture_filter=filt, light_direction=(0.3, -0.5, -1.0))
    w = torch.rand(1, 12, 16, 4, generator=gen, dtype=torch.float64)
    x0 = verts if wrt == "vertices" else tex
    u = torch.randn(x0.shape, generator=gen, dtype=torch.float64)
    u = u / u.abs().max()

    def loss(x):
        v, t = (x, tex) if wrt == "vertices" else (verts, x)
        return (r.render(v, m.faces, CAM, texture=t, uvs=m.uvs, uv_faces=m.uv_faces) * w).sum()

    return _directional(loss, x0, u)


def _directional(loss, x0, u, h=1e-6):
    """(autograd, central difference with step h) of the derivative of ``loss`` at x0 along u."""
    x = x0.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(loss(x), x)
    with torch.no_grad():
        fd = float((loss(x0 + h / 2 * u) - loss(x0 - h / 2 * u)) / h)
    return float((g * u).sum()), fd


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("blend", ["softmax", "hard"])
@pytest.mark.parametrize("filt,wrt", [("bilinear", "vertices"), ("bilinear", "texture"), ("nearest", "texture")])
def test_gradients_match_finite_differences(backend, blend, filt, wrt):
    """Threshold 1e-6 relative: with h = 1e-6 the central difference's truncation error (~h²·f''')
    and round-off (~1e-16·|L|/h, |L| ~ 100) are both ≲ 1e-8 relative; the texture derivative is
    exact up to round-off (the image is linear in the texture)."""
    ad, fd = _fd_check(backend, blend, filt, wrt)
    assert abs(ad) > 1e-3
    assert abs(ad - fd) <= 1e-6 * max(abs(fd), 1.0), (ad, fd)


@pytest.mark.parametrize("backend", BACKENDS)
def test_texture_input_errors(backend):
    _backend_ok(backend)
    m = scenes.textured_cube()
    r = gendr.Renderer(image_size=8, backend=backend, blend="hard")
    kw = dict(texture=m.texture, uvs=m.uvs, uv_faces=m.uv_faces)

    def call(**changes):
        r.render(m.vertices, m.faces, CAM, **(kw | changes))

    with pytest.raises(gendr.ShapeError, match=r"texture must have shape \[Ht, Wt, 3\|4\]"):
        call(texture=m.texture[..., :2])
    with pytest.raises(gendr.DTypeError, match="texture must be float32 or float64.*an 8-bit image: divide by 255"):
        call(texture=(m.texture * 255).astype(np.uint8))
    with pytest.raises(gendr.InputValueError, match=r"uv_faces indices must lie in \[0, 23\].*\[0, 24\]"):
        bad = m.uv_faces.copy()
        bad[3, 1] = 24
        call(uv_faces=bad)
    with pytest.raises(gendr.ShapeError, match=r"uv_faces must have shape \[F, 3\] = \[12, 3\]"):
        call(uv_faces=m.uv_faces[:5])
    with pytest.raises(gendr.ShapeError, match="without uv_faces, uvs must hold one uv per vertex"):
        call(uv_faces=None)
    with pytest.raises(gendr.ShapeError, match=r"uvs must have shape \[T, 2\]"):
        call(uvs=np.zeros((24, 3)))
    with pytest.raises(gendr.InputValueError, match="texture must be finite"):
        t = m.texture.copy()
        t[1, 2, 0] = np.nan
        call(texture=t)
    with pytest.raises(gendr.ParameterError, match="a texture needs uvs"):
        call(uvs=None)
    with pytest.raises(gendr.ParameterError, match="not both"):
        call(vertex_colors=np.ones((8, 3)))
    with pytest.raises(gendr.ParameterError, match="without a texture"):
        r.render(m.vertices, m.faces, CAM, uvs=m.uvs)
    with pytest.raises(gendr.ParameterError, match="texture_filter='trilinear'"):
        gendr.Renderer(texture_filter="trilinear")
    with pytest.raises(gendr.ParameterError, match="texture_wrap='mirror'"):
        gendr.Renderer(texture_wrap="mirror")


_QUAD_V = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
_QUAD_F = [[0, 1, 2], [0, 2, 3]]


def _quad_samples(backend, tex, uvs, filt, wrap, dtype, size=64):
    """An unlit screen-filling quad with per-corner ``uvs`` (affine in x, y: the orthographic camera
    interpolates them linearly), hard blend: (the image's RGB, the uv at each pixel centre)."""
    cam = gendr.OrthographicCamera(eye=(0.0, 0.0, 3.0), xmag=1.0, ymag=1.0)
    r = gendr.Renderer(image_size=size, backend=backend, blend="hard", ambient=1.0, diffuse=0.0,
                       texture_filter=filt, texture_wrap=wrap)
    img = _np(r, r.render(_QUAD_V.astype(dtype), _QUAD_F, cam, texture=tex.astype(dtype), uvs=uvs.astype(dtype)))
    c = 2.0 * (np.arange(size) + 0.5) / size - 1.0
    X, Y = np.meshgrid(c, -c)  # pixel centres; row 0 at the top
    lo, hi = uvs[0], uvs[2]  # corners (−1, −1) and (1, 1)
    uv = np.stack([lo[0] + (X + 1) / 2 * (hi[0] - lo[0]), lo[1] + (Y + 1) / 2 * (hi[1] - lo[1])], -1)
    return img[0, ..., :3], uv


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("dtype,n", [(np.float32, 47), (np.float64, 49)])
@pytest.mark.parametrize("filt", ["bilinear", "nearest"])
def test_repeat_wrap_at_sizes_whose_reciprocal_rounds(backend, dtype, n, filt):
    """Dr.Jit wrapped i − n·floor(i/n) with i/n as i times the rounded 1/n: 47/47 < 1 in float32
    (49/49 in float64), so the texel index n was read (and, backwards, written) out of bounds:
    garbage up to 1e34 along the right and bottom borders, memory corrupted. Both backends now equal
    the NumPy sampler, for uvs in [0, 1] and tiled over −7 … 9."""
    _backend_ok(backend)
    tex = np.random.default_rng(n).random((n, n, 3))
    for lo, hi in ((0.0, 1.0), (-7.0, 9.0)):
        uvs = np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]])
        img, uv = _quad_samples(backend, tex, uvs, filt, "repeat", dtype)
        ref = sample_numpy(tex, uv, filt, "repeat")
        if filt == "nearest":  # leave out pixels within float rounding of a texel boundary
            x, y = uv[..., 0] * tex.shape[1], (1 - uv[..., 1]) * tex.shape[0]
            ok = np.minimum(np.abs(x - np.round(x)), np.abs(y - np.round(y))) > 1e-3
        else:
            ok = np.ones(uv.shape[:2], bool)
        # float32: uv interpolated and reduced in float32 moves a sample by ~1e-6 texel at |uv| <= 9
        tol = 1e-4 if dtype == np.float32 else 1e-10
        np.testing.assert_allclose(img[ok], ref[ok], atol=tol)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_huge_uvs_sample_exactly(backend, wrap):
    """uvs far beyond one period (3e37 in float32: u·Wt overflowed, torch raised IndexError and Dr.Jit
    returned inf; 1e17 in float64: the backends disagreed by 0.08). The samplers reduce uv to one
    period first (gendr.textures.one_period): finite, and equal to the reference's samples."""
    _backend_ok(backend)
    tex = np.random.default_rng(5).random((5, 7, 3))
    for dtype, big in ((np.float32, 3e37), (np.float64, 1e17)):
        uvs = np.array([[big, big], [big, big], [big, big], [big, big]]) * np.array([1.0, -1.0])
        img, _ = _quad_samples(backend, tex, uvs, "bilinear", wrap, dtype, size=8)
        uv0 = uvs[0].astype(dtype).astype(np.float64)
        np.testing.assert_allclose(img, np.broadcast_to(sample_numpy(tex, uv0, "bilinear", wrap), img.shape), atol=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_input_errors_of_the_values_as_given(backend):
    """float64 values that overflow a float32 render, ragged lists and uint64 indices beyond int64:
    typed errors naming the value (Dr.Jit rendered the overflow as inf; ragged lists raised NumPy's
    ValueError; uint64 2^63 + 5 was reported as −9223372036854775803)."""
    _backend_ok(backend)
    m = scenes.textured_cube()
    v32 = m.vertices.astype(np.float32)
    r = gendr.Renderer(image_size=8, backend=backend, blend="hard")
    kw = dict(texture=m.texture, uvs=m.uvs, uv_faces=m.uv_faces)
    for name, value in (("texture", m.texture * 1e300), ("uvs", m.uvs * 1e300)):
        with pytest.raises(gendr.InputValueError, match=rf"{name} must be finite in float32 .*= inf"):
            r.render(v32, m.faces, CAM, **(kw | {name: value}))
    with pytest.raises(gendr.InputValueError, match=r"face_colors must be finite in float32 .*\[0, 0\] = inf"):
        r.render(v32, m.faces, CAM, face_colors=np.full((12, 3), 1e300))
    ragged = {"uvs": [[0.0, 0.0]] * 23 + [[0.0]], "uv_faces": m.uv_faces.tolist()[:-1] + [[0, 1]],
              "texture": [[[0.5, 0.5, 0.5]], [[0.5, 0.5]]]}
    for name, value in ragged.items():
        with pytest.raises(gendr.ShapeError, match=f"{name} must be a regular array"):
            r.render(m.vertices, m.faces, CAM, **(kw | {name: value}))
    with pytest.raises(gendr.ShapeError, match="vertex_colors must be a regular array"):
        r.render(m.vertices, m.faces, CAM, vertex_colors=[[1.0, 0.0, 0.0]] * 7 + [[1.0]])
    uvf = m.uv_faces.astype(np.uint64)
    uvf[0, 0] = 2 ** 63 + 5
    for given in (uvf, torch.as_tensor(uvf)):  # (the Dr.Jit backend wrapped a torch uint64 tensor)
        with pytest.raises(gendr.InputValueError, match="uv_faces holds index 9223372036854775813, beyond int64"):
            r.render(m.vertices, m.faces, CAM, **(kw | {"uv_faces": given}))


def test_textured_mesh_checks():
    m = scenes.textured_cube()
    with pytest.raises(gendr.InputValueError, match="uv_faces must lie in"):
        scenes.TexturedMesh(m.vertices, m.faces, uvs=m.uvs[:10], uv_faces=m.uv_faces, texture=m.texture)
    with pytest.raises(gendr.ShapeError, match="texture must be finite with shape"):
        scenes.TexturedMesh(m.vertices, m.faces, uvs=m.uvs, uv_faces=m.uv_faces, texture=m.texture[0])
    assert m.signed_volume() == pytest.approx(1.0)
    assert not np.array_equal(m.uv_faces, m.faces)
    with pytest.raises(gendr.UnknownNameError):
        scenes.get_textured_scene("nope")


def test_load_textured_obj_roundtrip(tmp_path):
    """OBJ + MTL + PNG written by hand, read through trimesh: renders like the built-in mesh."""
    PIL = pytest.importorskip("PIL.Image")
    pytest.importorskip("trimesh")
    m = scenes.textured_cube()
    PIL.fromarray(np.round(m.texture * 255).astype(np.uint8)).save(tmp_path / "tex.png")
    (tmp_path / "cube.mtl").write_text("newmtl mat\nKd 1 1 1\nmap_Kd tex.png\n")
    lines = ["mtllib cube.mtl", "usemtl mat"]
    lines += [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in m.vertices]
    lines += [f"vt {u:.17g} {v:.17g}" for u, v in m.uvs]
    lines += ["f " + " ".join(f"{a + 1}/{b + 1}" for a, b in zip(f, t)) for f, t in zip(m.faces, m.uv_faces)]
    (tmp_path / "cube.obj").write_text("\n".join(lines) + "\n")
    lm = scenes.load_textured_mesh(tmp_path / "cube.obj")
    assert lm.texture.shape == m.texture.shape
    np.testing.assert_allclose(lm.texture, m.texture, atol=1e-12)
    r = gendr.Renderer("heaviside", "or", tau=1.0, image_size=(H, W), blend="hard", ambient=1.0, diffuse=0.0)
    a = r.render(m.vertices, m.faces, CAM, texture=m.texture, uvs=m.uvs, uv_faces=m.uv_faces)
    b = r.render(lm.vertices, lm.faces, CAM, texture=lm.texture, uvs=lm.uvs, uv_faces=lm.uv_faces)
    np.testing.assert_allclose(_np(r, a), _np(r, b), atol=1e-9)
    (tmp_path / "plain.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(gendr.InputValueError, match="texture"):
        scenes.load_textured_mesh(tmp_path / "plain.obj")


# --------------------------------------------------------------------------------------------
# G-buffers
# --------------------------------------------------------------------------------------------
def _naive_gbuffer(mesh, camera, H, W):
    """Dense float64 z-buffer by ray casting from the camera geometry (independent of the backends):
    face id and view depth of the nearest triangle each pixel-centre ray hits."""
    from gendr_validation.cameras import camera_geometry
    g = camera_geometry(camera)
    assert g.kind == "perspective"
    v = g.view(mesh.vertices)
    t = np.tan(np.radians(g.fov_y) / 2)
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    d = np.stack([(2 * jj / W - 1) * t * W / H, (1 - 2 * ii / H) * t, -np.ones_like(jj)], -1)  # z = -1 rays
    fid, depth = np.full((H, W), -1), np.zeros((H, W))
    best = np.full((H, W), np.inf)
    for f, (a, b, c) in enumerate(v[mesh.faces]):
        n = np.cross(b - a, c - a)
        den = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (a @ n) / den  # ray point s·d, view depth s
            p = s[..., None] * d
            inside = np.ones((H, W), bool)
            for q, r_ in ((a, b), (b, c), (c, a)):
                inside &= (np.cross(r_ - q, p - q) @ n) >= 0
        hit = inside & (s > 0) & (s < best) & np.isfinite(s)
        fid[hit], depth[hit], best[hit] = f, s[hit], s[hit]
    return fid, depth


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("scene", ["icosphere", "torus"])
def test_gbuffer_matches_a_naive_ray_caster(backend, scene):
    _backend_ok(backend)
    from gendr_validation.cameras import camera_geometry, edge_distance
    m = scenes.get_scene(scene)
    r = gendr.Renderer(image_size=(H, W), backend=backend)
    g = r.rasterize(m.vertices, m.faces, CAM)
    fid, depth, bary, normal = (_np(r, x)[0] for x in (g.face_id, g.depth, g.bary, g.normal))
    rfid, rdepth = _naive_gbuffer(m, CAM, H, W)
    ok = edge_distance(m, camera_geometry(CAM), H, W) > 1e-6
    assert (fid[ok] == rfid[ok]).all()
    np.testing.assert_allclose(depth[ok], rdepth[ok], rtol=1e-9)
    vis = fid >= 0
    assert (depth[~vis] == 0).all() and (bary[~vis] == 0).all() and (normal[~vis] == 0).all()
    np.testing.assert_allclose(bary[vis].sum(-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(normal[vis], axis=-1), 1.0, atol=1e-12)
    # perspective-correct barycentrics interpolate in 3D: depth = Σ b_i·depth_i of the face's corners
    zc = -camera_geometry(CAM).view(m.vertices)[m.faces[fid[vis]]][..., 2]
    np.testing.assert_allclose((bary[vis] * zc).sum(-1), depth[vis], rtol=1e-9)
    assert g.mask.shape == (1, H, W)


@pytest.mark.parametrize("backend", BACKENDS)
def test_gbuffer_batched_and_backends_agree(backend):
    _backend_ok(backend)
    m = scenes.get_scene("teapot_like")
    cam = gendr.orbit_camera(np.array([10.0, 100.0, -40.0]), 20.0, 3.0)
    r = gendr.Renderer(image_size=(H, W), backend=backend)
    g = r.rasterize(m.vertices.astype(np.float32), m.faces, cam)
    t = gendr.Renderer(image_size=(H, W), backend="torch").rasterize(m.vertices.astype(np.float32), m.faces, cam)
    assert _np(r, g.depth).shape == (3, H, W) and _np(r, g.depth).dtype == np.float32
    assert (_np(r, g.face_id) == t.face_id.numpy()).all()
    # float32: barycentrics u_i/Σu_i cancel in Σu (Dr.Jit's LLVM fuses multiply-adds, torch does
    # not): 1.4e-5 measured, ~250 float32 ulps at 1
    for a, b in ((g.bary, t.bary), (g.depth, t.depth), (g.normal, t.normal)):
        np.testing.assert_allclose(_np(r, a), b.numpy(), atol=1e-4)
    # each batch element equals its own unbatched render
    one = gendr.Renderer(image_size=(H, W), backend="torch").rasterize(
        m.vertices.astype(np.float32), m.faces, gendr.orbit_camera(100.0, 20.0, 3.0))
    assert (one.face_id[0] == t.face_id[1]).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_gbuffer_depth_gradient_matches_finite_differences(backend):
    _backend_ok(backend)
    m = scenes.get_scene("icosphere", subdivisions=1)
    gen = torch.Generator().manual_seed(0)
    v0 = torch.tensor(m.vertices)
    u = torch.randn(v0.shape, generator=gen, dtype=torch.float64)
    w = torch.rand(1, H, W, 7, generator=gen, dtype=torch.float64)
    r = gendr.Renderer(image_size=(H, W), backend=backend)

    def loss(v):
        g = r.rasterize(v, m.faces, CAM)
        return (torch.cat([g.bary, g.depth[..., None], g.normal], -1) * w).sum()

    ad, fd = _directional(loss, v0, u)
    assert abs(ad - fd) <= 1e-6 * max(abs(fd), 1.0), (ad, fd)


def test_gbuffer_cull_backfaces_and_errors():
    m = scenes.get_scene("cube")
    r = gendr.Renderer(image_size=(H, W), cull_backfaces=True)
    flipped = m.faces[:, ::-1].copy()  # now the far sides face the camera
    front, back = r.rasterize(m.vertices, m.faces, CAM), r.rasterize(m.vertices, flipped, CAM)
    assert (front.face_id == back.face_id).sum() == (front.face_id == -1).sum()  # only background is shared
    vis = front.face_id >= 0
    assert (back.depth[vis] > front.depth[vis]).all()
    with pytest.raises(gendr.InputValueError, match="face indices must lie in"):
        r.rasterize(m.vertices, m.faces + 1, CAM)
    with pytest.raises(gendr.ShapeError):
        r.rasterize(m.vertices[:, :2], m.faces, CAM)


# --------------------------------------------------------------------------------------------
# the reference-renderer checks
# --------------------------------------------------------------------------------------------
def _references():
    from gendr_validation.hardlimit import open_references
    refs = open_references(("pyrender-osmesa", "mitsuba-scalar_rgb"))
    if not refs:
        pytest.skip("no reference renderer available")
    return refs


def test_textures_agree_with_the_references_and_the_check_can_fail():
    from gendr_validation import surfaces
    refs = _references()
    m = scenes.textured_cube()
    res = surfaces.check_textures("textured_cube", m, "perspective", CAM, 48, 64, ["torch"], refs)
    assert len(res) == 2 * len(refs) and all(r.passed for r in res), res
    assert all(r.compared > 500 for r in res)
    # a texture flipped upside down (the classic v-convention bug) must be caught
    bad = scenes.TexturedMesh(m.vertices, m.faces, uvs=m.uvs * np.array([1, -1]) + np.array([0, 1]),
                              uv_faces=m.uv_faces, texture=m.texture)

    class Flipped:  # the references see the correct mesh, gendr the flipped uvs
        def __init__(self, ref):
            self.ref = ref

        def render_textured(self, mesh, *a, **k):
            return self.ref.render_textured(m, *a, **k)

    res = surfaces.check_textures("flipped", bad, "perspective", CAM, 48, 64, ["torch"],
                                  {n: Flipped(r) for n, r in refs.items()})
    assert all(r.differ > 100 for r in res)


def test_gbuffer_agrees_with_the_references():
    from gendr_validation import surfaces
    from gendr_validation.hardlimit import standard_cameras
    refs = _references()
    cams = standard_cameras(48, 64)
    for scene in ("degenerate_mesh", "torus"):
        for cn in ("orthographic", "perspective_near"):
            res = surfaces.check_gbuffer(scene, scenes.get_scene(scene), cn, cams[cn], 48, 64, ["torch"], refs)
            assert all(r.passed for r in res), res
            if "mitsuba-scalar_rgb" in refs:
                assert any(r.face_id_differ == 0 for r in res)


def test_load_textured_glb_roundtrip(tmp_path):
    """A GLB written by trimesh (PBR base-colour texture, glTF's flipped v) reads back through
    load_textured_mesh and renders like the built-in mesh, pixel for pixel (hard blend, nearest)."""
    PIL = pytest.importorskip("PIL.Image")
    trimesh = pytest.importorskip("trimesh")
    m = scenes.textured_cube()
    # one vertex per face corner: glTF has one uv per vertex
    tm = trimesh.Trimesh(m.vertices[m.faces].reshape(-1, 3), np.arange(3 * len(m.faces)).reshape(-1, 3),
                         process=False)
    tm.visual = trimesh.visual.TextureVisuals(
        uv=m.uvs[m.uv_faces].reshape(-1, 2),
        material=trimesh.visual.material.PBRMaterial(
            baseColorTexture=PIL.fromarray(np.round(m.texture * 255).astype(np.uint8))))
    tm.export(tmp_path / "cube.glb")
    lm = scenes.load_textured_mesh(tmp_path / "cube.glb")
    assert lm.texture.shape == m.texture.shape
    np.testing.assert_allclose(lm.texture, m.texture, atol=1e-12)
    r = gendr.Renderer("heaviside", "or", tau=1.0, image_size=(H, W), blend="hard", ambient=1.0, diffuse=0.0,
                       texture_filter="nearest")
    a = r.render(m.vertices, m.faces, CAM, texture=m.texture, uvs=m.uvs, uv_faces=m.uv_faces)
    b = r.render(lm.vertices, lm.faces, CAM, texture=lm.texture, uvs=lm.uvs, uv_faces=lm.uv_faces)
    assert float(_np(r, a)[..., 3].sum()) > 0
    # GLB stores positions and uvs as float32: colours move by ~1e-7 at most (a mirrored or
    # misread texture moves them by whole texel differences, ~0.1 here)
    np.testing.assert_allclose(_np(r, a), _np(r, b), atol=1e-6)


# --------------------------------------------------------------------------------------------
# values checked against formulas computed here (no backend output used as the expectation)
# --------------------------------------------------------------------------------------------
#: a camera whose view frame is not the world frame (a normal reported in view space, or with axes
#: mixed up, differs from the world-space one)
_TILT_CAM = gendr.orbit_camera(-25.0, 15.0, 3.0, fov_y=45.0)
#: a triangle whose unit normal has three distinct components, |n_x| != |n_y| != |n_z|
_TILTED = np.array([[-0.8, -0.6, 0.3], [0.9, -0.4, -0.2], [0.1, 0.8, 0.1]])


def _inside(v, f, camera, size, margin=1e-6):
    """(signed distance d [F, H, W], barycentrics [F, H, W, 3]) from the naive reference's own
    geometry (tests/naive_reference.py: clipping, point-to-segment distances, ray–plane
    barycentrics), and the pixels whose centre lies inside exactly one face by more than ``margin``
    screen units (away from edges, where a pixel could go to either face)."""
    from naive_reference import pixel_face_geometry
    d, _, bary = pixel_face_geometry(torch.tensor(v), torch.tensor(np.asarray(f)), camera, size)
    d, bary = d.numpy()[0], bary.numpy()[0]
    inside = np.nan_to_num(d, nan=-1.0) > margin
    return d, bary, inside, inside.sum(0) == 1


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("winding", ["ccw", "cw"])
def test_gbuffer_normal_of_a_tilted_triangle(backend, winding):
    """One flat triangle: every vertex normal is its face normal, so the G-buffer normal must be
    (v1 − v0) × (v2 − v0) normalised, in world space (docs/conventions.md, G-buffers), at every
    covered pixel; the reversed winding flips it (a clockwise face seen from the camera points away
    from it). Catches swapped or negated components, view-space normals, a normal taken from the
    other winding. Tolerance 1e-12 (float64): the interpolation of three equal unit vectors,
    renormalised, is exact up to rounding."""
    _backend_ok(backend)
    f = np.array([[0, 1, 2]] if winding == "ccw" else [[0, 2, 1]])
    v = _TILTED
    n = np.cross(v[f[0, 1]] - v[f[0, 0]], v[f[0, 2]] - v[f[0, 0]])
    n /= np.linalg.norm(n)
    r = gendr.Renderer(image_size=(H, W), backend=backend)
    g = r.rasterize(v, f, _TILT_CAM)
    fid, normal = _np(r, g.face_id)[0], _np(r, g.normal)[0]
    vis = fid == 0
    assert vis.sum() > 60
    np.testing.assert_allclose(normal[vis], np.broadcast_to(n, normal[vis].shape), rtol=0, atol=1e-12)
    assert (normal[~vis] == 0).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_gbuffer_normal_interpolates_vertex_normals(backend):
    """A fold of two triangles sharing an edge (a roof): the shared corners' normals are the
    area-weighted sums of both faces' (v1 − v0) × (v2 − v0), the others their own face's; the
    G-buffer normal at a pixel is Σ b_k·n̂_k over the visible face's corners, renormalised, with the
    perspective-correct barycentrics b (taken from the naive reference's ray–plane intersection),
    world space. Catches swapped components, face normals in place of the interpolated ones, an
    interpolation with the wrong corners or weights. Tolerance 1e-10: float64 rounding of the
    barycentrics (~1e-15) times normals of norm 1."""
    _backend_ok(backend)
    v = np.array([[-0.9, -0.7, 0.0], [0.8, -0.6, 0.1], [0.0, 0.1, 0.6], [-0.2, 0.9, -0.3]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    vn = np.zeros_like(v)
    for k in range(3):
        np.add.at(vn, f[:, k], fn)
    vn /= np.linalg.norm(vn, axis=1, keepdims=True)
    assert np.abs(vn[0] - vn[1]).max() > 0.3 and np.abs(vn[3] - vn[2]).max() > 0.3  # it does bend
    r = gendr.Renderer(image_size=(H, W), backend=backend)
    g = r.rasterize(v, f, _TILT_CAM)
    fid, normal = _np(r, g.face_id)[0], _np(r, g.normal)[0]
    d, bary, inside, one = _inside(v, f, _TILT_CAM, (H, W))
    checked = 0
    for k in range(2):
        sel = one & inside[k]
        assert (fid[sel] == k).all()
        want = (bary[k][sel][..., None] * vn[f[k]]).sum(-2)
        want /= np.linalg.norm(want, axis=-1, keepdims=True)
        np.testing.assert_allclose(normal[sel], want, rtol=0, atol=1e-10)
        checked += sel.sum()
    assert checked > 80


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("blend", ["hard", "softmax"])
def test_textured_shading_is_texture_times_lambert(backend, blend):
    """The documented textured colour, texture(uv)·(ambient + diffuse·max(0, n̂·(−l̂))), at every
    pixel well inside one tilted flat triangle (its vertex normals are its face normal, so Lambert
    is one number here, computed from the corners and the light): uv from the naive reference's
    perspective-correct barycentrics, texture(uv) from gendr.textures.sample_numpy (float64
    NumPy). Both blends: at these pixels the softmax's background weight exp((ε − z̃)/γ) is ~e^-9000
    at the default γ = 1e-4, so it returns the face's colour too. Catches a backend that drops the
    lighting factor for textured faces (or applies it twice, or lights with another light).
    Tolerance 1e-10: float64, bilinear weights moved by rounding of the uvs (~1e-15) times texel
    differences < 1."""
    _backend_ok(backend)
    v, f = _TILTED, np.array([[0, 1, 2]])
    uvs = np.array([[0.1, 0.15], [0.95, 0.3], [0.4, 0.9]])
    tex = scenes.checker_texture(12, 18, square=3)
    ambient, diffuse, light = 0.25, 0.6, np.array([0.5, -0.3, -1.0])
    n = np.cross(v[1] - v[0], v[2] - v[0])
    lam = max(0.0, float(n @ -light) / np.linalg.norm(n) / np.linalg.norm(light))
    shade = ambient + diffuse * lam
    assert 0.3 < lam < 0.95 and abs(shade - 1.0) > 0.1  # lit partly: the factor is not 1
    r = gendr.Renderer("logistic", "probabilistic", tau=0.002, image_size=(H, W), backend=backend, blend=blend,
                       eps=1e-6, ambient=ambient, diffuse=diffuse, light_direction=tuple(light),
                       background=(0.9, 0.1, 0.5))
    img = _np(r, r.render(v, f, _TILT_CAM, texture=tex, uvs=uvs))[0]
    d, bary, inside, one = _inside(v, f, _TILT_CAM, (H, W), margin=0.05)  # 0.05 = 25τ: coverage 1 − 1e-11
    sel = one & inside[0]
    assert sel.sum() > 40
    uv = (bary[0][sel][..., None] * uvs[f[0]]).sum(-2)
    want = sample_numpy(tex, uv) * shade
    np.testing.assert_allclose(img[sel][:, :3], want, rtol=0, atol=1e-10)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("blend", ["hard", "softmax"])
def test_constant_texture_renders_like_vertex_colours(backend, blend):
    """A texture of one colour c shades every pixel as vertex colours c do (texture(uv) = c for any
    uv), under the same non-default light and blend, at every pixel: the smooth (interpolated)
    Lambert factor of a sphere, soft edges, and with γ = 0.05 the softmax mixing faces at different
    depths and the background. The vertex-colour path is checked against the naive reference
    (test_renderer_reference.py), so this pins the textured path's lighting and blending to it.
    Catches textured faces rendered without the lighting factor (the image would be c instead of
    c·(ambient + diffuse·lambert)), lit per face instead of per vertex, or weighed differently in the
    blend. Tolerance 1e-12: float64; the two paths multiply the same numbers in another order."""
    _backend_ok(backend)
    m = scenes.icosphere(1)
    c = np.array([0.8, 0.55, 0.3])
    tex = np.broadcast_to(c, (5, 7, 3)).copy()
    uvs = np.random.default_rng(3).uniform(-0.5, 1.5, (len(m.vertices), 2))  # any uv samples c
    r = gendr.Renderer("logistic", "probabilistic", tau=0.03, image_size=(H, W), backend=backend, blend=blend,
                       gamma=0.05, ambient=0.2, diffuse=0.7, light_direction=(0.6, -0.4, -1.0),
                       background=(0.1, 0.2, 0.9))
    textured = _np(r, r.render(m.vertices, m.faces, CAM, texture=tex, uvs=uvs))[0]
    coloured = _np(r, r.render(m.vertices, m.faces, CAM, vertex_colors=np.broadcast_to(c, m.vertices.shape).copy()))[0]
    np.testing.assert_allclose(textured, coloured, rtol=0, atol=1e-12)
    # the lighting does vary over the image (so a missing factor shows), and differs from 1
    covered = coloured[..., 3] > 0.99
    assert covered.sum() > 100
    ratio = coloured[covered][:, 0] / c[0]
    assert ratio.min() < 0.5 and ratio.max() - ratio.min() > 0.3
