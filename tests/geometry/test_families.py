"""Procedural shape families and the mesh-folder family: real meshes, checked as solids."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from physdyn.config import MeshFolderConfig
from physdyn.errors import ShapeError
from physdyn.geometry.families import ShapeFamily, ShapeInstance
from physdyn.geometry.families.primitives import PRIMITIVE_BUILDERS
from physdyn.registry import SHAPE_FAMILIES

PROCEDURAL = ["primitives", "bottles", "mugs", "trashcans", "speakers", "clusters"]
N_INSTANCES = 16  # per family; primitives cycles through its 12 kinds


def build(name: str, **params) -> ShapeFamily:
    return SHAPE_FAMILIES.build(name, params)


def draw(family: ShapeFamily, n: int, seed: int = 0) -> list[ShapeInstance]:
    # One generator per instance, as the dataset builder seeds them.
    return [family.make(i, np.random.default_rng([seed, i])) for i in range(n)]


@pytest.fixture(scope="module")
def instances() -> dict[str, list[ShapeInstance]]:
    return {name: draw(build(name), N_INSTANCES) for name in PROCEDURAL}


def test_builtin_families_are_registered():
    names = SHAPE_FAMILIES.names()
    for name in PROCEDURAL + ["meshes"]:
        assert name in names
        assert issubclass(SHAPE_FAMILIES.get(name), ShapeFamily)


@pytest.mark.parametrize("name", PROCEDURAL)
def test_config_is_a_typed_dataclass_with_defaults(name):
    cfg = SHAPE_FAMILIES.resolve_config(name, {})
    assert cfg == SHAPE_FAMILIES.get(name).Config()


@pytest.mark.parametrize("name", PROCEDURAL)
def test_instances_are_closed_volumes_of_object_size(name, instances):
    for inst in instances[name]:
        mesh = inst.mesh
        assert mesh.is_watertight and mesh.is_volume, inst.source
        assert mesh.volume > 0
        assert 0.05 <= mesh.extents.max() <= 0.5, (inst.source, mesh.extents)
        assert abs(mesh.bounds[0, 2]) < 1e-9  # upright design pose, standing on z = 0
        assert np.isfinite(mesh.vertices).all()
        assert len(mesh.faces) <= 5000
        assert inst.category == name
        assert inst.source.startswith(f"{name}(") and inst.source.endswith(")")
    sources = [inst.source for inst in instances[name]]
    assert len(set(sources)) == len(sources), "two instances drew the same parameters"


@pytest.mark.parametrize("name", PROCEDURAL)
def test_make_is_a_pure_function_of_index_and_rng(name):
    family = build(name)
    first = family.make(5, np.random.default_rng(123))
    family.make(6, np.random.default_rng(999))  # an unrelated call in between must not matter
    again = build(name).make(5, np.random.default_rng(123))
    assert first.source == again.source
    np.testing.assert_array_equal(first.mesh.vertices, again.mesh.vertices)
    np.testing.assert_array_equal(first.mesh.faces, again.mesh.faces)


@pytest.mark.parametrize("name", PROCEDURAL)
def test_different_rngs_give_different_shapes(name):
    family = build(name)
    a = family.make(3, np.random.default_rng(1))
    b = family.make(3, np.random.default_rng(2))
    assert a.source != b.source
    same = a.mesh.vertices.shape == b.mesh.vertices.shape and np.allclose(a.mesh.vertices, b.mesh.vertices)
    assert not same
    assert not np.isclose(a.mesh.volume, b.mesh.volume, rtol=1e-6)


def test_primitives_cycle_through_every_kind(instances):
    kinds = [inst.source.split("kind=")[1].split(",")[0] for inst in instances["primitives"]]
    assert set(kinds) == set(PRIMITIVE_BUILDERS)


def test_primitives_kinds_can_be_restricted_and_are_checked():
    family = build("primitives", kinds=["sphere", "box"])
    sphere, box = draw(family, 2)
    assert "kind=sphere" in sphere.source and "kind=box" in box.source
    np.testing.assert_allclose(sphere.mesh.extents, sphere.mesh.extents[0])  # a sphere stays round
    assert np.isclose(box.mesh.volume, np.prod(box.mesh.extents))
    with pytest.raises(ShapeError, match="teapot"):
        build("primitives", kinds=["teapot"])


def test_primitives_are_scaled_non_uniformly(instances):
    boxes = [i for i in instances["primitives"] if "kind=box" in i.source]
    ratios = [np.sort(b.mesh.extents)[0] / np.sort(b.mesh.extents)[-1] for b in boxes]
    assert any(r < 0.95 for r in ratios)


def test_clusters_are_one_irregular_solid_of_several_pieces(instances):
    for inst in instances["clusters"]:
        mesh = inst.mesh
        assert mesh.body_count == 1, inst.source  # the pieces always overlap: one solid, no enclosed void
        assert mesh.volume < 0.9 * mesh.convex_hull.volume, inst.source  # not convex
        assert len(mesh.convex_hull.vertices) >= 12, inst.source  # many facets to land on
    pieces = {int(inst.source.split("pieces=")[1].split(",")[0]) for inst in instances["clusters"]}
    assert min(pieces) >= 3 and max(pieces) <= 8 and len(pieces) >= 3


def test_clusters_pieces_overlap_even_when_few_and_thin():
    # Few points per piece make thin slivers, the hardest case for overlap: still one solid every time.
    family = build("clusters", points_per_piece=8, pieces_min=8, pieces_max=8)
    for inst in draw(family, 40, seed=5):
        assert inst.mesh.body_count == 1 and inst.mesh.is_volume, inst.source


@pytest.mark.parametrize("params, named", [({"pieces_min": 5, "pieces_max": 2}, "pieces_min=5"),
                                           ({"points_per_piece": 4}, "points_per_piece=4"),
                                           ({"size_min": 0.3, "size_max": 0.1}, "size_min=0.3")])
def test_clusters_parameters_are_checked(params, named):
    with pytest.raises(ShapeError, match=named):
        build("clusters", **params)


def test_bottles_have_a_neck_narrower_than_the_body(instances):
    for inst in instances["bottles"]:
        v = inst.mesh.vertices
        height = inst.mesh.extents[2]
        radial = np.linalg.norm(v[:, :2], axis=1)
        body = radial[v[:, 2] < 0.3 * height].max()
        top = radial[v[:, 2] > 0.97 * height].max()
        assert top < 0.7 * body, inst.source


def test_mugs_have_a_handle_and_an_open_cup(instances):
    for inst in instances["mugs"]:
        mesh = inst.mesh
        # One solid with one through-hole (the handle): Euler characteristic V - E + F = 2 - 2 * genus = 0.
        assert mesh.body_count == 1 and mesh.euler_number == 0, inst.source
        assert mesh.extents[0] > mesh.extents[1] + 0.01  # the handle sticks out along +x
        assert mesh.volume < 0.6 * mesh.convex_hull.volume  # hollow: the cup is open


def test_trashcans_are_open_bins(instances):
    for inst in instances["trashcans"]:
        mesh = inst.mesh
        assert mesh.volume < 0.5 * mesh.convex_hull.volume, inst.source
        # The middle of the bin is air, the middle of its base is solid.
        height = mesh.extents[2]
        assert not mesh.contains([[0.0, 0.0, 0.5 * height]])[0]
        assert mesh.contains([[0.0, 0.0, 0.002]])[0]


def test_square_tapered_trashcans():
    family = build(
        "trashcans",
        cross_sections={"round": 0.0, "square": 1.0, "hexagonal": 0.0, "octagonal": 0.0},
        taper_probability=1.0,
        rim_probability=0.0,
    )
    for inst in draw(family, 4):
        v = inst.mesh.vertices
        assert "shape=square" in inst.source
        assert np.sum(np.isclose(v[:, 2], 0.0)) == 5  # four corners and the centre of the base
        height = inst.mesh.extents[2]
        top = np.abs(v[v[:, 2] > height - 1e-9, 0]).max()
        bottom = np.abs(v[v[:, 2] < 1e-9, 0]).max()
        assert top > 1.04 * bottom  # wider at the top
        # Flat rectangular walls: the hull is exactly a frustum whose top is the bounding rectangle.
        area_top = inst.mesh.extents[0] * inst.mesh.extents[1]
        area_bottom = area_top * (bottom / top) ** 2
        frustum = height / 3.0 * (area_top + area_bottom + np.sqrt(area_top * area_bottom))
        assert np.isclose(inst.mesh.convex_hull.volume, frustum, rtol=1e-6)


def test_trashcans_reject_unknown_cross_section():
    with pytest.raises(ShapeError, match="cross_sections"):
        build("trashcans", cross_sections={"triangle": 1.0})


def test_speakers_on_feet():
    plain = {"plain": 1.0, "drivers": 0.0, "panel": 0.0}
    for inst in draw(build("speakers", feet_probability=1.0, front_styles=plain), 3):
        assert "foot_radius" in inst.source
        assert inst.mesh.is_volume and inst.mesh.body_count == 1  # feet fused to the cabinet
        # Nothing under the middle of the cabinet at ground level.
        assert not inst.mesh.contains([[0.0, 0.0, 0.001]])[0]


@pytest.mark.parametrize("front", ["drivers", "panel"])
def test_speakers_front_recesses(front):
    styles = {"plain": 0.0, "drivers": 0.0, "panel": 0.0, front: 1.0}
    edges = {"sharp": 1.0, "rounded": 0.0, "rounded_vertical": 0.0, "bevelled": 0.0}
    for inst in draw(build("speakers", feet_probability=0.0, front_styles=styles, edge_styles=edges), 3):
        mesh = inst.mesh
        assert f"front={front}" in inst.source and mesh.is_volume
        # A sharp box's hull is the box, so any missing volume is the recess.
        assert mesh.volume < np.prod(mesh.extents) - 1e-6
        if front == "panel":  # the panel covers the middle of the front (-y) face
            centre = [0.0, mesh.bounds[0, 1] + 0.001, mesh.extents[2] / 2]
            assert not mesh.contains([centre])[0]


def test_speakers_edges_are_finished():
    for style in ("rounded", "rounded_vertical", "bevelled"):
        odds = {"sharp": 0.0, "rounded": 0.0, "rounded_vertical": 0.0, "bevelled": 0.0, style: 1.0}
        plain = {"plain": 1.0, "drivers": 0.0, "panel": 0.0}
        family = build("speakers", edge_styles=odds, feet_probability=0.0, front_styles=plain)
        (inst,) = draw(family, 1)
        assert f"edge={style}" in inst.source
        assert inst.mesh.volume < 0.999 * np.prod(inst.mesh.extents)  # corners cut away
        assert inst.mesh.contains([[0.0, 0.0, 0.002]])[0]  # flat bottom, no feet


# --------------------------------------------------------------------------------------------------
# meshes: a folder of files
# --------------------------------------------------------------------------------------------------
FORMATS = ("obj", "stl", "ply", "off", "glb")


@pytest.fixture
def mesh_folder(tmp_path):
    """Five files, one per format, one of them in a subfolder; box extents grow with the file's rank."""
    sizes = {}
    for k, ext in enumerate(FORMATS):
        folder = tmp_path / "sub" if ext == "glb" else tmp_path
        folder.mkdir(exist_ok=True)
        extents = np.array([0.1, 0.2, 0.3]) * (k + 1)
        path = folder / f"{k}_box.{ext}"
        trimesh.creation.box(extents=extents).export(path)
        sizes[path] = extents
    (tmp_path / "notes.txt").write_text("not a mesh")
    return tmp_path, sizes


