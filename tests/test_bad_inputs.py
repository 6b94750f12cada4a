"""Bad input across every command: exit status 2, one clear line naming the problem, nothing damaged.
Files crafted to run code when unpickled are refused by every command that reads them, and run nothing.

One table, run in-process through ``physdyn.cli.main`` (a fresh process per case would cost minutes).
Each case runs in a workspace holding what a user already made — a finished store, a finished run, a report,
a prediction, a folder of their own files — and the workspace must be byte for byte the same afterwards:
no file changed, none added (no half-written output), none removed.
"""

from __future__ import annotations

import hashlib
import json
import pickle
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from physdyn.cli import main
from physdyn.errors import PhysdynError
from tests.models.conftest import QUICKSTART, shrunk_overrides

DATA = "configs/data/quickstart.yaml"


class RunsCode:
    """Unpickling this calls ``Path.touch(marker)``: a file appearing there means a reader ran code from a file."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


@pytest.fixture(scope="module")
def marker(tmp_path_factory) -> Path:
    """Where the planted files' code would create a file, outside the workspace."""
    return tmp_path_factory.mktemp("payload") / "code_ran"


def plant_code_carrying_files(ws: Path, marker: Path) -> None:
    """Files that look like physdyn's own but carry ``RunsCode``: a checkpoint, a run folder whose last.ckpt is
    that checkpoint, an encoder file, a prediction file, and a store with an array of pickled Python objects."""
    payload = RunsCode(marker)
    checkpoint = torch.load(ws / "run" / "last.ckpt", map_location="cpu", weights_only=True)
    torch.save({**checkpoint, "notes": payload}, ws / "code.ckpt")
    shutil.copytree(ws / "run", ws / "code_run")
    shutil.copyfile(ws / "code.ckpt", ws / "code_run" / "last.ckpt")
    torch.save({"encoder": "pointnet", "state_dict": {}, "classes": ["mugs"], "notes": payload}, ws / "code_encoder.pt")
    np.savez(ws / "code.npz", com_position=np.array([payload], dtype=object))
    shutil.copytree(ws / "store.zarr", ws / "code.zarr")
    pickled = [{"name": "numcodecs.pickle", "configuration": {"protocol": 2}}]
    root = json.loads((ws / "code.zarr" / "zarr.json").read_text())
    root["consolidated_metadata"]["metadata"]["sims/friction"]["codecs"] = pickled
    (ws / "code.zarr" / "zarr.json").write_text(json.dumps(root))
    array = ws / "code.zarr" / "sims" / "friction"
    (array / "zarr.json").write_text(json.dumps({**json.loads((array / "zarr.json").read_text()), "codecs": pickled}))
    (array / "c" / "0").write_bytes(pickle.dumps(payload, protocol=2))


@pytest.fixture(scope="module")
def workspace(tiny_store, tmp_path_factory, marker):
    """What a user already has: a store, a finished run, a report, a prediction, their own files; and files
    from elsewhere that carry code."""
    from physdyn.models.training import fit, load_experiment_config

    ws = tmp_path_factory.mktemp("workspace")
    shutil.copytree(tiny_store, ws / "store.zarr")
    run = fit(load_experiment_config(QUICKSTART, shrunk_overrides(str(ws / "store.zarr"), ws / "run", "trainer.max_steps=2")))
    assert run.last_checkpoint is not None
    (ws / "report").mkdir()
    (ws / "report" / "metrics.json").write_text("{}")
    (ws / "taken.json").write_text("{}")
    (ws / "thesis").mkdir()
    (ws / "thesis" / "chapter1.tex").write_text("months of work")
    (ws / "thesis" / "config.yaml").write_text("mine: true\n")
    (ws / "binary.bin").write_bytes(bytes(range(256)) * 4)
    (ws / "bad.yaml").write_text("data: [unclosed\n")
    (ws / "notes.ckpt").write_text("not a checkpoint")
    torch.save({"weights": [1, 2, 3]}, ws / "dict.ckpt")
    (ws / "garbage.obj").write_text("this is not a mesh\nv 1 2\nf 9 9 9\n")
    import trimesh

    trimesh.creation.box((0.08, 0.12, 0.2)).export(ws / "box.obj")
    (ws / "corrupt.zarr").mkdir()
    (ws / "corrupt.zarr" / "zarr.json").write_text("{ not json")
    (ws / "requests.jsonl").write_text(json.dumps({"mesh": "box.obj", "lin_vel": [1, 0, 0], "ang_vel": [0, 0, 1]}) + "\n")
    (ws / "trials").mkdir()
    (ws / "trials" / "t1.csv").write_text("when,where\n0,1\n")  # not the tracker layout
    plant_code_carrying_files(ws, marker)
    return ws


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(folder.rglob("*"))}


