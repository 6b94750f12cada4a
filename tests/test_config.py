"""Config loading: presets compose, overrides are typed, switching a component drops the old one's params."""

from pathlib import Path

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


def test_presets_are_found_by_name_and_by_source_path_from_anywhere(tmp_path, monkeypatch, capsys):
    from physdyn.cli import main
    from physdyn.config import PRESETS, list_presets, preset_path

    monkeypatch.chdir(tmp_path)  # outside the source tree, as after a plain `pip install`
    by_name = preset_path("quickstart", "experiment")
    assert by_name == PRESETS / "experiment" / "quickstart.yaml"
    assert preset_path("configs/experiment/quickstart.yaml", "experiment").read_text() == by_name.read_text()
    assert load_experiment_config(by_name).name == "quickstart"  # its defaults (../model, ../trainer) resolve
    assert load_config(DataConfig, preset_path("quickstart", "data")).rate_hz == 15.0
    with pytest.raises(ConfigError, match="neither a config file nor a data preset; presets: .*quickstart"):
        preset_path("quikstart", "data")
    mine = tmp_path / "configs" / "data" / "quickstart.yaml"  # a user's own file of that name wins
    mine.parent.mkdir(parents=True)
    mine.write_text("seed: 7\n")
    assert preset_path("configs/data/quickstart.yaml", "data") == Path("configs/data/quickstart.yaml")
    listed = list_presets()
    assert {"quickstart", "speakers"} <= {name for name, _ in listed["data"]}
    assert all(summary for entries in listed.values() for _, summary in entries)  # every preset says what it is
    assert main(["configs", "experiment"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("experiment (physdyn fit --config NAME):") and "quickstart" in out and "data (" not in out


@pytest.mark.slow  # builds a wheel (a few seconds)
def test_the_wheel_ships_every_preset_and_the_viewer_script(tmp_path):
    import subprocess
    import sys
    import zipfile

    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", str(REPO),
                    "-w", str(tmp_path)], check=True, capture_output=True, timeout=300)
    names = set(zipfile.ZipFile(next(tmp_path.glob("physdyn-*.whl"))).namelist())
    for preset in (REPO / "configs").glob("*/*.yaml"):
        assert f"physdyn/presets/{preset.parent.name}/{preset.name}" in names, preset
    assert "physdyn/viz/viewer.js" in names and "physdyn/assets/bundled.ckpt" in names


def test_defaults_that_include_each_other_are_a_one_line_error(tmp_path):
    (tmp_path / "a.yaml").write_text("defaults: [b.yaml]\nseed: 1\n")
    (tmp_path / "b.yaml").write_text("defaults: [a.yaml]\nseed: 2\n")
    (tmp_path / "self.yaml").write_text("defaults: [self.yaml]\n")
    for name in ("a.yaml", "self.yaml"):
        with pytest.raises(ConfigError, match="cycle") as info:
            load_config(DataConfig, tmp_path / name)
        assert "\n" not in str(info.value)


@pytest.mark.parametrize("scale", sorted(p.name for p in (REPO / "configs/reproduce").glob("*.yaml")))
def test_every_reproduce_scale_loads_and_its_training_configs_validate(scale):
    from physdyn.experiments.suite import load_scale

    cfg, path = load_scale(REPO / "configs/reproduce" / scale)
    for preset, overrides in ((cfg.train_preset, cfg.train_overrides), (cfg.mlp_preset, cfg.mlp_overrides)):
        load_experiment_config(path.parent / preset, list(overrides))
    if scale == "cpu_detached.yaml":  # the cpu scale with one override more
        cpu, _ = load_scale("cpu")
        assert cfg.data == cpu.data and cfg.mlp_overrides == cpu.mlp_overrides
        trained = load_experiment_config(path.parent / cfg.train_preset, list(cfg.train_overrides))
        assert trained.model.head.params == {"detach_topple": True} and trained.trainer["max_steps"] == 3000


def test_every_public_name_of_the_config_modules_is_importable_from_physdyn_config():
    """The schemas live in one module per concern (physdyn/config/); code and plugins import them from
    ``physdyn.config``, so a name added to a module must be re-exported there too."""
    import ast
    import importlib
    from typing import TypeVar

    import physdyn.config as config

    missing = []
    for path in sorted(Path(config.__file__).parent.glob("*.py")):
        if path.name == "__init__.py":
            continue
        module = importlib.import_module(f"physdyn.config.{path.stem}")
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
                names = [node.name]
            else:
                targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
                names = [t.id for t in targets if isinstance(t, ast.Name)]
            for name in names:
                value = getattr(module, name)
                if name.startswith("_") or isinstance(value, TypeVar):
                    continue
                if getattr(config, name, None) is not value or name not in config.__all__:
                    missing.append(f"{module.__name__}.{name}")
    assert not missing, f"not re-exported by physdyn/config/__init__.py: {', '.join(missing)}"
