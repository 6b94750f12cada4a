"""Reading mesh files: every supported format, scaling, and a one-line ShapeError naming the file for
each kind of bad input."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from physdyn.errors import ShapeError
from physdyn.geometry.mesh_io import MESH_EXTENSIONS, PreparedMesh, load_mesh, prepare_mesh

EXTENTS = np.array([0.1, 0.2, 0.3])


@pytest.mark.parametrize("ext", [e.lstrip(".") for e in MESH_EXTENSIONS])
def test_loads_every_format_and_applies_scale(tmp_path, ext):
    path = tmp_path / f"box.{ext}"
    trimesh.creation.box(extents=EXTENTS).export(path)
    mesh = load_mesh(path)
    np.testing.assert_allclose(mesh.extents, EXTENTS, rtol=1e-6)
    assert mesh.is_watertight and np.isclose(mesh.volume, np.prod(EXTENTS), rtol=1e-5)
    scaled = load_mesh(str(path), scale=2.5)
    np.testing.assert_allclose(scaled.extents, 2.5 * EXTENTS, rtol=1e-6)


def test_uppercase_extension_is_accepted(tmp_path):
    path = tmp_path / "BOX.OBJ"
    trimesh.creation.box(extents=EXTENTS).export(path, file_type="obj")
    assert load_mesh(path).is_volume


def test_a_scene_is_baked_into_one_mesh(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box(extents=(0.1, 0.1, 0.1)), node_name="a")
    moved = trimesh.transformations.translation_matrix([0.3, 0.0, 0.0])
    scene.add_geometry(trimesh.creation.box(extents=(0.1, 0.1, 0.1)), node_name="b", transform=moved)
    path = tmp_path / "scene.glb"
    scene.export(path)
    mesh = load_mesh(path)
    assert mesh.body_count == 2
    np.testing.assert_allclose(mesh.extents, [0.4, 0.1, 0.1], rtol=1e-6)  # node transform applied


def _write(path, content):
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    return path


TETRA_NAN = "v 0 0 0\nv 0.1 0 0\nv 0 nan 0\nv 0 0 0.1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n"
TETRA_INF = TETRA_NAN.replace("nan", "inf")
FLAT = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0.1 0.1 0\nf 1 2 3\nf 2 4 3\nf 1 3 2\nf 2 3 4\n"
LINE = "v 0 0 0\nv 0.1 0 0\nv 0.2 0 0\nf 1 2 3\n"
POINTS_ONLY = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\n"

BAD_FILES = {
    "empty.obj": ("", "empty file"),
    "garbage.stl": (bytes(range(256)) * 3, "no triangles"),
    "garbage.ply": (b"\x00\x01 not a ply file at all" * 10, "could not be read"),
    "garbage.glb": (b"glTF\x02\x00\x00\x00" + b"\xff" * 40, "could not be read"),
    "garbage.off": ("this is not\nan OFF file\n", "could not be read"),
    "points.obj": (POINTS_ONLY, "no triangles"),
    "nan.obj": (TETRA_NAN, "NaN or infinite"),
    "inf.obj": (TETRA_INF, "NaN or infinite"),
    "flat.obj": (FLAT, "zero volume"),
    "line.obj": (LINE, "zero volume"),
    "model.fbx": ("anything", "unsupported format"),
    "noext": ("anything", "unsupported format"),
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_bad_file_gives_one_line_shape_error_naming_it(tmp_path, name):
    content, problem = BAD_FILES[name]
    path = _write(tmp_path / name, content)
    with pytest.raises(ShapeError) as err:
        load_mesh(path)
    message = str(err.value)
    assert str(path) in message and problem in message
    assert "\n" not in message


def test_missing_file(tmp_path):
    path = tmp_path / "nowhere" / "cup.obj"
    with pytest.raises(ShapeError, match="not found") as err:
        load_mesh(path)
    assert str(path) in str(err.value)


def test_a_folder_is_not_a_mesh(tmp_path):
    folder = tmp_path / "cup.obj"
    folder.mkdir()
    with pytest.raises(ShapeError, match="not a file"):
        load_mesh(folder)


@pytest.mark.parametrize("extents, scale", [((100.0, 100.0, 100.0), 1.0), ((0.5, 0.5, 0.5), 0.001)])
def test_absurd_size_asks_for_a_scale(tmp_path, extents, scale):
    path = tmp_path / "box.stl"
    trimesh.creation.box(extents=extents).export(path)
    with pytest.raises(ShapeError, match="pass a scale") as err:
        load_mesh(path, scale=scale)
    assert str(path) in str(err.value)


def test_millimetre_file_loads_with_a_scale(tmp_path):
    path = tmp_path / "box_mm.stl"
    trimesh.creation.box(extents=(100.0, 200.0, 300.0)).export(path)
    np.testing.assert_allclose(load_mesh(path, scale=0.001).extents, EXTENTS, rtol=1e-6)


@pytest.mark.parametrize("scale", [0.0, -1.0, float("nan")])
def test_bad_scale(tmp_path, scale):
    path = tmp_path / "box.obj"
    trimesh.creation.box(extents=EXTENTS).export(path)
    with pytest.raises(ShapeError, match="scale"):
        load_mesh(path, scale=scale)


# --------------------------------------------------------------------------------------------------
# prepare_mesh
# --------------------------------------------------------------------------------------------------
def _two_cubes_sharing_an_edge() -> trimesh.Trimesh:
    a = trimesh.creation.box(bounds=[[0.0, 0.0, 0.0], [0.1, 0.1, 0.1]])
    b = trimesh.creation.box(bounds=[[0.1, 0.1, 0.0], [0.2, 0.2, 0.1]])
    return trimesh.util.concatenate([a, b])


def test_non_manifold_file_loads_and_prepares_without_crashing(tmp_path):
    path = tmp_path / "two_cubes.obj"
    _two_cubes_sharing_an_edge().export(path)
    mesh = load_mesh(path)
    prepared = prepare_mesh(mesh, str(path))
    assert isinstance(prepared, PreparedMesh)
    # Four faces meet at the shared edge: not a 2-manifold, so exact mass properties are not trusted.
    assert not prepared.watertight
    assert any(str(path) in w and "convex hull" in w for w in prepared.warnings)


def test_duplicated_face_is_removed(tmp_path):
    cube = trimesh.creation.box(extents=EXTENTS)
    faces = np.vstack([cube.faces, cube.faces[:1]])
    path = tmp_path / "dup.obj"
    trimesh.Trimesh(cube.vertices, faces, process=False).export(path)
    mesh = load_mesh(path)
    assert not mesh.is_watertight  # the duplicate makes one edge appear three times
    prepared = prepare_mesh(mesh, str(path))
    assert prepared.watertight and len(prepared.mesh.faces) == 12
    assert np.isclose(prepared.mesh.volume, np.prod(EXTENTS))
    assert any("duplicate" in w for w in prepared.warnings)


def test_inverted_winding_is_fixed():
    cube = trimesh.creation.box(extents=EXTENTS)
    cube.invert()
    before = cube.faces.copy()
    prepared = prepare_mesh(cube, "inverted cube")
    assert prepared.watertight and prepared.mesh.volume > 0
    np.testing.assert_array_equal(cube.faces, before)  # the input is left alone


def test_split_vertices_and_a_small_hole_are_repaired():
    cube = trimesh.creation.box(extents=EXTENTS)
    corners = cube.vertices[cube.faces].reshape(-1, 3)  # three private vertices per triangle, as in STL
    soup = trimesh.Trimesh(corners, np.arange(36).reshape(-1, 3), process=False)
    prepared = prepare_mesh(soup, "triangle soup")
    assert prepared.watertight and not prepared.warnings
    open_box = trimesh.Trimesh(cube.vertices, cube.faces[1:], process=False)  # one triangle missing
    prepared = prepare_mesh(open_box, "open box")
    assert prepared.watertight
    assert np.isclose(prepared.mesh.volume, np.prod(EXTENTS))
    assert any("filled holes" in w for w in prepared.warnings)


def test_open_surface_falls_back_with_a_warning():
    # A sphere with its top cut off: fill_holes closes only triangle and quad holes, so this stays open.
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    bowl = trimesh.Trimesh(sphere.vertices, sphere.faces[sphere.triangles_center[:, 2] < 0.05])
    prepared = prepare_mesh(bowl, "bowl.stl")
    assert not prepared.watertight
    assert any("bowl.stl" in w and "convex hull" in w for w in prepared.warnings)


def test_prepare_rejects_zero_volume_and_non_finite():
    # A closed but flat mesh: a square, both sides. Every edge is shared twice, yet there is no volume.
    v = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0]], float)
    f = np.array([[0, 1, 2], [1, 3, 2]])
    flat = trimesh.Trimesh(v, np.vstack([f, f[:, ::-1]]), process=False)
    with pytest.raises(ShapeError, match="flat sheet") as err:
        prepare_mesh(flat, "sheet.obj")
    assert "sheet.obj" in str(err.value)
    cube = trimesh.creation.box(extents=EXTENTS)
    vertices = cube.vertices.copy()
    vertices[3] = np.nan
    bad = trimesh.Trimesh(vertices, cube.faces, process=False)
    with pytest.raises(ShapeError, match="NaN"):
        prepare_mesh(bad, "nan cube")
    with pytest.raises(ShapeError, match="no faces"):
        prepare_mesh(trimesh.Trimesh(), "nothing")


def test_prepared_procedural_shapes_stay_watertight():
    from physdyn.registry import SHAPE_FAMILIES

    for name in ("mugs", "trashcans"):
        inst = SHAPE_FAMILIES.build(name).make(0, np.random.default_rng(0))
        prepared = prepare_mesh(inst.mesh, inst.source)
        assert prepared.watertight
        assert np.isclose(prepared.mesh.volume, inst.mesh.volume)


# --------------------------------------------------------------------------------------------------
# The clean fast path: what the repairs would leave, without running them
# --------------------------------------------------------------------------------------------------
def _clean_meshes() -> dict[str, trimesh.Trimesh]:
    from physdyn.registry import SHAPE_FAMILIES

    meshes = {name: SHAPE_FAMILIES.build(name).make(1, np.random.default_rng(7)).mesh
              for name in ("primitives", "bottles", "mugs", "trashcans", "speakers")}
    box = trimesh.creation.box(extents=EXTENTS)
    box.apply_translation([-0.3, 0.2, -0.1])  # negative coordinates: the mass integrals' slow cubes
    apart = trimesh.creation.box(extents=EXTENTS)
    apart.apply_translation([0.5, 0.0, 0.0])
    meshes.update(box=box, torus=trimesh.creation.torus(0.1, 0.03), sphere=trimesh.creation.uv_sphere(0.1, [24, 24]),
                  two_bodies=trimesh.util.concatenate([box, apart]))
    return meshes


def test_a_clean_mesh_skips_the_repairs_and_comes_out_exactly_as_they_would_leave_it():
    from physdyn.geometry.mesh_io import _repair, already_clean

    for name, mesh in _clean_meshes().items():
        vertices, faces = np.array(mesh.vertices), np.array(mesh.faces, dtype=np.int64)
        assert already_clean(vertices, faces), name
        fast = prepare_mesh(mesh, name)
        repaired = _repair(trimesh.Trimesh(vertices.copy(), faces.copy(), process=False), name)
        np.testing.assert_array_equal(fast.mesh.vertices, repaired.mesh.vertices, err_msg=name)
        np.testing.assert_array_equal(fast.mesh.faces, repaired.mesh.faces, err_msg=name)
        assert fast.watertight and repaired.watertight and fast.warnings == repaired.warnings == [], name
        # The check's hull is the collision hull: trimesh's, vertex for vertex, in its order.
        np.testing.assert_array_equal(fast.hull_vertices, repaired.mesh.convex_hull.vertices, err_msg=name)
        assert not np.shares_memory(fast.mesh.vertices, mesh.vertices)  # the caller's mesh stays its own


def test_every_mesh_the_repairs_change_takes_the_slow_path():
    from physdyn.geometry.mesh_io import already_clean

    cube = trimesh.creation.box(extents=EXTENTS)
    inverted = cube.copy()
    inverted.invert()
    far = trimesh.creation.box(bounds=[[0.3, 0, 0], [0.4, 0.1, 0.1]])
    far.invert()
    merged_corner = np.array(cube.faces)
    merged_corner[merged_corner == 0] = 8  # a second copy of vertex 0 (vertex 8), used instead of it...
    merged_corner[0, merged_corner[0] == 8] = 0  # ...except by the first face: merging joins the two
    cases = {
        "inverted": (inverted.vertices, inverted.faces),
        "split vertices": (cube.vertices[cube.faces].reshape(-1, 3), np.arange(36).reshape(-1, 3)),
        "open": (cube.vertices, cube.faces[1:]),
        "duplicate face": (cube.vertices, np.vstack([cube.faces, cube.faces[:1]])),
        "degenerate face": (cube.vertices, np.vstack([cube.faces, [[0, 0, 1]]])),
        "unreferenced vertex": (np.vstack([cube.vertices, [[1.0, 1.0, 1.0]]]), cube.faces),
        "coincident vertex": (np.vstack([cube.vertices, cube.vertices[:1]]), merged_corner),
        "one body inverted": (np.vstack([cube.vertices, far.vertices]), np.vstack([cube.faces, far.faces + 8])),
        "sharing an edge": (_two_cubes_sharing_an_edge().vertices, _two_cubes_sharing_an_edge().faces),
    }
    for name, (vertices, faces) in cases.items():
        assert not already_clean(np.array(vertices, dtype=np.float64), np.array(faces, dtype=np.int64)), name


def test_inverted_bodies_are_flipped_as_trimesh_flips_them():
    """``_flip_inverted_bodies`` replaces trimesh's per-body loop (fix_inversion, multibody): the same faces
    flipped, in the same order, on meshes with bodies inverted, open, non-manifold or too small to judge."""
    from physdyn.geometry.mesh_io import _flip_inverted_bodies

    rng = np.random.default_rng(3)
    parts = [trimesh.creation.box(extents=EXTENTS), trimesh.creation.icosphere(1, 0.05),
             trimesh.creation.cylinder(0.04, 0.1, sections=9), trimesh.creation.torus(0.1, 0.03)]
    for i, part in enumerate(parts):
        part.apply_translation([0.4 * i, 0.0, 0.0])
    cube = trimesh.creation.box(extents=EXTENTS)
    open_box = trimesh.Trimesh(cube.vertices + [0.0, 1.0, 0.0], cube.faces[1:], process=False)
    open_box.invert()  # open, so neither trimesh nor physdyn may judge its inside
    triangle = trimesh.Trimesh([[0, 2, 0], [0.1, 2, 0], [0, 2.1, 0]], [[0, 2, 1]], process=False)
    miswound = trimesh.creation.box(extents=EXTENTS)
    miswound.invert()
    faces = np.array(miswound.faces)
    faces[0] = faces[0, ::-1]  # closed, inside out but for one face: not consistently wound, so left alone
    miswound = trimesh.Trimesh(miswound.vertices + [0.0, -1.0, 0.0], faces, process=False)
    cases = {"none inverted": parts, "all inverted": [p.copy() for p in parts],
             "open, miswound and tiny ones beside": parts + [open_box, miswound, triangle], "sharing an edge": [_two_cubes_sharing_an_edge()]}
    for p in cases["all inverted"]:
        p.invert()
    for seed in range(4):
        chosen = [p.copy() for p in parts]
        for p in chosen:
            if rng.random() < 0.5:
                p.invert()
        cases[f"some inverted ({seed})"] = chosen + [open_box, miswound]
    flipped = 0
    for name, pieces in cases.items():
        mesh = trimesh.util.concatenate(pieces)
        ours, theirs = mesh.copy(), mesh.copy()
        _ = ours.face_normals, theirs.face_normals  # cached normals are flipped with the faces
        trimesh.repair.fix_inversion(theirs, multibody=True)
        _flip_inverted_bodies(ours)
        np.testing.assert_array_equal(ours.faces, theirs.faces, err_msg=name)
        np.testing.assert_array_equal(ours.face_normals, theirs.face_normals, err_msg=name)
        flipped += not np.array_equal(theirs.faces, mesh.faces)
    assert flipped >= 5  # the comparison covered real flips, not only meshes left alone
