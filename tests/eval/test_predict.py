"""`physdyn predict` and the predictor API on users' own meshes, with a real (tiny) trained checkpoint."""

import contextlib
import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

import physdyn
from physdyn.cli import main as cli_main
from physdyn.errors import PhysdynError, PredictionError, PredictionWarning
from physdyn.geometry.rotations import quat_to_matrix
from physdyn.models.training import fit, load_experiment_config
from physdyn.predict.body import preparation_key, prepare_body
from physdyn.predict.prediction_files import read_prediction, write_prediction
from physdyn.predict.predictor import Predictor, load_predictor
from tests.conftest import REPO, module_level_imports
from tests.models.conftest import QUICKSTART, shrunk_overrides

KEYS = {"rate_hz", "time", "com_position", "orientation_xyzw", "linear_velocity", "angular_velocity",
        "topple_probability", "toppled", "com_mesh", "mesh", "mesh_scale", "checkpoint"}
LIN, ANG, SECONDS = [1.2, 0.0, 0.0], [0.0, 0.0, 3.0], 2.0


@pytest.fixture(scope="module")
def checkpoint(tiny_store, tmp_path_factory):
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("predict_run")
    return str(fit(load_experiment_config(QUICKSTART, shrunk_overrides(tiny_store, out, "trainer.max_steps=20"))).last_checkpoint)


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    """Users' meshes, not a procedural family: an off-centre box (.obj) and a cylinder (.stl)."""
    folder = tmp_path_factory.mktemp("meshes")
    box = trimesh.creation.box((0.08, 0.12, 0.2))
    box.apply_translation([0.3, -0.1, 0.05])  # the mesh frame is not at the centre of mass
    box.export(folder / "box.obj")
    trimesh.creation.cylinder(radius=0.04, height=0.15, sections=24).export(folder / "can.stl")
    return folder


def predict_argv(mesh, checkpoint, out, *extra):
    return ["predict", str(mesh), "--lin-vel", *map(str, LIN), "--ang-vel", *map(str, ANG), "--seconds", str(SECONDS),
            "--checkpoint", checkpoint, "--out", str(out), *extra]


@pytest.fixture(scope="module")
def cli_run(checkpoint, meshes, tmp_path_factory):
    """One user run with every option: JSON out, the simulation beside, an animation. Through the command
    line's main in this process (a fresh one spends about 6 s starting: the slow test below runs one)."""
    out = tmp_path_factory.mktemp("cli")
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = cli_main(predict_argv(meshes / "box.obj", checkpoint, out / "box.json", "--compare-sim", "--render", str(out / "box.gif")))
    proc = subprocess.CompletedProcess(["physdyn", "predict"], code, stdout.getvalue(), stderr.getvalue())
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out, proc


def test_predicting_imports_neither_lightning_nor_the_store_library():
    """A prediction loads its model into the plain torch network: Lightning (and through it torch._dynamo,
    torchmetrics) took 5 of a fresh `physdyn predict`'s 10 s, zarr another 0.3 (docs/predict.md). The
    predictor's own imports, followed through the package, reach neither."""
    seen, reached = module_level_imports("physdyn.predict.predictor")
    assert {"physdyn.models.dynamics_network", "physdyn.pipeline.presets"} <= seen and "torch" in reached  # it followed the package
    assert not {"lightning", "torchmetrics", "zarr"} & reached, sorted(reached)


