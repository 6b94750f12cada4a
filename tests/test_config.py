"""Config loading: presets compose, overrides are typed, switching a component drops the old one's params."""

import pytest

from physdyn.config import DataConfig, load_config
from physdyn.errors import ConfigError
from physdyn.models.training import load_experiment_config
from tests.conftest import REPO


def test_switching_a_component_by_override_drops_the_presets_params():
    preset = REPO / "configs/experiment/quickstart.yaml"
    kept = load_experiment_config(preset, ["model.encoder.name=pointnet"])
    assert "point_widths" in kept.model.encoder.params  # same component: the preset's params stay
    switched = load_experiment_config(preset, ["model.encoder.name=dgcnn", "model.encoder.params.k=8"])
    assert switched.model.encoder.name == "dgcnn" and switched.model.encoder.params == {"k": 8}


def test_presets_compose_through_defaults():
    combined = load_config(DataConfig, REPO / "configs/data/combined.yaml")
    assert list(combined.families) == ["primitives", "bottles", "mugs", "trashcans", "speakers"]
    assert sum(f.shapes * f.sims_per_shape for f in combined.families.values()) == pytest.approx(65_000, rel=0.01)
    assert load_config(DataConfig, REPO / "configs/data/speakers_30hz.yaml").rate_hz == 30


def test_malformed_yaml_is_a_one_line_error(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("families:\n  mugs: {shapes: 3\n")
    with pytest.raises(ConfigError, match="not valid YAML") as err:
        load_config(DataConfig, bad)
    assert "\n" not in str(err.value)
    listed = tmp_path / "list.yaml"
    listed.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="must be a mapping"):
        load_config(DataConfig, listed)