def test_meshes_family_loads_every_file_sorted_and_scaled(mesh_folder):
    folder, sizes = mesh_folder
    family = build("meshes", dir=str(folder), scale=0.5, category="boxes")
    assert family.num_shapes(1000) == 5
    expected = sorted(sizes, key=lambda p: p.relative_to(folder).as_posix())
    for index, path in enumerate(expected):
        inst = family.make(index, np.random.default_rng(0))
        assert inst.source == str(path)
        assert inst.category == "boxes"
        np.testing.assert_allclose(inst.mesh.extents, 0.5 * sizes[path], rtol=1e-6)
        assert inst.mesh.is_watertight  # STL's per-triangle vertices were merged
    with pytest.raises(ShapeError, match="out of range"):
        family.make(5, np.random.default_rng(0))


def test_meshes_family_non_recursive_skips_subfolders(mesh_folder):
    folder, _ = mesh_folder
    family = build("meshes", dir=str(folder), recursive=False)
    assert family.num_shapes(0) == 4
    assert family.category == "meshes"


def test_meshes_family_needs_a_folder_with_meshes(tmp_path):
    with pytest.raises(ShapeError, match=r"meshes\.dir is not set; pass meshes\.dir=PATH"):
        build("meshes")
    with pytest.raises(ShapeError, match="not a folder"):
        build("meshes", dir=str(tmp_path / "nowhere"))
    (tmp_path / "readme.md").write_text("no meshes here")
    with pytest.raises(ShapeError, match="no mesh files") as err:
        build("meshes", dir=str(tmp_path))
    assert str(tmp_path) in str(err.value)


