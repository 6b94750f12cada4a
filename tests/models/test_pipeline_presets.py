"""Predictors as presets of registered stages: the shipped presets build through one factory and `physdyn
configs` lists them; a new stage is a registered class plus a config key, and changes a prediction exactly as
it says."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
import trimesh

from physdyn.errors import ConfigError
from physdyn.pipeline.presets import StageConfig, build_pipeline, load_pipeline, preset_file, read_preset, shipped_presets
from physdyn.pipeline.spread import SpreadStage
from physdyn.pipeline.stages import CorrectionStage, ToppleStage
from physdyn.predict.predictor import load_predictor
from physdyn.registry import ALL_REGISTRIES, CORRECTION_STAGES, DISTRIBUTION_STAGES, TOPPLE_STAGES

OFFSET = np.array([0.03, -0.02, 0.0])  # m: what the toy correction adds to every position


@CORRECTION_STAGES.register("toy_offset")
class ToyOffset(CorrectionStage):
    """Moves the whole trajectory by ``Config.offset`` (after the first state)."""

    @dataclasses.dataclass
    class Config:
        offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __init__(self, config: "ToyOffset.Config"):
        self.offset = np.asarray(config.offset, dtype=np.float64)

    def apply(self, batch, states, toppled):
        states["com_position"][:, 1:] += self.offset


@TOPPLE_STAGES.register("toy_half")
class ToyHalf(ToppleStage):
    """Every push half toppled at every step after the first."""

    def run(self, batch, motion):
        out = np.full((batch.size, batch.steps + 1), 0.5)
        out[:, 0] = 0.0
        return out


@DISTRIBUTION_STAGES.register("toy_ring")
class ToyRing(SpreadStage):
    """Every sample ends ``Config.radius`` from the roll-out's end, spaced evenly around it."""

    @dataclasses.dataclass
    class Config:
        radius: float = 0.0

    def __init__(self, config: "ToyRing.Config"):
        self.radius = config.radius

    def spread(self, nominal, lin_vel, ang_vel, uncertainty, samples, rng):
        angle = 2 * np.pi * np.arange(samples) / samples
        com = np.repeat(nominal["com_position"][:, None], samples, axis=1)
        com[:, :, -1, :2] += self.radius * np.stack([np.cos(angle), np.sin(angle)], axis=-1)
        return {"com_position": com, "orientation_xyzw": np.repeat(nominal["orientation_xyzw"][:, None], samples, axis=1),
                "toppled": np.zeros(com.shape[:2], dtype=bool)}


def test_the_shipped_presets_are_listed_and_each_names_a_stage_of_each_kind():
    assert {"fast", "bundled", "contact_prior"} <= set(shipped_presets())
    for name in ("fast", "bundled", "contact_prior"):
        preset = read_preset(preset_file(name))
        assert preset.name == name and preset.motion.name and preset.topple.name and preset.correction.name
    assert {"motion_stages", "topple_stages", "correction_stages"} <= set(ALL_REGISTRIES)
    fast, bundled = load_pipeline("fast"), load_pipeline("bundled")
    assert [type(s).__name__ for s in (fast.motion, fast.topple, fast.correction)] == [
        "ContactPriorMotion", "PointNetTopple", "PointNetCorrection"]
    assert [type(s).__name__ for s in (bundled.motion, bundled.topple, bundled.correction)] == [
        "SimulatedStartMotion", "LogisticTopple", "NoCorrection"]
    assert bundled.simulates and not fast.simulates and not bundled.without_simulator().simulates


def test_physdyn_configs_lists_the_predictor_presets(capsys):
    from physdyn.cli import main

    assert main(["configs", "predictor"]) == 0
    out = capsys.readouterr().out
    assert all(f"  {name} " in out for name in ("fast", "bundled", "contact_prior"))
    assert main(["configs"]) == 0 and "predictor (" in capsys.readouterr().out


def test_a_registered_stage_named_in_a_preset_changes_the_prediction_as_it_says(tmp_path):
    box = trimesh.creation.box((0.1, 0.06, 0.04))
    push = ([0.8, 0.1, 0.0], [0.0, 0.0, 3.0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain = load_predictor("contact_prior").predict(box, *push, seconds=1.0)
    preset = tmp_path / "toy.yaml"
    preset.write_text("name: toy\nmotion: {name: contact_prior}\ntopple: toy_half\n"
                      "correction: {name: toy_offset, params: {offset: [0.03, -0.02, 0.0]}}\n")
    toy = load_predictor(str(preset)).predict(box, *push, seconds=1.0)
    np.testing.assert_array_equal(toy["com_position"][0], plain["com_position"][0])
    np.testing.assert_allclose(toy["com_position"][1:], plain["com_position"][1:] + OFFSET, atol=1e-12)
    np.testing.assert_array_equal(toy["orientation_xyzw"], plain["orientation_xyzw"])
    assert plain["topple_probability"] is None and not plain["toppled"]
    np.testing.assert_array_equal(toy["topple_probability"][1:], 0.5)
    assert toy["toppled"] and toy["checkpoint"] == str(preset)


def test_a_registered_distribution_stage_makes_the_samples(tmp_path):
    box = trimesh.creation.box((0.1, 0.06, 0.04))
    push = ([0.8, 0.1, 0.0], [0.0, 0.0, 3.0])
    preset = tmp_path / "ring.yaml"
    preset.write_text("name: ring\nmotion: {name: contact_prior}\ndistribution: {name: toy_ring, params: {radius: 0.05}}\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ring = load_predictor(str(preset))
        plain = ring.predict(box, *push, seconds=1.0)
        dist = ring.predict_distribution(box, *push, seconds=1.0, samples=8)
    assert dist["distribution"] == "toy_ring" and "sample_lin_vel" not in dist
    end = dist["com_position"][:, -1, :2] - plain["com_position"][-1, :2]
    np.testing.assert_allclose(np.linalg.norm(end, axis=1), 0.05, atol=1e-12)
    np.testing.assert_allclose(dist["final_position_mean"][:2], plain["com_position"][-1, :2], atol=1e-12)


def test_a_preset_naming_an_unknown_stage_or_parameter_says_which_key(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nmotion: {name: contact_prior}\ntopple: {name: crystal_ball}\n")
    with pytest.raises(ConfigError, match=r"topple\.name.*unknown topple stage 'crystal_ball'"):
        load_pipeline(str(bad))
    bad.write_text("name: bad\nmotion: {name: contact_prior, params: {rate: 30}}\n")
    with pytest.raises(ConfigError, match=r"motion\.params"):
        load_pipeline(str(bad))
    preset = dataclasses.replace(read_preset(preset_file("fast")), weights="bundled")
    with pytest.raises(ConfigError, match="changes are not its prior's; name motion 'network'"):
        build_pipeline(preset)
    with pytest.raises(ConfigError, match="reads the weights' 'outcome_correction'"):
        build_pipeline(dataclasses.replace(preset, motion=StageConfig("network"), topple=StageConfig("logistic")))
