"""What a new user runs first. A plain (non-editable) install predicts a mesh with the shipped default and nothing
else: the README's first command, run outside the source tree (the shipped model travels inside the package).
`make quickstart` trains the shipped default's kind of model: the same prior, on the clouds it reads."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
MESH = REPO / "examples" / "meshes" / "bracket_mm.obj"
QUICKSTART_DATA = "configs/data/quickstart_hull_small.yaml"


def test_the_quickstart_trains_the_shipped_defaults_kind_of_model():
    from physdyn.config import DataConfig, load_config, preset_path, to_dict
    from physdyn.models.checkpoint_file import read_checkpoint
    from physdyn.models.training import load_experiment_config
    from physdyn.pipeline.presets import preset_recipe

    shipped = read_checkpoint(REPO / "physdyn" / "assets" / "fast.ckpt")["hyper_parameters"]
    motion = preset_recipe("fast")[0]  # the recipe's first step writes the contact prior
    prior = to_dict(load_experiment_config(preset_path(motion.config, "experiment"),
                                           [f"{k}={v}" for k, v in motion.settings.items()]))
    assert prior["model"] == shipped["config"]["model"]  # the contact prior with fast's settings (8 sub-steps...)
    assert prior["data"]["normalization"] == shipped["config"]["data"]["normalization"]
    assert prior["trainer"]["max_steps"] == 0  # no network: nothing to train, `fit` only writes it
    data = load_config(DataConfig, REPO / QUICKSTART_DATA)
    info = shipped["data_info"]
    assert (data.points_method, data.num_points, data.rate_hz) == (info["points_method"], info["num_points"], info["rate_hz"])
    # the Makefile's main job simulates that store and runs fast's recipe on it
    make = (REPO / "Makefile").read_text()
    job = make[make.index("\nquickstart:"):make.index("\ntest:")]
    store = re.search(r"^QS_DATA := (\S+)$", make, re.M).group(1)
    assert QUICKSTART_DATA in job and re.search(r"physdyn recipe fast --data \$\(QS_DATA\)", job)
    assert store.endswith(".zarr")


@pytest.mark.slow  # builds a wheel, makes a venv and predicts (about half a minute)
def test_a_plain_install_predicts_the_example_mesh_with_the_shipped_model(tmp_path):
    wheels, venv, elsewhere = tmp_path / "wheels", tmp_path / "venv", tmp_path / "elsewhere"
    elsewhere.mkdir()
    run = lambda *args: subprocess.run([*map(str, args)], cwd=elsewhere, capture_output=True, text=True,  # noqa: E731
                                       timeout=600)
    built = run(sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", REPO, "-w", wheels)
    assert built.returncode == 0, built.stderr[-2000:]
    # The venv sees this environment's torch & co (no download) but gets its own, non-editable physdyn.
    assert run(sys.executable, "-m", "venv", "--system-site-packages", venv).returncode == 0
    installed = run(venv / "bin" / "python", "-m", "pip", "install", "-q", "--no-deps", "--no-index",
                    next(wheels.glob("physdyn-*.whl")))
    assert installed.returncode == 0, installed.stderr[-2000:]
    done = run(venv / "bin" / "physdyn", "predict", MESH, "--scale", "0.001", "--lin-vel", "1.2", "0", "0",
               "--ang-vel", "0", "0", "3")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "prediction (fast)" in done.stdout and "centre of mass at" in done.stdout, done.stdout
    where = run(venv / "bin" / "python", "-c", "import physdyn; print(physdyn.__file__)")
    assert str(venv) in where.stdout, where.stdout + where.stderr  # the installed copy answered, not the source tree
