"""Built-in procedural meshes, normalisation and mesh loading (gendr.scenes)."""
import math
import subprocess
import sys

import numpy as np
import pytest

from gendr.errors import GendrError, InputValueError, ParameterError, ShapeError, UnknownNameError
from gendr.scenes import (CLOSED_SCENES, SCENES, Mesh, cube, get_scene, icosphere, load_mesh,
                          normalize, torus)

trimesh = pytest.importorskip("trimesh")


def _tm(mesh):
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


@pytest.fixture(scope="module")
def meshes():
    return {name: fn() for name, fn in SCENES.items()}


def test_registry_lists_the_required_scenes():
    assert set(SCENES) == {"icosphere", "cube", "torus", "thin_shape", "airplane", "chair", "teapot_like",
                           "tetrahedron", "open_mesh", "degenerate_mesh"}
    assert set(CLOSED_SCENES) <= set(SCENES)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_dtypes_shapes_indices_and_unit_ball(meshes, name):
    m = meshes[name]
    assert isinstance(m, Mesh)
    assert m.vertices.dtype == np.float64 and m.vertices.ndim == 2 and m.vertices.shape[1] == 3
    assert m.faces.dtype == np.int64 and m.faces.ndim == 2 and m.faces.shape[1] == 3
    assert m.num_faces > 0
    assert m.faces.min() >= 0 and m.faces.max() < m.num_vertices
    assert np.all(np.isfinite(m.vertices))
    assert m.bounding_radius <= 1.0 + 1e-12
    centre = 0.5 * (m.vertices.min(0) + m.vertices.max(0))
    assert np.linalg.norm(centre) < 0.25, "roughly centred at the origin"
    # deterministic
    again = SCENES[name]()
    assert np.array_equal(again.vertices, m.vertices) and np.array_equal(again.faces, m.faces)


@pytest.mark.parametrize("s, faces, vertices", [(0, 20, 12), (1, 80, 42), (2, 320, 162), (3, 1280, 642)])
def test_icosphere_counts(s, faces, vertices):
    m = icosphere(s)
    assert (m.num_faces, m.num_vertices) == (faces, vertices)
    assert np.allclose(np.linalg.norm(m.vertices, axis=1), 1.0)


def test_icosphere_default_and_subdivision_5():
    m = icosphere()
    assert (m.num_faces, m.num_vertices) == (1280, 642)
    assert icosphere(5).num_faces == 20480
    r = icosphere(1, radius=0.5)
    assert np.allclose(np.linalg.norm(r.vertices, axis=1), 0.5)


@pytest.mark.parametrize("name", CLOSED_SCENES)
def test_closed_scenes_are_watertight_and_outward(meshes, name):
    m = meshes[name]
    tm = _tm(m)
    assert tm.is_watertight, name
    assert tm.is_winding_consistent, name
    assert m.signed_volume() > 0, name
    assert math.isclose(m.signed_volume(), tm.volume, rel_tol=1e-9)
    for part in tm.split(only_watertight=False):  # every part of a composite points outwards
        assert part.volume > 0, name
    # Euler characteristic: 2 per genus-0 part; the torus (and the teapot's ring handle) have genus 1
    parts = len(tm.split(only_watertight=False))
    handles = {"torus": 1, "teapot_like": 1}.get(name, 0)
    assert tm.euler_number == 2 * parts - 2 * handles, name


def test_part_counts(meshes):
    counts = {n: len(_tm(meshes[n]).split(only_watertight=False)) for n in ("airplane", "chair", "teapot_like")}
    assert counts["chair"] == 6  # seat, back, four legs
    assert counts["airplane"] >= 4  # fuselage, wings, tail, fin (+ engines)
    assert counts["teapot_like"] >= 4  # body, spout, handle, knob (+ lid)