RUN_OVERRIDES = ["data.store={ws}/store.zarr", "out_dir={ws}/new_run", "progress_bar=false", "trainer.max_steps=1"]
PREDICT = ["predict", "{ws}/box.obj", "--lin-vel", "1", "0", "0", "--ang-vel", "0", "0", "1", "--checkpoint", "{ws}/run/last.ckpt"]
TEST = ["test", "--checkpoint", "{ws}/run/last.ckpt", "--data", "{ws}/store.zarr"]

# (id, argv, text the one error line must contain)
CASES = [
    # simulate: files, schema values, relations, flags, ownership
    ("sim-missing-config", ["simulate", "--config", "{ws}/nope.yaml", "--out", "{ws}/new.zarr"], "config file not found"),
    ("sim-binary-config", ["simulate", "--config", "{ws}/binary.bin", "--out", "{ws}/new.zarr"], "not a text file"),
    ("sim-malformed-config", ["simulate", "--config", "{ws}/bad.yaml", "--out", "{ws}/new.zarr"], "not valid YAML"),
    ("sim-unknown-key", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "no_such_key=1"], "no_such_key"),
    ("sim-rate-zero", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "rate_hz=0"], "'rate_hz'"),
    ("sim-rate-not-dividing", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "rate_hz=17"], "does not divide"),
    ("sim-time-step-zero", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "physics.time_step=0"], "physics.time_step"),
    ("sim-time-step-nan", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "physics.time_step=nan"], "physics.time_step"),
    ("sim-gravity-up", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "physics.gravity=9.81"], "physics.gravity"),
    ("sim-gravity-inf", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "physics.gravity=-inf"], "physics.gravity"),
    ("sim-negative-friction", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "physics.lateral_friction_object=-1"],
     "physics.lateral_friction_object"),
    ("sim-negative-duration", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "physics.max_duration=-1"], "physics.max_duration"),
    ("sim-restitution", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "physics.restitution=2"], "physics.restitution"),
    ("sim-absurd-push", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "impulse.speed_max=1000"], "impulse.speed_max"),
    ("sim-push-range", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "impulse.speed_min=3"], "impulse.speed_min"),
    ("sim-friction-range", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "friction.min=0.9"], "friction.min"),
    ("sim-no-shapes", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "families.bottles.shapes=0"], "families.bottles.shapes"),
    ("sim-split", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "split.test_fraction=0.95"], "split.test_fraction"),
    ("sim-split-sum", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "split.test_fraction=0.6", "split.val_fraction=0.5"],
     "split.val_fraction"),
    ("sim-points", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "num_points=2"], "num_points"),
    ("sim-density", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "mass.density=0"], "mass.density"),
    ("sim-workers-zero", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "--workers", "0"], "--workers"),
    ("sim-workers-negative", ["simulate", "--config", DATA, "--out", "{ws}/new.zarr", "--workers", "-3"], "--workers"),
    ("sim-existing-store", ["simulate", "--config", DATA, "--out", "{ws}/store.zarr"], "already exists"),
    ("sim-resume-complete", ["simulate", "--config", DATA, "--out", "{ws}/store.zarr", "--resume"], "already complete"),
    ("sim-overwrite-user-folder", ["simulate", "--config", DATA, "--out", "{ws}/thesis", "--overwrite"], "not a physdyn store"),
    ("sim-resume-and-overwrite", ["simulate", "--config", DATA, "--out", "{ws}/store.zarr", "--resume", "--overwrite"], "contradict"),
    ("sim-meshes-unset", ["simulate", "--config", "configs/data/meshes.yaml", "--out", "{ws}/new.zarr"], "meshes.dir"),
    # fit: config, store, ownership, checkpoints
    ("fit-missing-config", ["fit", "--config", "{ws}/nope.yaml"], "config file not found"),
    ("fit-binary-config", ["fit", "--config", "{ws}/binary.bin"], "not a text file"),
    ("fit-missing-store", ["fit", "--config", str(QUICKSTART), "data.store={ws}/nope.zarr", "out_dir={ws}/new_run"], "nope.zarr"),
    ("fit-corrupt-store", ["fit", "--config", str(QUICKSTART), "data.store={ws}/corrupt.zarr", "out_dir={ws}/new_run"], "corrupt.zarr"),
    ("fit-window-zero", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "data.window=0"], "data.window"),
    ("fit-window-huge", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "data.window=100000"], "data.window"),
    ("fit-unknown-prior", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "model.prior=newton"], "model.prior"),
    ("fit-contact-without-orientation", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "model.orientation_input=false"],
     "model.prior"),
    ("fit-override-not-yaml", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "model.residual_gate_linear=["],
     "model.residual_gate_linear=[': the value is not valid YAML"),
    ("fit-loss-kind", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "loss.kind=l2"], "loss.kind"),
    ("fit-feedback", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "rollout.feedback=1.5"], "rollout.feedback"),
    ("fit-lr-min", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "optim.lr_min=1"], "optim.lr_min"),
    ("fit-trainer-typo", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "trainer.max_epoch=3"], "trainer.max_epoch"),
    ("fit-encoder-init-text", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "model.encoder_init={ws}/notes.ckpt"],
     "model.encoder_init"),
    ("fit-ckpt-missing", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "ckpt_path={ws}/nope.ckpt"], "ckpt_path"),
    ("fit-ckpt-text", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "ckpt_path={ws}/notes.ckpt"], "notes.ckpt"),
    ("fit-overwrite-user-folder", ["fit", "--config", str(QUICKSTART), "data.store={ws}/store.zarr", "out_dir={ws}/thesis",
                                   "--overwrite"], "not a physdyn run"),
    ("fit-finished-run", ["fit", "--config", str(QUICKSTART), *shrunk_overrides("{ws}/store.zarr", "{ws}/run", "trainer.max_steps=2")],
     "finished run"),
    ("fit-resume-changed", ["fit", "--config", str(QUICKSTART), *shrunk_overrides("{ws}/store.zarr", "{ws}/run", "trainer.max_steps=4"),
                            "model.prior=planar", "--resume"], "model.prior"),
    ("fit-resume-nothing", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "--resume"], "--resume"),
    # test: checkpoint, outputs, options
    ("test-missing-ckpt", ["test", "--checkpoint", "{ws}/nope.ckpt", "--out", "{ws}/rep"], "nope.ckpt"),
    ("test-text-ckpt", ["test", "--checkpoint", "{ws}/notes.ckpt", "--out", "{ws}/rep"], "not a PyTorch checkpoint"),
    ("test-dict-ckpt", ["test", "--checkpoint", "{ws}/dict.ckpt", "--out", "{ws}/rep"], "not a physdyn DynamicsModel checkpoint"),
    ("test-out-is-file", [*TEST, "--out", "{ws}/taken.json"], "is a file"),
    ("test-out-under-file", [*TEST, "--out", "{ws}/taken.json/rep"], "is a file"),
    ("test-existing-report", [*TEST, "--out", "{ws}/report"], "already holds a report"),
    ("test-warm-start-negative", [*TEST, "--out", "{ws}/rep", "--warm-start", "-1"], "--warm-start"),
    ("test-warm-start-too-long", [*TEST, "--out", "{ws}/rep", "--warm-start", "100000"], "--warm-start"),
    ("test-missing-store", ["test", "--checkpoint", "{ws}/run/last.ckpt", "--data", "{ws}/nope.zarr", "--out", "{ws}/rep"], "nope.zarr"),
    ("test-unknown-category", [*TEST, "--out", "{ws}/rep", "--categories", "unicorns"], "unicorns"),
    # predict: mesh, numbers, outputs, batch
    ("predict-missing-mesh", ["predict", "{ws}/nope.obj", "--lin-vel", "1", "0", "0", "--ang-vel", "0", "0", "1"], "nope.obj"),
    ("predict-garbage-mesh", ["predict", "{ws}/garbage.obj", "--lin-vel", "1", "0", "0", "--ang-vel", "0", "0", "1"], "garbage.obj"),
    ("predict-nan-velocity", ["predict", "{ws}/box.obj", "--lin-vel", "nan", "0", "0", "--ang-vel", "0", "0", "1"], "finite"),
    ("predict-absurd-velocity", [*PREDICT[:2], "--lin-vel", "1e6", "0", "0", "--ang-vel", "0", "0", "1"], "check the units"),
    ("predict-absurd-spin", [*PREDICT[:2], "--lin-vel", "1", "0", "0", "--ang-vel", "0", "0", "1e5"], "check the units"),
    ("predict-seconds-zero", [*PREDICT, "--seconds", "0"], "seconds"),
    ("predict-seconds-huge", [*PREDICT, "--seconds", "1e12"], "seconds"),
    ("predict-zero-quaternion", [*PREDICT, "--orientation", "0", "0", "0", "0"], "zero quaternion"),
    ("predict-scale-zero", [*PREDICT, "--scale", "0"], "scale"),
    ("predict-bad-extension", [*PREDICT, "--out", "{ws}/out.txt"], "unsupported extension"),
    # plan: bad goals and budgets are refused before the model is loaded
    ("plan-goal-nan", ["plan", "{ws}/box.obj", "--goal", "nan", "0", "--out", "{ws}/plan.json"], "goal must be finite"),
    ("plan-goal-inf", ["plan", "{ws}/box.obj", "--goal", "0.1", "inf", "--out", "{ws}/plan.json"], "goal must be finite"),
    ("plan-goal-unreachable", ["plan", "{ws}/box.obj", "--goal", "5", "0", "--out", "{ws}/plan.json"], "beyond what a push"),
    ("plan-goal-yaw-nan", ["plan", "{ws}/box.obj", "--goal", "0.1", "0", "--goal-yaw", "nan"], "goal yaw must be finite"),
    ("plan-budget-zero", ["plan", "{ws}/box.obj", "--goal", "0.1", "0", "--budget", "0", "--out", "{ws}/plan.json"], "budget"),
    ("plan-render-without-trajectory", ["plan", "{ws}/box.obj", "--goal", "0.1", "0", "--search", "pybullet", "--no-check",
                                        "--render", "{ws}/plan.html"], "--render needs a trajectory"),
    ("plan-render-screened-no-check", ["plan", "{ws}/box.obj", "--goal", "0.1", "0", "--no-check", "--render", "{ws}/plan.html",
                                       "--out", "{ws}/plan.json"], "--render needs a trajectory"),
    ("plan-pybullet-step-zero", ["plan", "{ws}/box.obj", "--goal", "0.1", "0", "--pybullet-step", "0", "--out", "{ws}/plan.json"],
     "PyBullet step must be in"),
    ("plan-budget-negative", ["plan", "{ws}/box.obj", "--goal", "0.1", "0", "--budget", "-1"], "budget"),
    ("plan-speed-bounds", ["plan", "{ws}/box.obj", "--goal", "0.1", "0", "--speed-min", "3", "--speed-max", "1"], "speed bounds"),
    ("plan-existing-out", ["plan", "{ws}/box.obj", "--goal", "0.1", "0", "--out", "{ws}/taken.json"], "already exists"),
    ("plan-bad-extension", ["plan", "{ws}/box.obj", "--goal", "0.1", "0", "--out", "{ws}/plan.csv"], "unsupported extension"),
    ("predict-existing-output", [*PREDICT, "--out", "{ws}/taken.json"], "already exists"),
    ("predict-output-under-file", [*PREDICT, "--out", "{ws}/taken.json/x.json"], "is a file"),
    ("predict-dict-checkpoint", [*PREDICT[:-1], "{ws}/dict.ckpt"], "not a physdyn DynamicsModel checkpoint"),
    ("predict-device", [*PREDICT, "--device", "quantum"], "device"),
    ("predict-batch-missing", ["predict", "--batch", "{ws}/nope.jsonl", "--out-dir", "{ws}/preds"], "nope.jsonl"),
    ("predict-batch-binary", ["predict", "--batch", "{ws}/binary.bin", "--out-dir", "{ws}/preds"], "not a text file"),
    # import-mocap and simulate-mocap: trials, shape, rates, ownership
    ("mocap-missing-trials", ["import-mocap", "{ws}/nope", "--shape", "box:0.07,0.06,0.17", "--out", "{ws}/m.zarr"], "nope"),
    ("mocap-no-trials", ["import-mocap", "{ws}/thesis", "--shape", "box:0.07,0.06,0.17", "--out", "{ws}/m.zarr"], "thesis"),
    ("mocap-bad-header", ["import-mocap", "{ws}/trials", "--shape", "box:0.07,0.06,0.17", "--out", "{ws}/m.zarr"], "t1.csv"),
    ("mocap-bad-box", ["import-mocap", "{ws}/trials", "--shape", "box:0,0.06,0.17", "--out", "{ws}/m.zarr"], "box"),
    ("mocap-rate-zero", ["import-mocap", "{ws}/trials", "--shape", "box:0.07,0.06,0.17", "--out", "{ws}/m.zarr", "--rate", "0"],
     "--rate"),
    ("mocap-existing-store", ["import-mocap", "{ws}/trials", "--shape", "box:0.07,0.06,0.17", "--out", "{ws}/store.zarr"],
     "already exists"),
    ("simmocap-no-trials", ["simulate-mocap", "--out", "{ws}/new_trials", "--trials", "0"], "--trials"),
    ("simmocap-nan-floor", ["simulate-mocap", "--out", "{ws}/new_trials", "--trials", "1", "--floor-offset", "nan"],
     "--floor-offset"),
    ("simmocap-absurd-floor", ["simulate-mocap", "--out", "{ws}/new_trials", "--trials", "1", "--floor-offset", "1e9"],
     "--floor-offset"),
    # reproduce: scale, selection, workers
    ("reproduce-unknown-scale", ["reproduce", "--scale", "huge", "--out", "{ws}/suite"], "unknown scale"),
    ("reproduce-unknown-experiment", ["reproduce", "--scale", "tiny", "--out", "{ws}/suite", "--only", "nope"], "nope"),
    ("reproduce-workers-zero", ["reproduce", "--scale", "tiny", "--out", "{ws}/suite", "--workers", "0"], "--workers"),
    ("reproduce-jobs-zero", ["reproduce", "--scale", "tiny", "--out", "{ws}/suite", "--jobs", "0"], "--jobs"),
    ("reproduce-missing-scale-file", ["reproduce", "--scale", "{ws}/nope.yaml", "--out", "{ws}/suite"], "nope.yaml"),
    # view and fit-topple
    ("view-missing-file", ["view", "{ws}/nope.json"], "does not exist"),
    ("view-not-a-prediction", ["view", "{ws}/taken.json"], "not a prediction file"),
    ("view-report-without-page", ["view", "{ws}/report"], "holds no viewer.html"),
    ("view-unknown-sim", ["view", "--checkpoint", "{ws}/run/last.ckpt", "--data", "{ws}/store.zarr", "--sims", "99999",
                          "--out", "{ws}/v.html"], "99999"),
    ("topple-dict-checkpoint", ["fit-topple", "--checkpoint", "{ws}/dict.ckpt", "--out", "{ws}/t.ckpt"],
     "not a physdyn DynamicsModel checkpoint"),
    ("topple-existing-output", ["fit-topple", "--checkpoint", "{ws}/run/last.ckpt", "--out", "{ws}/notes.ckpt"], "already exists"),
    ("topple-missing-store", ["fit-topple", "--checkpoint", "{ws}/run/last.ckpt", "--data", "{ws}/nope.zarr", "--out", "{ws}/t.ckpt"],
     "nope.zarr"),
    ("topple-pointnet-surface-store", ["fit-topple", "--pointnet", "--checkpoint", "{ws}/run/last.ckpt", "--data",
                                       "{ws}/store.zarr", "--out", "{ws}/t.ckpt"], "holds surface clouds; --pointnet reads hull_surface"),
    ("topple-pointnet-physics", ["fit-topple", "--pointnet", "--physics", "--checkpoint", "{ws}/run/last.ckpt", "--out",
                                 "{ws}/t.ckpt"], "drop --physics"),
    ("topple-pointnet-few-steps", ["fit-topple", "--pointnet", "--steps", "2", "--checkpoint", "{ws}/run/last.ckpt", "--out",
                                   "{ws}/t.ckpt"], "--steps at least 20"),
    ("topple-pointnet-one-width", ["fit-topple", "--pointnet", "--widths", "64", "--checkpoint", "{ws}/run/last.ckpt",
                                   "--out", "{ws}/t.ckpt"], "--widths takes two or more"),
    ("topple-pointnet-bad-device", ["fit-topple", "--pointnet", "--device", "gpu", "--checkpoint", "{ws}/run/last.ckpt",
                                    "--out", "{ws}/t.ckpt"], "--device gpu"),
    ("topple-pointnet-missing-cuda", ["fit-topple", "--pointnet", "--device", "cuda:5", "--checkpoint",
                                      "{ws}/run/last.ckpt", "--out", "{ws}/t.ckpt"], "--device cuda:5"),
    ("topple-two-stores-logistic", ["fit-topple", "--checkpoint", "{ws}/run/last.ckpt", "--data", "{ws}/store.zarr", "--data",
                                    "{ws}/store.zarr", "--out", "{ws}/t.ckpt"], "fits on one store"),
    ("config-unknown-preset", ["simulate", "--config", "quikstart", "--out", "{ws}/new.zarr"], "neither a config file nor a data preset"),
    # data info: stores
    ("info-missing-store", ["data", "info", "{ws}/nope.zarr"], "nope.zarr"),
    ("info-corrupt-store", ["data", "info", "{ws}/corrupt.zarr"], "corrupt.zarr"),
    ("info-not-a-store", ["data", "info", "{ws}/thesis"], "thesis"),
    ("info-unknown-protocol", ["data", "info", "nosuchproto://bucket/x.zarr"], "nosuchproto"),
]