def test_meshes_family_reports_a_bad_file_by_name(tmp_path):
    trimesh.creation.box(extents=(0.1, 0.1, 0.1)).export(tmp_path / "a_good.obj")
    (tmp_path / "b_bad.ply").write_bytes(b"\x00garbage" * 20)
    family = build("meshes", dir=str(tmp_path))
    assert family.make(0, np.random.default_rng(0)).mesh.is_volume
    with pytest.raises(ShapeError, match="b_bad.ply"):
        family.make(1, np.random.default_rng(0))


def test_the_data_configs_mesh_folder_settings_reach_the_family(tmp_path):
    # meshes.dir and meshes.scale of a data config (the MeshFolderConfig schema) are what the family reads.
    from physdyn.config import DataConfig, load_config, preset_path
    from physdyn.sim.generate import build_family

    trimesh.creation.box(extents=(0.2, 0.1, 0.3)).export(tmp_path / "a.obj")
    cfg = load_config(DataConfig, preset_path("meshes", "data"), [f"meshes.dir={tmp_path}", "meshes.scale=0.5"])
    assert SHAPE_FAMILIES.get("meshes").Config is MeshFolderConfig and isinstance(cfg.meshes, MeshFolderConfig)
    made = build_family(cfg, "meshes").make(0, np.random.default_rng(0))
    np.testing.assert_allclose(sorted(made.mesh.extents), [0.05, 0.1, 0.15], atol=1e-9)
    assert "a.obj" in made.source
