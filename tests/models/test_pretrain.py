"""`physdyn pretrain`: the encoder learns shape classes and `fit` can start from its weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from physdyn.data.normalization import Normalization
from physdyn.errors import ConfigError
from physdyn.models.dynamics_module import DynamicsModel
from physdyn.models.pretrain import load_pretrain_config, pretrain
from physdyn.models.training import load_experiment_config
from tests.conftest import run_cli
from tests.models.conftest import QUICKSTART, REPO

PRETRAIN = REPO / "configs" / "experiment" / "pretrain.yaml"
SMALL_ENCODER = [
    "encoder.params.point_widths=[16,16,32]", "encoder.params.fc_widths=[32]", "encoder.params.feature_size=8",
    "data.num_points=64", "data.oversample=1", "trainer.max_steps=3", "trainer.log_every_n_steps=1",
    "trainer.enable_model_summary=false", "progress_bar=false",
]


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_physdyn_pretrain_runs_a_few_steps_and_fit_can_start_from_it(tmp_path):
    out = tmp_path / "pre"
    proc = run_cli(
        "pretrain", "--config", str(PRETRAIN), f"out_dir={out}", "data.families.primitives=3",
        "data.families.mugs=3", *SMALL_ENCODER, timeout=240,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "encoder.pt" in proc.stdout
    saved = torch.load(out / "encoder.pt", map_location="cpu", weights_only=False)
    assert saved["encoder"] == "pointnet" and saved["classes"] == ["mugs", "primitives"]
    # a dynamics model with the same encoder sizes starts from exactly these weights
    cfg = load_experiment_config(QUICKSTART, [
        "model.encoder.params.point_widths=[16,16,32]", "model.encoder.params.fc_widths=[32]",
        "model.encoder.params.feature_size=8", f"model.encoder_init={out / 'encoder.pt'}",
    ])
    model = DynamicsModel(cfg, Normalization())
    assert model.load_encoder_weights(cfg.model.encoder_init) == len(saved["state_dict"])
    for key, value in model.encoder.state_dict().items():
        assert torch.equal(value, saved["state_dict"][key]), key
    # an encoder of other sizes: nothing fits -> a clear error
    other = DynamicsModel(load_experiment_config(QUICKSTART), Normalization())
    with pytest.raises(ConfigError, match="model.encoder_init"):
        other.load_encoder_weights(out / "encoder.pt")


def _modelnet(root, per_split=3):
    makers = {
        "box": lambda s: trimesh.creation.box(extents=[0.1 * s, 0.2, 0.05]),
        "cylinder": lambda s: trimesh.creation.cylinder(radius=0.05 * s, height=0.2),
        "sphere": lambda s: trimesh.creation.icosphere(radius=0.1 * s),
    }
    for name, make in makers.items():
        for split in ("train", "test"):
            (root / name / split).mkdir(parents=True)
            for i in range(per_split):
                make(1.0 + 0.2 * i).export(root / name / split / f"{name}_{i:04d}.off")


def test_pretrain_on_a_modelnet_layout_folder_learns_the_classes(tmp_path):
    _modelnet(tmp_path / "mn")
    cfg = load_pretrain_config(PRETRAIN, [
        f"data.modelnet_root={tmp_path / 'mn'}", f"out_dir={tmp_path / 'out'}", *SMALL_ENCODER,
        "trainer.max_steps=60", "data.batch_size=9", "optim.lr=3e-3", "data.augment=false",
        "trainer.check_val_every_n_epoch=20",
    ])
    result = pretrain(cfg)
    saved = torch.load(result.encoder_path, map_location="cpu", weights_only=False)
    assert saved["classes"] == ["box", "cylinder", "sphere"]
    assert result.metrics["train/loss"] < np.log(3)  # below chance: it learned something
    with pytest.raises(ConfigError, match="data.modelnet_root"):
        pretrain(load_pretrain_config(PRETRAIN, [f"data.modelnet_root={tmp_path / 'missing'}", f"out_dir={tmp_path / 'o2'}"]))
    with pytest.raises(ConfigError, match="data.families.chairs"):
        load_pretrain_config(PRETRAIN, ["data.families.chairs=3"])


def test_pretraining_follows_the_step_learning_rate_schedule(tmp_path):
    # Pretraining shares fit's optimiser set-up: `optim.schedule=step` once stayed constant here.
    out = tmp_path / "pre"
    cfg = load_pretrain_config(PRETRAIN, [
        f"out_dir={out}", "data.families.primitives=3", "data.families.mugs=3", *SMALL_ENCODER,
        "data.batch_size=4", "optim.schedule=step", "optim.decay_samples=4", "optim.decay_rate=0.5",
    ])
    pretrain(cfg)
    ckpt = torch.load(out / "last.ckpt", map_location="cpu", weights_only=False)
    assert ckpt["global_step"] == 3
    assert ckpt["optimizer_states"][0]["param_groups"][0]["lr"] == pytest.approx(1e-3 * 0.5**3)
    with pytest.raises(ConfigError, match="optim.lr_min"):
        pretrain(load_pretrain_config(PRETRAIN, [f"out_dir={tmp_path / 'bad'}", *SMALL_ENCODER, "optim.lr_min=1.0",
                                                  "data.families.primitives=3", "data.families.mugs=3"]))