@pytest.mark.parametrize("argv, expected", [pytest.param(a, e, id=i) for i, a, e in CASES])
def test_bad_input_is_one_clear_line_and_damages_nothing(workspace, capsys, argv, expected):
    args = [a.replace("{ws}", str(workspace)) for a in argv]
    before = digest(workspace)
    capsys.readouterr()
    try:
        status = main(args)
    except SystemExit as exc:  # argparse's own usage errors
        status = exc.code
    err = capsys.readouterr().err.strip()
    assert status == 2, f"exit {status}: {err}"
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("physdyn ") and "error" in lines[0], lines[0]
    assert expected in lines[0], lines[0]
    assert "Traceback" not in err and "unexpected error" not in err, err
    assert digest(workspace) == before, "the workspace changed"


def test_there_are_at_least_sixty_cases():
    assert len(CASES) >= 60 and len({c[0] for c in CASES}) == len(CASES)


def test_the_python_api_refuses_the_same_values(workspace):
    from physdyn.config import DataConfig, load_config
    from physdyn.errors import PredictionError
    from physdyn.predict.predictor import load_predictor

    with pytest.raises(PhysdynError, match="rate_hz"):
        load_config(DataConfig, DATA, ["rate_hz=0"])
    predictor = load_predictor(str(workspace / "run" / "last.ckpt"))
    with pytest.raises(PredictionError, match="finite"):
        predictor.predict(workspace / "box.obj", [np.nan, 0, 0], [0, 0, 1])
    with pytest.raises(PredictionError, match="rows"):
        predictor.predict_many([workspace / "box.obj"] * 3, np.zeros((2, 3)), [0, 0, 1])
    with pytest.raises(PredictionError, match="check the units"):
        predictor.predict(workspace / "box.obj", [0, 0, 0], [0, 0, 1e6])


