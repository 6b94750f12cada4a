"""`physdyn recipe`: a preset's stages trained by one command, on a tiny real store, kept step by step."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from physdyn.cli import main
from physdyn.pipeline.presets import preset_recipe
from physdyn.pipeline.recipe import command_line, outputs, with_overrides
from physdyn.predict.predictor import load_predictor

# the tiny store's clouds have 64 points: the PointNets thin them to 32 (fast's thin 256 to 64)
SHORT = [f"--set={o}" for o in ("topple.steps=20", "topple.batch=16", "topple.seeds=[0]", "topple.num_points=32",
                                 "correction.steps=20", "correction.batch=16", "correction.seeds=[0]",
                                 "correction.num_points=32")]


@pytest.mark.slow  # three trainings and a check of each (about 15 s); make quickstart runs the recipe too
def test_the_fast_recipe_trains_every_stage_and_the_model_predicts(tiny_hull_store, tmp_path, capsys):
    out = tmp_path / "fast"
    assert main(["recipe", "fast", "--data", tiny_hull_store, "--out", str(out), *SHORT]) == 0
    model = out / "model.ckpt"
    pipeline = load_predictor(str(model)).model
    # the preset's stages, from the checkpoint the recipe wrote
    assert (type(pipeline.motion).__name__, type(pipeline.topple).__name__, type(pipeline.correction).__name__) == \
        tuple(type(getattr(load_predictor("fast").model, kind)).__name__ for kind in ("motion", "topple", "correction"))
    assert pipeline.motion.network.config.model.contact_substeps == 8
    result = load_predictor(str(model)).predict(trimesh.creation.box((0.1, 0.16, 0.12)), [1.0, 0.0, 0.0], [0, 0, 3], 2.0)
    assert np.isfinite(result["com_position"]).all() and result["com_position"][-1, 0] > 0.05
    # a second run keeps every finished step and writes nothing
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*.ckpt")}
    capsys.readouterr()
    assert main(["recipe", "fast", "--data", tiny_hull_store, "--out", str(out), *SHORT]) == 0
    assert capsys.readouterr().out.count("kept") == 4
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.ckpt")} == before


def test_each_step_reads_the_checkpoint_of_the_one_before_or_the_one_it_names(tmp_path):
    steps = with_overrides(preset_recipe("bundled"), ["topple.seeds=[1,2]"])
    made = outputs(steps, tmp_path)
    names = [s.name for s in steps]
    fit_topple = command_line(steps, names.index("topple"), ["a.zarr", "b.zarr"], tmp_path)
    assert fit_topple[:3] == ["fit-topple", "--checkpoint", str(made["combined"])]
    assert fit_topple.count("--data") == 2 and "--physics" in fit_topple and fit_topple[-3:] == ["--seeds", "1", "2"]
    angular = command_line(steps, 0, ["a.zarr", "b.zarr"], tmp_path)
    assert angular[:3] == ["fit", "--config", "bundled"] and "data.store=a.zarr" in angular


@pytest.mark.parametrize("override, text", [
    ("nosuch.steps=3", "no step 'nosuch'"),
    ("topple", "expected STEP.KEY=VALUE"),
])
def test_a_bad_override_is_one_line_and_nothing_is_written(tmp_path, tiny_hull_store, capsys, override, text):
    assert main(["recipe", "fast", "--data", tiny_hull_store, "--out", str(tmp_path / "r"), "--set", override]) == 2
    err = capsys.readouterr().err.strip()
    assert text in err and len(err.splitlines()) == 1
    assert not (tmp_path / "r").exists()


def test_a_preset_without_a_recipe_says_so(tmp_path, tiny_hull_store, capsys):
    assert main(["recipe", "contact_prior", "--data", tiny_hull_store, "--out", str(tmp_path / "r")]) == 2
    assert "has no recipe" in capsys.readouterr().err
