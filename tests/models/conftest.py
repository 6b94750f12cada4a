"""Helpers for the training tests: the REAL presets, shrunk to run in seconds on a CPU."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
QUICKSTART = REPO / "configs" / "experiment" / "quickstart.yaml"

# lightning-hydra-template style: the real preset with a tiny model and a few steps.
SHRINK = [
    "data.num_points=64",
    "data.batch_size=16",
    "model.encoder.params.point_widths=[16,16,32]",
    "model.encoder.params.fc_widths=[32]",
    "model.encoder.params.feature_size=8",
    "model.predictor.params.num_layers=2",
    "model.predictor.params.hidden=32",
    "trainer.max_steps=3",
    "trainer.enable_model_summary=false",
    "trainer.log_every_n_steps=1",
    "progress_bar=false",
]


def shrunk_overrides(store: str, out_dir: Path, *extra: str) -> list[str]:
    """The shrink, less the predictor parameters a predictor named in ``extra`` does not take (``none`` has
    no network to shrink)."""
    import dataclasses

    from physdyn.registry import PREDICTORS

    shrink = list(SHRINK)
    named = [e.split("=", 1)[1] for e in extra if e.startswith("model.predictor.name=")]
    if named:
        fields = {f.name for f in dataclasses.fields(PREDICTORS.get(named[-1]).Config)}
        shrink = [o for o in shrink if not o.startswith("model.predictor.params.")
                  or o.split("=", 1)[0].rsplit(".", 1)[1] in fields]
    return [f"data.store={store}", f"out_dir={out_dir}", *shrink, *extra]


@pytest.fixture
def quickstart_config(tiny_store, tmp_path):
    """A factory: the real quickstart preset shrunk for the CPU, with extra overrides."""
    from physdyn.models.training import load_experiment_config

    def make(*extra: str, out: str = "run"):
        return load_experiment_config(QUICKSTART, shrunk_overrides(tiny_store, tmp_path / out, *extra))

    return make
