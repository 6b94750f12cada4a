"""The interactive viewer: what the page carries, how it is made from predictions and stores, and what a
browser shows (headless Chromium, where installed)."""

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

from physdyn.data.store import load_store
from physdyn.cli import main
from physdyn.predict.prediction_files import read_prediction, write_prediction
from physdyn.predict.predictor import load_predictor
from physdyn.viz.store_scenes import pick_sequences, shape_mesh
from physdyn.viz.viewer import MAX_FACES, ViewerError, read_viewer_data, scene_from_prediction, write_viewer
from tests.conftest import run_cli

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def prediction(tmp_path_factory):
    """A real prediction of the default model, with the simulation beside it, for a mesh in millimetres."""
    folder = tmp_path_factory.mktemp("viewer")
    mesh = trimesh.creation.box((80.0, 120.0, 200.0))
    mesh.apply_translation([300.0, -100.0, 50.0])  # mesh frame away from the centre of mass
    mesh.export(folder / "box_mm.obj")
    result = load_predictor().predict(str(folder / "box_mm.obj"), [1.5, 0, 0], [0, 0, 4], seconds=1.5, scale=0.001,
                                      compare_sim=True)
    write_prediction(result, folder / "box.json")
    return folder


def view(*args: str, capsys) -> tuple[int, str]:
    """`physdyn view ARGS` in this process (the CLI's own boundary): exit code and stderr."""
    code = main(["view", *args])
    return code, capsys.readouterr().err


def test_the_page_carries_the_prediction_file_and_its_mesh(prediction):
    result = read_prediction(prediction / "box.json")
    assert result["mesh_scale"] == 0.001
    proc = run_cli("view", str(prediction / "box.json"))  # the mesh path recorded in the file, its scale
    assert proc.returncode == 0, proc.stderr[-2000:]
    page = prediction / "box.html"
    text = page.read_text()
    assert "<script src=" not in text and "<link " not in text  # self-contained: nothing fetched
    scene = read_viewer_data(page)["scenes"][0]
    for key in ("com_position", "orientation_xyzw", "topple_probability"):
        np.testing.assert_allclose(scene["predicted"][key], result[key], atol=1e-6)
    for key in ("com_position", "orientation_xyzw"):
        np.testing.assert_allclose(scene["reference"][key], result["simulated"][key], atol=1e-6)
    assert scene["predicted"]["toppled"] == result["toppled"] and scene["rate_hz"] == result["rate_hz"]
    np.testing.assert_allclose(scene["com_mesh"], result["com_mesh"], atol=1e-6)
    # The mesh is drawn in metres where the prediction put it: its lowest vertex on the ground at step 0.
    vertices, faces = np.asarray(scene["mesh"]["vertices"]), np.asarray(scene["mesh"]["faces"])
    assert len(faces) <= MAX_FACES and faces.min() == 0 and faces.max() == len(vertices) - 1
    np.testing.assert_allclose(np.ptp(vertices, axis=0), [0.08, 0.12, 0.2], atol=1e-6)
    from physdyn.geometry.rotations import quat_to_matrix

    posed = (vertices - result["com_mesh"]) @ quat_to_matrix(result["orientation_xyzw"][0]).T + result["com_position"][0]
    assert abs(posed[:, 2].min()) < 1e-3


def test_view_refuses_what_it_cannot_show_and_keeps_existing_pages(prediction, tmp_path, capsys):
    page = tmp_path / "p.html"
    assert view(str(prediction / "box.json"), "--out", str(page), capsys=capsys)[0] == 0
    before = page.read_bytes()
    moved = tmp_path / "moved.json"
    moved.write_text((prediction / "box.json").read_text().replace("box_mm.obj", "gone.obj"))
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    cases = [
        ([str(prediction / "box.json"), "--out", str(page)], "already exists"),
        ([str(moved)], "--mesh PATH"),
        ([str(bad)], "not a readable prediction file"),
        ([str(prediction / "box.json"), str(moved)], "pass --out"),
        ([str(tmp_path)], "holds no viewer.html"),
        ([], "nothing to show"),
        (["--checkpoint", "x.ckpt"], "go together"),
    ]
    for args, message in cases:
        code, err = view(*args, capsys=capsys)
        assert code == 2 and message in err, (args, err)
        assert len(err.strip().splitlines()) == 1
    assert page.read_bytes() == before
    assert not (tmp_path / "moved.html").exists() and not (tmp_path / "bad.html").exists()
    # --mesh finds the moved mesh; several predictions make one page with a scene each.
    assert view(str(moved), str(prediction / "box.json"), "--out", str(tmp_path / "two.html"), capsys=capsys)[0] == 2
    assert not (tmp_path / "two.html").exists()  # moved.json's mesh is still missing: nothing is written
    code, err = view(str(moved), "--mesh", str(prediction / "box_mm.obj"), "--scale", "0.001", capsys=capsys)
    assert code == 0, err
    assert len(read_viewer_data(tmp_path / "moved.html")["scenes"]) == 1