def test_open3d_that_cannot_load_is_one_line_with_the_fix_before_any_work(workspace, capsys, monkeypatch):
    # As after a bare `pip install` on a machine without libusb-1.0: the loader fails on import.
    import builtins

    real_import = builtins.__import__

    def failing_import(name, *args, **kwargs):
        if name == "open3d":
            raise OSError("libusb-1.0.so.0: cannot open shared object file: No such file or directory")
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(__import__("sys").modules, "open3d", raising=False)
    monkeypatch.setattr(builtins, "__import__", failing_import)
    before = digest(workspace)
    capsys.readouterr()
    status = main(["simulate", "--config", DATA, "--out", str(workspace / "new.zarr")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1, err
    assert "open3d cannot be loaded" in err[0] and "apt-get install libusb-1.0-0" in err[0]
    assert digest(workspace) == before


def test_an_unexpected_error_is_one_line_pointing_to_debug_which_shows_the_traceback(workspace, capsys, monkeypatch):
    import physdyn.predict.predictor as predict_module

    def broken(*args, **kwargs):
        raise KeyError("something physdyn did not foresee")

    monkeypatch.setattr(predict_module, "load_predictor", broken)
    argv = ["predict", str(workspace / "box.obj"), "--lin-vel", "1", "0", "0", "--ang-vel", "0", "0", "1"]
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unexpected error: KeyError" in err[0] and "--debug" in err[0], err
    with pytest.raises(KeyError):
        main(["--debug", *argv])


# Files that carry code (see plant_code_carrying_files), given to every command that reads such a file:
# (id, argv, the planted file the line names, text the line must contain). "export" is
# `python -m physdyn.models.export`.
REFUSED = "that physdyn does not load (files are read without running code; docs/security.md)"
CODE_CASES = [
    ("predict", [*PREDICT[:-1], "{ws}/code.ckpt"], "code.ckpt", REFUSED),
    ("test", ["test", "--checkpoint", "{ws}/code.ckpt", "--data", "{ws}/store.zarr", "--out", "{ws}/rep"], "code.ckpt", REFUSED),
    ("test-baseline-checkpoint", [*TEST, "--out", "{ws}/rep", "--baseline-checkpoint", "{ws}/code.ckpt"], "code.ckpt", REFUSED),
    ("fit-resume", ["fit", "--config", str(QUICKSTART), *shrunk_overrides("{ws}/store.zarr", "{ws}/code_run", "trainer.max_steps=4"),
                    "--resume"], "code_run/last.ckpt", REFUSED),
    ("fit-ckpt-path", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "ckpt_path={ws}/code.ckpt"], "code.ckpt", REFUSED),
    ("fit-encoder-init", ["fit", "--config", str(QUICKSTART), *RUN_OVERRIDES, "model.encoder_init={ws}/code_encoder.pt"],
     "code_encoder.pt", REFUSED),
    ("fit-topple", ["fit-topple", "--checkpoint", "{ws}/code.ckpt", "--out", "{ws}/t.ckpt"], "code.ckpt", REFUSED),
    ("view-checkpoint", ["view", "--checkpoint", "{ws}/code.ckpt", "--data", "{ws}/store.zarr", "--sims", "0", "--out", "{ws}/v.html"],
     "code.ckpt", REFUSED),
    ("view-prediction", ["view", "{ws}/code.npz", "--out", "{ws}/v.html"], "code.npz", "holds Python objects " + REFUSED),
    ("export", ["export", "{ws}/code.ckpt", "{ws}/e.ckpt"], "code.ckpt", REFUSED),
    ("export-linear-from", ["export", "{ws}/run/last.ckpt", "{ws}/e.ckpt", "--linear-from", "{ws}/code.ckpt"], "code.ckpt", REFUSED),
    ("store-test", ["test", "--checkpoint", "{ws}/run/last.ckpt", "--data", "{ws}/code.zarr", "--out", "{ws}/rep"], "code.zarr",
     "Unknown codec: 'numcodecs.pickle'"),
    ("store-fit", ["fit", "--config", str(QUICKSTART), "data.store={ws}/code.zarr", "out_dir={ws}/new_run"], "code.zarr",
     "Unknown codec: 'numcodecs.pickle'"),
    ("store-info", ["data", "info", "{ws}/code.zarr"], "code.zarr", "Unknown codec: 'numcodecs.pickle'"),
]


def test_the_planted_files_do_run_code_when_unpickled(workspace, marker):
    # Otherwise the test below would prove nothing.
    for load in (lambda: torch.load(workspace / "code.ckpt", weights_only=False),
                 lambda: torch.load(workspace / "code_encoder.pt", weights_only=False),
                 lambda: np.load(workspace / "code.npz", allow_pickle=True)["com_position"],
                 lambda: pickle.loads((workspace / "code.zarr" / "sims" / "friction" / "c" / "0").read_bytes())):
        load()
        assert marker.exists()
        marker.unlink()


@pytest.mark.parametrize("argv, named, expected", [pytest.param(a, n, e, id=i) for i, a, n, e in CODE_CASES])
def test_a_file_that_carries_code_runs_nothing_and_is_refused_in_one_line(workspace, marker, capsys, monkeypatch,
                                                                         argv, named, expected):
    args = [a.replace("{ws}", str(workspace)) for a in argv]
    before = digest(workspace)
    capsys.readouterr()
    if args[0] == "export":
        from physdyn.models import export

        monkeypatch.setattr(sys, "argv", ["export", *args[1:]])
        with pytest.raises(SystemExit) as exited:
            export.main()
        status = exited.value.code
    else:
        status = main(args)
    err = capsys.readouterr().err.strip()
    ran = marker.exists()
    marker.unlink(missing_ok=True)  # so that one failure does not fail the cases after it
    assert not ran, "the file's code ran"
    lines = [line for line in err.splitlines() if line.strip()]
    assert status == 2 and len(lines) == 1, f"exit {status}: {err}"
    assert str(workspace / named) in lines[0] and expected in lines[0], lines[0]
    assert "not a PyTorch checkpoint" not in lines[0] and "not a physdyn DynamicsModel checkpoint" not in lines[0], lines[0]
    assert digest(workspace) == before, "the workspace changed"