def test_single_part_euler_numbers(meshes):
    for name, chi in (("icosphere", 2), ("cube", 2), ("tetrahedron", 2), ("thin_shape", 2), ("torus", 0)):
        m = meshes[name]
        edges = {tuple(sorted(e)) for f in m.faces.tolist() for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
        assert m.num_vertices - len(edges) + m.num_faces == chi, name


def test_outward_normals_point_away_from_centre_for_convex_scenes(meshes):
    for name in ("icosphere", "cube", "tetrahedron"):
        m = meshes[name]
        centroids = m.vertices[m.faces].mean(axis=1)
        assert np.all(np.einsum("ij,ij->i", m.face_normals(), centroids) > 0), name


def test_teapot_is_asymmetric(meshes):
    v = meshes["teapot_like"].vertices
    # not symmetric under x -> -x (spout on one side, handle on the other) nor under z -> -z rotation
    assert not np.allclose(np.sort(-v[:, 0]), np.sort(v[:, 0]), atol=1e-3)
    spout_tip = v[np.argmax(v[:, 0])]
    assert spout_tip[1] > 0.1  # the spout rises


def test_thin_shape_is_thin(meshes):
    m = meshes["thin_shape"]
    ext = np.linalg.svd(m.vertices - m.vertices.mean(0), compute_uv=False)
    assert ext[0] > 20 * ext[1]


def test_open_mesh_is_open_with_consistent_winding(meshes):
    tm = _tm(meshes["open_mesh"])
    assert not tm.is_watertight
    assert tm.is_winding_consistent
    boundary = trimesh.grouping.group_rows(tm.edges_sorted, require_count=1)
    assert len(boundary) > 0


def test_degenerate_mesh_has_zero_area_and_tiny_faces(meshes):
    m = meshes["degenerate_mesh"]
    areas = m.face_areas()
    assert np.sum(areas == 0) >= 2
    assert np.any((areas > 0) & (areas < 1e-12))
    assert np.any(areas > 0.1)  # and some real ones
    assert len(np.unique(m.faces)) < m.num_vertices  # an unused vertex


def test_torus_parameters():
    m = torus(0.5, 0.2, 10, 6)
    assert m.num_faces == 2 * 10 * 6 and m.num_vertices == 60
    assert m.signed_volume() > 0
    exact = 2 * math.pi ** 2 * 0.5 * 0.2 ** 2
    assert 0.7 * exact < m.signed_volume() < exact
    with pytest.raises(InputValueError, match="r < R"):
        torus(0.2, 0.5)


def test_cube_size_and_volume():
    assert math.isclose(cube(0.5).signed_volume(), 0.125)
    assert np.allclose(np.abs(cube(2.0).vertices), 1.0)
    with pytest.raises(InputValueError, match="size"):
        cube(-1.0)
    with pytest.raises(InputValueError, match="subdivisions"):
        icosphere(-1)


def test_get_scene_and_unknown_name():
    assert get_scene("cube").num_faces == 12
    assert get_scene("icosphere", subdivisions=1).num_faces == 80
    with pytest.raises(UnknownNameError) as info:
        get_scene("teapot")
    msg = str(info.value)
    assert "teapot" in msg and "teapot_like" in msg and "icosphere" in msg
    assert info.value.kind == "scene" and isinstance(info.value, GendrError)


def test_mesh_validation():
    with pytest.raises(ShapeError, match=r"\[V, 3\]"):
        Mesh(np.zeros((4, 2)), np.zeros((1, 3), dtype=int))
    with pytest.raises(ShapeError, match=r"\[F, 3\]"):
        Mesh(np.zeros((4, 3)), np.zeros((1, 4), dtype=int))
    with pytest.raises(InputValueError, match="indices"):
        Mesh(np.zeros((4, 3)), [[0, 1, 4]])
    m = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    assert m.vertices.dtype == np.float64 and m.faces.dtype == np.int64
    assert np.allclose(m.face_normals(), [[0, 0, 1]])
    assert np.allclose(m.vertex_normals(), [[0, 0, 1]] * 3)


def test_normalize():
    m = Mesh(icosphere(1).vertices * 7.0 + [10.0, -3.0, 2.0], icosphere(1).faces)
    n = normalize(m)
    assert math.isclose(n.bounding_radius, 1.0)
    assert np.allclose(0.5 * (n.vertices.min(0) + n.vertices.max(0)), 0.0, atol=1e-12)
    assert np.array_equal(n.faces, m.faces)
    assert math.isclose(normalize(m, radius=0.5).bounding_radius, 0.5)


@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "off"])
def test_load_mesh_round_trip(tmp_path, ext):
    src = get_scene("chair")
    path = tmp_path / f"chair.{ext}"
    _tm(src).export(path)
    m = load_mesh(path)
    assert m.num_faces == src.num_faces
    # same triangle corners (vertex order may differ between formats)
    assert np.allclose(np.sort(np.round(m.vertices[m.faces].reshape(-1, 3), 5), axis=0),
                       np.sort(np.round(src.vertices[src.faces].reshape(-1, 3), 5), axis=0), atol=1e-5)
    assert m.signed_volume() == pytest.approx(src.signed_volume(), rel=1e-4)  # winding survived