def test_a_scene_with_nan_poses_is_refused(prediction, tmp_path):
    result = read_prediction(prediction / "box.json")
    result["com_position"][3, 0] = np.nan
    scene = scene_from_prediction(result, trimesh.creation.box((0.08, 0.12, 0.2)))
    with pytest.raises(ViewerError, match="NaN"):
        write_viewer([scene], tmp_path / "x.html")
    assert not (tmp_path / "x.html").exists()


def test_store_shapes_are_made_again_from_the_store_config(tiny_store):
    store = load_store(tiny_store)
    cache: dict = {}
    for shape in range(0, store.num_shapes, 4):  # every category
        vertices, faces, note = shape_mesh(store, shape, cache)
        assert note is None, store.source[shape]
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        # The stored cloud (body frame) lies on the rebuilt surface once moved to mesh coordinates.
        points = store.points[shape][:200].astype(np.float64) + store.com_mesh[shape]
        _, distance, _ = trimesh.proximity.closest_point(mesh, points)
        assert distance.max() < 1e-4, store.source[shape]


def test_a_shape_that_cannot_be_made_again_is_drawn_as_its_hull(tiny_store):
    store = load_store(tiny_store)
    store.attrs = {**store.attrs, "config": {"families": {"nope": {"shapes": 1}}}}
    vertices, faces, note = shape_mesh(store, 0, {})
    assert "convex hull" in note
    hull = trimesh.Trimesh(vertices, faces)
    assert hull.is_watertight and hull.volume > 0


def test_pick_sequences_takes_best_median_and_worst_of_each_category():
    per_sequence = {"category": ["a", "b", "a", "a", "b", "a", "a"],
                    "final.position_m": [0.5, 0.2, 0.1, float("nan"), 0.4, 0.3, 0.9]}
    picked = pick_sequences(per_sequence)
    assert picked == [(2, "a: best"), (5, "a: median"), (6, "a: worst"), (1, "b: best"), (4, "b: worst")]


def _chromium(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--enable-unsafe-swiftshader", "--use-angle=swiftshader", "--window-size=1100,800",
             "--virtual-time-budget=8000"]
    return subprocess.run([CHROMIUM, *flags, *args], capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow  # about 10 s of browser start-up and software WebGL; CI installs chromium and runs it
@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (apt-get install chromium); .ci/run installs it")
def test_a_browser_shows_the_mesh_the_plane_and_the_controls(prediction, tmp_path):
    from PIL import Image

    page = tmp_path / "page.html"
    assert run_cli("view", str(prediction / "box.json"), "--out", str(page)).returncode == 0
    profile = ["--user-data-dir=" + str(tmp_path / "profile")]
    dom = _chromium(*profile, "--dump-dom", page.as_uri() + "#step=10").stdout
    assert 'data-ready="1"' in dom  # the script ran to the end without an error
    assert 'id="play"' in dom and 'id="slider"' in dom and "<canvas" in dom  # controls, and WebGL drew
    assert "step 10" in dom and "error: position" in dom  # the readout follows the cursor
    shot = tmp_path / "shot.png"
    _chromium(*profile, f"--screenshot={shot}", page.as_uri() + "#step=10")
    rgb = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    predicted = (b - r > 50) & (b > 90)  # the steel-blue predicted mesh, shaded
    simulated = (r - b > 50) & (r > 150)  # the orange ghost of the simulation
    ground = (abs(r - g) < 6) & (abs(g - b) < 6) & (r > 170) & (r < 225)  # the grey plane
    assert predicted.sum() > 500 and simulated.sum() > 200 and ground.sum() > 5000, (predicted.sum(), simulated.sum(), ground.sum())


@pytest.mark.slow  # a browser start and software WebGL, as above
@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (apt-get install chromium); .ci/run installs it")
def test_a_browser_shows_a_distributions_fan_and_its_topple_probability(prediction, tmp_path):
    dist = tmp_path / "dist.npz"
    made = run_cli("predict", str(prediction / "box_mm.obj"), "--scale", "0.001", "--lin-vel", "1.5", "0", "0",
                   "--ang-vel", "0", "0", "4", "--seconds", "1.5", "--samples", "8", "--out", str(dist))
    assert made.returncode == 0, made.stderr
    page = tmp_path / "dist.html"
    assert run_cli("view", str(dist), "--out", str(page)).returncode == 0
    dom = _chromium("--user-data-dir=" + str(tmp_path / "profile"), "--dump-dom", page.as_uri()).stdout
    assert 'data-ready="1"' in dom  # the page's script ran to the end without an error
    assert "<canvas" in dom and 'id="slider"' in dom
