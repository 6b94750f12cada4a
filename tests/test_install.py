"""A plain (non-editable) install works outside the source tree: the presets travel inside the package."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # builds a wheel, makes a venv and runs part of the tiny reproduce suite (about a minute)
def test_a_plain_install_reproduces_outside_the_source_tree(tmp_path):
    wheels, venv, elsewhere = tmp_path / "wheels", tmp_path / "venv", tmp_path / "elsewhere"
    elsewhere.mkdir()
    run = lambda *args, cwd=elsewhere: subprocess.run([*map(str, args)], cwd=cwd, capture_output=True, text=True,  # noqa: E731
                                                      timeout=600)
    built = run(sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", REPO, "-w", wheels)
    assert built.returncode == 0, built.stderr[-2000:]
    # The venv sees this environment's torch & co (no download) but gets its own, non-editable physdyn.
    assert run(sys.executable, "-m", "venv", "--system-site-packages", venv).returncode == 0
    python = venv / "bin" / "python"
    installed = run(python, "-m", "pip", "install", "-q", "--no-deps", "--no-index", next(wheels.glob("physdyn-*.whl")))
    assert installed.returncode == 0, installed.stderr[-2000:]
    where = run(python, "-c", "import physdyn, physdyn.config as c; print(physdyn.__file__); print(c.PRESETS.is_symlink())")
    assert str(venv) in where.stdout.splitlines()[0] and where.stdout.splitlines()[1] == "False", where.stdout + where.stderr
    before = (REPO / "docs" / "results.md").read_bytes()
    done = run(venv / "bin" / "physdyn", "reproduce", "--scale", "tiny", "--out", "suite", "--only", "lstm-vs-mlp")
    assert done.returncode == 0, done.stderr[-2000:]
    assert (elsewhere / "suite" / "results.md").is_file() and (elsewhere / "suite" / "train").is_dir()
    assert (REPO / "docs" / "results.md").read_bytes() == before  # the project's page is not touched
    listed = run(venv / "bin" / "physdyn", "configs", "experiment")
    assert "quickstart" in listed.stdout and "bundled" in listed.stdout