def test_load_mesh_scene_with_several_geometries(tmp_path):
    scene = trimesh.Scene([_tm(get_scene("cube")), _tm(get_scene("tetrahedron"))])
    path = tmp_path / "two.glb"
    scene.export(path)
    m = load_mesh(path)
    assert m.num_faces == 12 + 4


def test_load_mesh_errors(tmp_path):
    with pytest.raises(InputValueError, match="nope.obj"):
        load_mesh(tmp_path / "nope.obj")
    bad = tmp_path / "garbage.ply"
    bad.write_bytes(b"this is not a mesh\x00\x01")
    with pytest.raises(InputValueError, match="garbage.ply"):
        load_mesh(bad)
    points = tmp_path / "points.obj"
    points.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(InputValueError, match="points.obj"):
        load_mesh(points)
    with pytest.raises(InputValueError, match="is not a file"):
        load_mesh(tmp_path)


def test_import_gendr_scenes_does_not_import_torch_or_trimesh():
    code = ("import sys, gendr, gendr.scenes, gendr.images, gendr.cli; "
            "assert 'torch' not in sys.modules; assert 'trimesh' not in sys.modules; assert 'PIL' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_a_scene_keyword_it_does_not_take_names_the_accepted_ones():
    """(a raw TypeError before)"""
    with pytest.raises(ParameterError, match="'subdivision'.*subdivisions, radius"):
        get_scene("icosphere", subdivision=2)


@pytest.mark.parametrize("path", [None, 3, ["a.obj"]])
def test_load_mesh_needs_a_path(path):
    with pytest.raises(InputValueError, match="str or os.PathLike"):
        load_mesh(path)


def test_scene_inputs_raise_typed_errors():
    """(each was a raw TypeError / ValueError, or a silently wrong texture)"""
    from gendr import scenes

    with pytest.raises(ParameterError, match="textured scene 'textured_cube' got unexpected parameter 'foo'"):
        scenes.get_textured_scene("textured_cube", foo=1)
    with pytest.raises(InputValueError, match=r"mesh vertices must be numbers of shape \[V, 3\]"):
        scenes.Mesh([[0.0, 0.0], [1.0, 0.0, 0.0]], [[0, 1, 1]])
    with pytest.raises(InputValueError, match="could not convert string"):
        scenes.Mesh([["a", "b", "c"]], [])
    with pytest.raises(InputValueError, match="at least one mesh"):
        scenes.concatenate([])
    m = scenes.textured_cube()
    as_bytes = scenes.TexturedMesh(m.vertices, m.faces, m.uvs, m.uv_faces, np.round(m.texture * 255).astype(np.uint8))
    np.testing.assert_allclose(as_bytes.texture, m.texture, atol=0.5 / 255)


def test_review_fixes_of_mesh_loading(tmp_path):
    """OBJ index 0 (trimesh read it as the last vertex: a wrong face), a textured OBJ without a
    texture map (trimesh made up a grey 2×2 image), per-face normals (a triangle soup: merge_vertices)."""
    from gendr.scenes import load_mesh, load_textured_mesh, merge_vertices
    (tmp_path / "zero.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n")
    with pytest.raises(InputValueError, match="line 4: 'f 0 1 2' has index 0; OBJ indices start at 1"):
        load_mesh(tmp_path / "zero.obj")
    body = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"
    (tmp_path / "nomtl.obj").write_text(body)
    (tmp_path / "gone.obj").write_text("mtllib gone.mtl\n" + body)
    for name in ("nomtl.obj", "gone.obj"):
        with pytest.raises(InputValueError, match="has no texture image: no map_Kd"):
            load_textured_mesh(tmp_path / name)
    # what trimesh reads stays accepted: a lower-case key, a material file name with a space
    from gendr.images import write_png
    write_png(tmp_path / "t.png", np.full((4, 4, 3), 0.5))
    (tmp_path / "my mat.mtl").write_text("newmtl m\nmap_kd t.png\n")
    (tmp_path / "space.obj").write_text("mtllib my mat.mtl\nusemtl m\n" + body)
    assert load_textured_mesh(tmp_path / "space.obj").texture.shape == (4, 4, 3)
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nvn 0 0 -1\n"
                                       "f 1//1 2//1 3//1\nf 2//2 4//2 3//2\n")
    soup = load_mesh(tmp_path / "flat.obj")
    merged = merge_vertices(soup)
    assert soup.num_vertices == 6 and merged.num_vertices == 4  # trimesh splits by normal; merged back
    np.testing.assert_array_equal(merged.vertices[merged.faces], soup.vertices[soup.faces])


