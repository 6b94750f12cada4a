"""Checkpoints are read without running code, and full Lightning checkpoints keep loading.

``tests/fixtures/old_format.ckpt`` is the ``last.ckpt`` of a tiny `physdyn fit` run (the quickstart preset
shrunk as in ``conftest.SHRINK``, three steps on the tiny store), as physdyn 0.1.0 wrote it on 2026-11-25 for a
reader without ``weights_only=True``: weights, hyper-parameters, and Lightning's optimiser, scheduler, loop
and callback states. The refusal of files that carry code, command by command: tests/test_bad_inputs.py.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from physdyn.config import ExperimentConfig, config_from_dict
from physdyn.eval.baselines import load_checkpoint
from physdyn.models.checkpoint_file import read_checkpoint
from physdyn.models.dynamics_module import DynamicsModel
from physdyn.models.trainer_setup import SafeCheckpointIO
from physdyn.models.training import fit
from physdyn.predict.predictor import BUNDLED_CHECKPOINT, load_predictor
from tests.conftest import REPO

OLD_FORMAT = REPO / "tests" / "fixtures" / "old_format.ckpt"


@pytest.mark.parametrize("path", [OLD_FORMAT, BUNDLED_CHECKPOINT], ids=["old-fit-run", "bundled"])
def test_old_checkpoints_load_and_predict(path, tmp_path):
    box = tmp_path / "box.obj"
    trimesh.creation.box((0.08, 0.12, 0.2)).export(box)
    result = load_predictor(str(path)).predict(str(box), [1.0, 0.0, 0.0], [0.0, 0.0, 2.0], seconds=0.5)
    assert np.isfinite(result["com_position"]).all() and len(result["time"]) > 1


@pytest.mark.parametrize("path", [OLD_FORMAT, BUNDLED_CHECKPOINT], ids=["old-fit-run", "bundled"])
def test_the_model_is_the_one_lightning_would_load(path):
    # load_checkpoint builds the model from the dict it read safely; Lightning's loader builds the same one.
    ours = load_checkpoint(path)
    theirs = DynamicsModel.load_from_checkpoint(path, map_location="cpu", weights_only=True)
    assert dict(ours.hparams) == dict(theirs.hparams)
    theirs_state = theirs.state_dict()
    assert ours.state_dict().keys() == theirs_state.keys()
    for key, value in ours.state_dict().items():
        assert torch.equal(value, theirs_state[key]), key
    # what fit-topple added travels beside the network, as its pipeline's topple stage
    from physdyn.models.checkpoint_file import read_checkpoint
    from physdyn.pipeline.presets import load_pipeline

    assert (load_pipeline(path).topple.registered_name == "head") == (not read_checkpoint(path).get("topple_classifier"))
    assert (ours.linear_channels is None) == (theirs.linear_channels is None)


def test_an_old_checkpoint_resumes_training(tiny_store, tmp_path):
    # Lightning reads the optimiser, scheduler and loop states through SafeCheckpointIO.
    state = SafeCheckpointIO().load_checkpoint(OLD_FORMAT)
    assert {"optimizer_states", "lr_schedulers", "loops", "callbacks"} <= set(state) and state["global_step"] == 3
    saved = read_checkpoint(OLD_FORMAT)["hyper_parameters"]["config"]
    config = config_from_dict(ExperimentConfig, {
        **saved, "data": {**saved["data"], "store": tiny_store}, "out_dir": str(tmp_path / "run"),
        "ckpt_path": str(OLD_FORMAT), "trainer": {**saved["trainer"], "max_steps": 5},
    })
    result = fit(config)
    assert read_checkpoint(result.last_checkpoint)["global_step"] == 5