# a fresh process: about 6 s, most of it importing torch, trimesh and open3d (5 s more with Lightning, which
# kept it in the slow suite until predictions stopped importing it)
def test_predict_in_a_fresh_process_writes_what_main_writes(cli_run, meshes, checkpoint, tmp_path):
    # as a user runs it, with Python's import log: what the process imported, functions' imports included
    proc = subprocess.run([sys.executable, "-X", "importtime", "-m", "physdyn.cli",
                           *predict_argv(meshes / "box.obj", checkpoint, tmp_path / "box.json")],
                          capture_output=True, text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert f"wrote {tmp_path / 'box.json'}" in proc.stdout
    imported = {line.rsplit("|", 1)[1].strip() for line in proc.stderr.splitlines() if line.startswith("import time:")}
    assert "torch" in imported and "physdyn.models.dynamics_network" in imported  # the log is read
    assert not {"lightning", "zarr"} & imported
    fresh, in_process = read_prediction(tmp_path / "box.json"), read_prediction(cli_run[0] / "box.json")
    for key in ("com_position", "orientation_xyzw", "linear_velocity", "angular_velocity"):
        np.testing.assert_array_equal(fresh[key], in_process[key])


def _posed_min_z(mesh_path, result, step=0):
    mesh = trimesh.load(mesh_path, force="mesh")
    R = quat_to_matrix(result["orientation_xyzw"][step])
    return ((mesh.vertices - result["com_mesh"]) @ R.T + result["com_position"][step])[:, 2].min()


def _check_trajectory(res, T):
    assert res["com_position"].shape == (T, 3) and res["orientation_xyzw"].shape == (T, 4)
    assert res["linear_velocity"].shape == (T, 3) and res["angular_velocity"].shape == (T, 3)
    np.testing.assert_allclose(res["time"], np.arange(T) / res["rate_hz"])
    np.testing.assert_allclose(np.linalg.norm(res["orientation_xyzw"], axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(res["linear_velocity"][0], LIN, atol=1e-9)
    np.testing.assert_allclose(res["angular_velocity"][0], ANG, atol=1e-9)
    np.testing.assert_allclose(res["com_position"][0, :2], 0.0, atol=1e-12)
    assert isinstance(res["toppled"], bool)


def test_cli_writes_every_key_with_the_right_shapes_and_initial_state(cli_run, meshes, checkpoint):
    out, proc = cli_run
    assert f"wrote {out / 'box.json'}" in proc.stdout and "toppled" in proc.stdout
    raw = json.loads((out / "box.json").read_text())
    assert set(raw) == KEYS | {"simulated"} and set(raw["simulated"]) == KEYS
    res = read_prediction(out / "box.json")
    T = round(SECONDS * res["rate_hz"]) + 1
    _check_trajectory(res, T)
    assert res["topple_probability"].shape == (T,) and res["toppled"] == bool((res["topple_probability"] >= 0.5).any())
    assert res["mesh"] == str(meshes / "box.obj") and res["checkpoint"] == checkpoint
    np.testing.assert_allclose(res["com_mesh"], [0.3, -0.1, 0.05], atol=1e-9)
    np.testing.assert_allclose(res["orientation_xyzw"][0], [0, 0, 0, 1])  # the mesh frame as it is
    assert abs(_posed_min_z(meshes / "box.obj", res)) < 1e-9  # lowest point on the ground
    assert res["com_position"][0, 2] == pytest.approx(0.1)


def test_compare_sim_starts_from_the_same_state(cli_run, meshes):
    res = read_prediction(cli_run[0] / "box.json")
    sim = res["simulated"]
    T = len(res["time"])
    _check_trajectory(sim, T)
    assert sim["checkpoint"] == "pybullet" and sim["rate_hz"] == res["rate_hz"]
    np.testing.assert_allclose(sim["com_position"][0], res["com_position"][0], atol=1e-9)
    assert abs(_posed_min_z(meshes / "box.obj", sim)) < 1e-6
    # a box slid at 1.2 m/s on mu = 0.25 stops after about v^2 / (2 mu g) = 0.29 m, upright
    assert 0.15 < np.linalg.norm(sim["com_position"][-1, :2]) < 0.45 and not sim["toppled"]
    np.testing.assert_allclose(sim["linear_velocity"][-1], 0.0, atol=0.02)
    assert set(np.unique(sim["topple_probability"])) <= {0.0, 1.0}


def test_render_writes_a_gif_with_one_frame_per_step(cli_run):
    out, proc = cli_run
    assert f"wrote {out / 'box.gif'}" in proc.stdout
    T = len(read_prediction(out / "box.json")["time"])
    with Image.open(out / "box.gif") as gif:
        assert gif.format == "GIF" and gif.n_frames == T  # --fps 15 = the model's rate: one frame a step
        assert gif.size[0] > gif.size[1]  # prediction and simulation side by side


def test_python_api_returns_what_the_file_holds_in_every_format(cli_run, meshes, checkpoint, tmp_path):
    predictor = physdyn.load_predictor(checkpoint)
    assert isinstance(predictor, Predictor)
    result = predictor.predict(str(meshes / "box.obj"), LIN, ANG, seconds=SECONDS, compare_sim=True)
    from_cli = read_prediction(cli_run[0] / "box.json")
    _assert_same(result, from_cli)
    for ext in ("npz", "csv"):
        path = write_prediction(result, tmp_path / f"box.{ext}")
        _assert_same(result, read_prediction(path))
        assert not list(tmp_path.glob(".*"))  # no temporary file left behind
    with np.load(tmp_path / "box.npz") as npz:
        assert KEYS <= set(npz.files) and {f"simulated_{k}" for k in KEYS} <= set(npz.files)
    lines = (tmp_path / "box.csv").read_text().splitlines()
    header = next(line for line in lines if not line.startswith("#")).split(",")
    assert header[:5] == ["time", "com_position_x", "com_position_y", "com_position_z", "orientation_x"]
    assert "topple_probability" in header and "simulated_orientation_w" in header
    assert sum(not line.startswith("#") for line in lines) == len(result["time"]) + 1
    assert '# toppled: false' in lines or '# toppled: true' in lines
    with pytest.raises(PredictionError, match="already exists; pass --overwrite"):
        write_prediction(result, tmp_path / "box.csv")
    write_prediction(result, tmp_path / "box.csv", overwrite=True)


def _assert_same(a, b):
    assert set(a) == set(b)
    for key, value in a.items():
        if key == "simulated":
            _assert_same(value, b[key])
        elif isinstance(value, np.ndarray):
            np.testing.assert_allclose(b[key], value, rtol=0, atol=1e-9, err_msg=key)
        else:
            assert b[key] == value, key


def test_api_in_memory_mesh_orientation_and_open_mesh_warning(checkpoint):
    predictor = load_predictor(checkpoint)
    can = trimesh.creation.cylinder(radius=0.04, height=0.15, sections=24)
    lying = np.array([np.sin(np.pi / 4), 0, 0, np.cos(np.pi / 4)])  # on its side: 90 degrees about x
    res = predictor.predict(can, LIN, ANG, seconds=0.5, orientation_xyzw=lying)
    assert res["mesh"] == "<in-memory>" and len(res["time"]) == round(0.5 * predictor.rate_hz) + 1
    np.testing.assert_allclose(res["orientation_xyzw"][0], lying, atol=1e-12)
    assert res["com_position"][0, 2] == pytest.approx(0.04, abs=1e-3)  # resting on its curved side
    # an open mesh (no top cap) still predicts, with the convex hull's mass properties and a warning
    cup = trimesh.Trimesh(can.vertices, can.faces[~np.isclose(can.triangles_center[:, 2], 0.075)])
    with pytest.warns(PredictionWarning, match="convex hull"):
        open_res = predictor.predict(cup, LIN, ANG, seconds=0.5)
    assert np.isfinite(open_res["com_position"]).all()


def test_bad_values_are_refused_where_they_enter(checkpoint, meshes):
    predictor = load_predictor(checkpoint)
    box = str(meshes / "box.obj")
    for kwargs, match in (({"lin_vel": [1, 0]}, "must be 3 numbers"), ({"ang_vel": [0, np.inf, 0]}, "must be finite"),
                          ({"seconds": 0}, "seconds must be a positive number"),
                          ({"orientation_xyzw": [0, 0, 0, 0]}, "zero quaternion")):
        args = {"lin_vel": LIN, "ang_vel": ANG, **kwargs}
        with pytest.raises(PhysdynError, match=match):
            predictor.predict(box, **args)



def test_an_installation_without_the_default_model_says_so(tmp_path, monkeypatch):
    import physdyn.predict.predictor as P

    monkeypatch.setattr(P, "DEFAULT_CHECKPOINT", tmp_path / "fast.ckpt")  # as if the asset were left out
    with pytest.raises(PhysdynError, match="no shipped model.*--checkpoint"):
        load_predictor()


def test_a_model_without_topple_head_writes_null_probabilities(tmp_path):
    T = 3
    result = {"rate_hz": 15.0, "time": np.arange(T) / 15.0, "com_position": np.zeros((T, 3)),
              "orientation_xyzw": np.tile([0.0, 0, 0, 1], (T, 1)), "linear_velocity": np.zeros((T, 3)),
              "angular_velocity": np.zeros((T, 3)), "topple_probability": None, "toppled": False,
              "com_mesh": np.zeros(3), "mesh": "m.obj", "checkpoint": "c"}
    assert json.loads(write_prediction(result, tmp_path / "r.json").read_text())["topple_probability"] is None
    for ext in ("json", "npz", "csv"):
        back = read_prediction(write_prediction(result, tmp_path / f"n.{ext}"))
        assert back["topple_probability"] is None and back["mesh"] == "m.obj", ext


def test_batch_writes_good_lines_and_reports_bad_ones_by_number(checkpoint, meshes, tmp_path, capsys):
    requests = tmp_path / "requests.jsonl"
    good = {"mesh": str(meshes / "can.stl"), "lin_vel": [0.8, 0, 0], "ang_vel": [0, 0, 1], "seconds": 1, "out": "can.npz"}
    bad = {"mesh": str(meshes / "missing.obj"), "lin_vel": [1, 0, 0], "ang_vel": [0, 0, 0], "seconds": 1, "out": "bad.json"}
    requests.write_text(json.dumps(good) + "\n" + json.dumps(bad) + "\n")
    out = tmp_path / "predictions"
    code, _, stderr = _cli("predict", "--batch", str(requests), "--out-dir", str(out), "--checkpoint", checkpoint,
                           capsys=capsys)
    assert code != 0
    assert "line 2" in stderr and "missing.obj" in stderr and "line 1" not in stderr
    assert sorted(p.name for p in out.iterdir()) == ["can.npz"]
    res = read_prediction(out / "can.npz")
    assert res["com_position"].shape == (16, 3) and res["mesh"] == good["mesh"]


@pytest.fixture(scope="module")
def bad_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bad")
    (folder / "garbage.obj").write_text("this is not a mesh\nv 1 2\nf 9 9 9\n")
    torch.save({"weights": [1, 2, 3]}, folder / "dict.ckpt")
    (folder / "notes.ckpt").write_text("not a checkpoint")
    (folder / "taken.json").write_text("{}")
    return folder


@pytest.mark.parametrize("case", ["missing mesh", "nan velocity", "unreadable mesh", "dict checkpoint",
                                  "text checkpoint", "existing output", "bad extension"])
def test_bad_input_exits_with_one_line_and_writes_nothing(case, checkpoint, meshes, bad_files, tmp_path, capsys):
    mesh, lin, ckpt, out = str(meshes / "box.obj"), ["1", "0", "0"], checkpoint, tmp_path / "out.json"
    expected = {
        "missing mesh": "mesh file not found", "nan velocity": "--lin-vel must be finite",
        "unreadable mesh": "garbage.obj", "dict checkpoint": "not a physdyn DynamicsModel checkpoint",
        "text checkpoint": "not a PyTorch checkpoint", "existing output": "already exists; pass --overwrite",
        "bad extension": "unsupported extension '.txt'",
    }[case]
    if case == "missing mesh":
        mesh = str(tmp_path / "nope.obj")
    elif case == "nan velocity":
        lin = ["nan", "0", "0"]
    elif case == "unreadable mesh":
        mesh = str(bad_files / "garbage.obj")
    elif case == "dict checkpoint":
        ckpt = str(bad_files / "dict.ckpt")
    elif case == "text checkpoint":
        ckpt = str(bad_files / "notes.ckpt")
    elif case == "existing output":
        out = bad_files / "taken.json"
    elif case == "bad extension":
        out = tmp_path / "out.txt"
    # in-process: the CLI's own error boundary, without a fresh interpreter per case
    code = cli_main(["predict", mesh, "--lin-vel", *lin, "--ang-vel", "0", "0", "1", "--checkpoint", ckpt, "--out", str(out),
                     "--render", str(tmp_path / "anim.gif")])
    err = capsys.readouterr().err
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], err
    assert not (tmp_path / "anim.gif").exists()
    if case == "existing output":
        assert out.read_text() == "{}"
    else:
        assert not out.exists()
    assert not [p for p in tmp_path.iterdir()]  # no temporary files either


@pytest.mark.parametrize("name", [None, "bundled"], ids=["default", "bundled"])
def test_the_shipped_models_predict_a_users_mesh(name):
    """`physdyn predict` works right after install: the packaged checkpoints load and roll out; the default is
    ``fast`` (nothing simulated, the frontier's point: docs/performance.md), ``bundled`` is there by name."""
    import physdyn
    from physdyn.models.checkpoint_file import SHIPPED

    for path in SHIPPED.values():
        assert path.is_file() and path.stat().st_size < 10e6  # "a few MB"
    predictor = physdyn.load_predictor(name)
    mesh = Path(__file__).resolve().parents[2] / "examples" / "meshes" / "bracket_mm.obj"
    result = predictor.predict(str(mesh), [1.0, 0.0, 0.0], [0.0, 0.0, 2.0], seconds=2.0, scale=0.001)
    assert result["checkpoint"] == (name or "fast") and len(result["time"]) == 2 * int(predictor.rate_hz) + 1
    np.testing.assert_allclose(result["linear_velocity"][0], [1.0, 0.0, 0.0])
    assert np.isfinite(result["com_position"]).all()
    moved = np.linalg.norm(result["com_position"][-1, :2] - result["com_position"][0, :2])
    assert 0.01 < moved < 1.0  # a 1 m/s push on a plane with mu = 0.25 slides about 20 cm


def test_the_default_prediction_runs_no_simulator(tmp_path, monkeypatch, capsys):
    """`physdyn predict MESH` with no --checkpoint (and ``load_predictor()``) predicts with PyBullet refusing to run."""
    from tests.conftest import refuse_pybullet

    import scipy.spatial

    mesh = tmp_path / "part.obj"
    trimesh.creation.box((0.1, 0.06, 0.04)).export(mesh)
    refuse_pybullet(monkeypatch)
    monkeypatch.setattr(scipy.spatial, "ConvexHull", None)  # nor qhull to thin its cloud: the body knows its hull
    out = tmp_path / "part.json"
    assert cli_main(["predict", str(mesh), "--lin-vel", "0.9", "0.1", "0", "--ang-vel", "0", "0", "3", "--out", str(out)]) == 0
    written = read_prediction(out)
    assert written["checkpoint"] == "fast" and not written["toppled"]
    moved = np.linalg.norm(written["com_position"][-1, :2] - written["com_position"][0, :2])
    assert 0.01 < moved < 1.0
    assert load_predictor().predict(str(mesh), [0.9, 0.1, 0.0], [0.0, 0.0, 3.0], seconds=1.0)["checkpoint"] == "fast"


def test_predict_many_equals_each_request_predicted_alone_in_any_chunking(checkpoint, meshes):
    predictor = load_predictor(checkpoint)
    rng = np.random.default_rng(1)
    R = 5
    files = [str(meshes / ("box.obj" if i % 2 else "can.stl")) for i in range(R)]
    lin = np.c_[rng.uniform(-1.5, 1.5, (R, 2)), np.zeros(R)]
    ang = np.c_[np.zeros((R, 2)), rng.uniform(-3, 3, R)]
    seconds = [1.0, 2.0, 1.0, 1.0, 2.0]  # two lengths: one roll-out padded to the longer, cut per request
    alone = [predictor.predict(f, lin[i], ang[i], seconds[i]) for i, f in enumerate(files)]
    for chunk in (R, 2, 1):
        many = predictor.predict_many(files, lin, ang, seconds, chunk_size=chunk)
        assert len(many) == R
        for a, b in zip(many, alone):
            assert a["com_position"].shape == b["com_position"].shape and a["mesh"] == b["mesh"]
            for key in ("com_position", "orientation_xyzw", "linear_velocity", "angular_velocity", "topple_probability"):
                np.testing.assert_allclose(a[key], b[key], rtol=1e-5, atol=1e-5, err_msg=key)
            # the verdict is the request's own: its probabilities up to its own end, not the padded batch's
            assert a["toppled"] == b["toppled"] == bool((a["topple_probability"] >= 0.5).any())
    with pytest.raises(PredictionError, match="expected 3 numbers or 5 rows"):
        predictor.predict_many(files, lin[:3], ang, 1.0)
    with pytest.raises(PredictionError, match="compare_sim must be true or false"):
        predictor.predict_many(files[:1], lin[:1], ang[:1], 1.0, compare_sim="no")
    assert predictor.predict_many([], np.zeros((0, 3)), np.zeros((0, 3))) == []


def test_padded_batch_of_the_bundled_hybrid_equals_each_request_alone(meshes):
    """The bundled model simulates its first 0.4 s: a request shorter than that, padded into a batch with a
    longer one, still gets exactly its own roll-out (states, topple probabilities and verdict)."""
    predictor = load_predictor("bundled")
    files = [str(meshes / "box.obj"), str(meshes / "can.stl")]
    lin, ang, seconds = np.array([[1.2, 0.0, 0.0], [0.0, 0.8, 0.0]]), np.array([[0.0, 0.0, 2.0], [0.0, 0.0, -1.0]]), [0.2, 1.5]
    many = predictor.predict_many(files, lin, ang, seconds)
    for i, got in enumerate(many):
        alone = predictor.predict(files[i], lin[i], ang[i], seconds[i])
        assert len(got["time"]) == len(alone["time"]) == round(seconds[i] * predictor.rate_hz) + 1
        assert got["toppled"] == alone["toppled"]
        for key in ("com_position", "orientation_xyzw", "linear_velocity", "angular_velocity", "topple_probability"):
            np.testing.assert_allclose(got[key], alone[key], rtol=1e-5, atol=1e-5, err_msg=key)


def test_a_networks_only_model_predicts_with_no_simulator(checkpoint, meshes, monkeypatch):
    """A model without a simulated start or a simulating topple classifier runs no PyBullet at all: every
    simulator in physdyn connects through ``pb.connect`` (physdyn/sim/world.py), made to fail here."""
    import physdyn.sim.world as world

    predictor = load_predictor(checkpoint)
    assert predictor.model.topple.registered_name == "head" and not predictor.model.simulates
    monkeypatch.setattr(world.pb, "connect", lambda *a, **k: (_ for _ in ()).throw(AssertionError("PyBullet was called")))
    result = predictor.predict(str(meshes / "box.obj"), LIN, ANG, seconds=1.0)
    many = predictor.predict_many([str(meshes / "can.stl")] * 3, LIN, ANG, seconds=[0.5, 1.0, 1.5])
    assert np.isfinite(result["com_position"]).all()
    assert [len(m["time"]) for m in many] == [predictor.num_steps(x) for x in (0.5, 1.0, 1.5)]
    with pytest.raises(AssertionError, match="PyBullet was called"):  # the patch does catch a simulator
        predictor.predict(str(meshes / "box.obj"), LIN, ANG, seconds=1.0, compare_sim=True)


def _cli(*args: str, capsys) -> tuple[int, str, str]:
    """`physdyn ARGS` in this process (the CLI's own error boundary): exit code, stdout, stderr."""
    code = cli_main(list(args))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_batch_lines_with_a_non_boolean_or_an_escaping_path_are_refused(checkpoint, meshes, tmp_path, capsys):
    base = {"mesh": str(meshes / "can.stl"), "lin_vel": [0.8, 0, 0], "ang_vel": [0, 0, 1], "seconds": 1}
    lines = [dict(base, out="ok.json"), dict(base, out="no.json", compare_sim="no"), dict(base, out="../outside.json"),
             dict(base, out="ok2.json")]
    requests = tmp_path / "requests.jsonl"
    requests.write_text("\n".join(json.dumps(line) for line in lines) + "\n")
    out = tmp_path / "predictions"
    code, stdout, stderr = _cli("predict", "--batch", str(requests), "--out-dir", str(out), "--checkpoint", checkpoint,
                                capsys=capsys)
    assert code == 2
    assert "line 2: error: \"compare_sim\" must be true or false" in stderr
    assert "line 3: error: \"out\": '../outside.json' leads outside --out-dir" in stderr
    assert sorted(p.name for p in out.iterdir()) == ["ok.json", "ok2.json"]
    assert not (tmp_path / "outside.json").exists()
    assert "2 of 4 requests written" in stdout


def test_the_preparation_is_cached_by_mesh_content_not_object_identity(checkpoint, meshes, tmp_path, monkeypatch):
    import physdyn.predict.predictor as predictor_module

    prepared = []

    def counting(mesh, scale=1.0, density=None):
        prepared.append(mesh)
        return prepare_body(mesh, scale, density)

    monkeypatch.setattr(predictor_module, "prepare_body", counting)
    predictor = load_predictor(checkpoint)
    box = trimesh.creation.box((0.08, 0.12, 0.2))
    twin = trimesh.Trimesh(box.vertices.copy(), box.faces.copy(), process=False)  # equal content, another object
    first = predictor.predict(box, LIN, ANG, seconds=1.0)
    cached = predictor.predict(twin, LIN, ANG, seconds=1.0)
    batch = predictor.predict_many([twin, box], LIN, ANG, seconds=1.0)
    assert len(prepared) == 1
    fresh = Predictor(predictor.model).predict(twin, LIN, ANG, seconds=1.0)  # another predictor prepares its own
    assert len(prepared) == 2
    keys = ("com_position", "orientation_xyzw", "linear_velocity", "angular_velocity", "com_mesh")
    for key in keys:  # the cached preparation predicts exactly what a fresh one does
        np.testing.assert_array_equal(cached[key], fresh[key], err_msg=key)
        np.testing.assert_array_equal(first[key], fresh[key], err_msg=key)
        for res in batch:  # batched: to float32 round-off, as predict_many promises
            np.testing.assert_allclose(res[key], fresh[key], rtol=1e-5, atol=1e-5, err_msg=key)

    # A changed mesh (in place: the same object) is prepared again; so is another scale.
    box.vertices[:, 2] *= 1.5
    taller = predictor.predict(box, LIN, ANG, seconds=1.0)
    assert len(prepared) == 3 and taller["com_position"][0, 2] == pytest.approx(0.15, abs=1e-9)
    predictor.predict(twin, LIN, ANG, seconds=1.0, scale=0.5)
    assert len(prepared) == 4

    # The same file across calls, under two spellings of its path, is prepared once; rewritten, again.
    path = tmp_path / "can.stl"
    path.write_bytes((meshes / "can.stl").read_bytes())
    predictor.predict(str(path), LIN, ANG, seconds=1.0)
    predictor.predict(tmp_path / "." / "can.stl", LIN, ANG, seconds=1.0)
    assert len(prepared) == 5
    trimesh.creation.cylinder(radius=0.05, height=0.15, sections=24).export(path)
    predictor.predict(str(path), LIN, ANG, seconds=1.0)
    assert len(prepared) == 6

    # forget_meshes: the next request is a new mesh again (a benchmark of new meshes counts its preparation)
    predictor.forget_meshes()
    again = predictor.predict(twin, LIN, ANG, seconds=1.0)
    assert len(prepared) == 7
    np.testing.assert_array_equal(again["com_position"], fresh["com_position"])


def test_the_preparation_cache_is_bounded_and_keeps_the_recently_used(checkpoint, monkeypatch):
    import physdyn.predict.predictor as predictor_module

    monkeypatch.setattr(predictor_module, "PREPARED_CACHE_SIZE", 2)
    predictor = load_predictor(checkpoint)
    boxes = [trimesh.creation.box((0.1, 0.1, 0.1 + 0.02 * i)) for i in range(3)]
    predictor.predict_many(boxes[:2], LIN, ANG, seconds=0.5)
    predictor.predict(boxes[0], LIN, ANG, seconds=0.5)  # box 0 is now the most recently used
    predictor.predict(boxes[2], LIN, ANG, seconds=0.5)  # evicts box 1
    kept = {key[1] for key in predictor._prepared.meshes}
    keys = [preparation_key(b, 1.0)[1] for b in boxes]
    assert kept == {keys[0], keys[2]}


def test_a_batch_of_one_object_is_posed_as_each_push_alone(meshes):
    """Two objects pushed 300 times in turn, each from its own orientation: resting height, I_zz / m and
    I / m in world axes equal the one-at-a-time functions' to the bit (the batch poses a body at once)."""
    from physdyn.geometry.mass import vertical_inertia, world_inertia_per_mass
    from physdyn.predict.predictor import _posed
    from physdyn.sim.trajectory import resting_com_position

    box, can = prepare_body(str(meshes / "box.obj")), prepare_body(str(meshes / "can.stl"))
    bodies = [box, can] * 150
    q0 = np.random.default_rng(0).normal(size=(300, 4))
    q0 /= np.linalg.norm(q0, axis=1, keepdims=True)
    p0, spin, inertia = _posed(bodies, q0)
    for body, q, p, s, i in zip(bodies, q0, p0, spin, inertia):
        mass = (body.spec.inertia_diag, body.spec.principal_axes, body.spec.mass, q)
        assert np.array_equal(p, resting_com_position(body.spec, q))
        assert s == float(vertical_inertia(*mass)) and np.array_equal(i, world_inertia_per_mass(*mass))
    assert len(np.unique(p0[:, 2])) > 100  # the orientations rest at different heights


def test_a_batch_checks_its_rows_at_once_naming_the_first_bad_one_and_normalises_as_one_at_a_time(checkpoint, meshes):
    from physdyn.predict.predictor import _orientations, check_orientation

    q = np.random.default_rng(1).normal(size=(2000, 4)) * np.geomspace(0.01, 10, 2000)[:, None]
    assert np.array_equal(_orientations(q, 2000), np.stack([check_orientation(row) for row in q]))
    predictor = load_predictor(checkpoint)
    box = str(meshes / "box.obj")
    lin = np.tile([0.5, 0.0, 0.0], (4, 1))
    lin[2, 1] = np.nan
    with pytest.raises(PredictionError, match=r"linear velocity \(lin_vel\) of request 3 must be finite"):
        predictor.predict_many([box] * 4, lin, [0.0, 0.0, 1.0])
    turns = np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))
    turns[3] = 0.0
    with pytest.raises(PredictionError, match="zero quaternion"):
        predictor.predict_many([box] * 4, [0.5, 0.0, 0.0], [0.0, 0.0, 1.0], orientation_xyzw=turns)


def test_each_request_of_a_padded_batch_is_judged_toppled_at_its_own_end(checkpoint, meshes):
    """A classifier whose probability passes 0.5 at step 20: a 1 s request (16 states) ends before it, a 2 s
    one after; padded into one roll-out of 31 states, each keeps its own verdict."""

    import dataclasses

    from physdyn.pipeline.stages import ToppleStage

    class Rising(ToppleStage):
        def run(self, batch, motion):
            return np.tile(np.arange(batch.steps + 1) / 40.0, (batch.size, 1))

    predictor = load_predictor(checkpoint)
    predictor.model = dataclasses.replace(predictor.model, topple=Rising())
    box = str(meshes / "box.obj")
    short, long = predictor.predict_many([box, box], [[0.5, 0.0, 0.0]] * 2, [[0.0, 0.0, 1.0]] * 2, seconds=[1.0, 2.0])
    assert len(short["topple_probability"]) == 16 and len(long["topple_probability"]) == 31
    assert not short["toppled"] and long["toppled"]
    assert not predictor.predict(box, [0.5, 0.0, 0.0], [0.0, 0.0, 1.0], seconds=1.0)["toppled"]