def test_review_fixes_of_mesh_values():
    from gendr.scenes import TexturedMesh, cube, normalize
    for faces, words in (([["0", "1", "2"]], "must be integers, got dtype <U1"),
                         ([[0, 1, None]], "must be integers, got dtype object"),
                         ([[0, 1, 1e20]], r"must lie in \[0, 3\), got range \[0, 1e\+20\]")):
        with pytest.raises(InputValueError, match=words):
            Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces)
    assert normalize(cube(), np.float32(2)).bounding_radius == pytest.approx(2.0)
    big = normalize(Mesh([[-1e200, -1e200, 0], [1e200, -1e200, 0], [-1e200, 1e200, 0]], [[0, 1, 2]]))
    assert big.bounding_radius == pytest.approx(1.0)  # (was all zeros: the norm overflowed)
    kw = dict(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]], uvs=[[0, 0], [1, 0], [0, 1]],
              uv_faces=[[0, 1, 2]])
    assert TexturedMesh(**kw, texture=np.full((2, 2, 3), 65535, np.uint16)).texture.max() == 1.0
    with pytest.raises(InputValueError, match="texture of dtype int32"):
        TexturedMesh(**kw, texture=np.ones((2, 2, 3), np.int32))


def test_review_fixes_of_images_and_interop(tmp_path):
    from gendr.images import contact_sheet, write_png
    from gendr.interop import project_points
    from gendr import PerspectiveCamera
    with pytest.raises(InputValueError, match="background must be finite"):
        contact_sheet([np.zeros((2, 2, 4))], background=float("nan"))
    with pytest.raises(FileNotFoundError, match=f"cannot write '{tmp_path}/no/x.png': the folder"):
        write_png(tmp_path / "no" / "x.png", np.zeros((2, 2, 3)))
    for size in ("88", (8.9, 8.9), True):
        with pytest.raises(ParameterError, match="project_points parameter image"):
            project_points(PerspectiveCamera(), np.zeros((1, 3)), size)
