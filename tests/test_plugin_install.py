"""Install the example plugin (plugins/physdyn-dgcnn) into this environment and check physdyn lists it.

The install is `pip install --no-deps --no-build-isolation --no-index -e plugins/physdyn-dgcnn`: no network,
no dependency resolution (so torch is never touched). An install already made from this checkout (`make
install` makes one) is kept; the slow test_installing_again_is_harmless repeats it. It is skipped, with the
reason, when this environment cannot build a local package (no pip, or no recent setuptools). Checks run in
fresh interpreters outside the repository, since this one may have looked up plugins before the install.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from tests.conftest import shared_root

REPO_ROOT = Path(__file__).resolve().parents[1]
PLUGIN = REPO_ROOT / "plugins" / "physdyn-dgcnn"
DIST_NAME = "physdyn-dgcnn"
PIP_INSTALL = [
    sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
    "--no-deps", "--no-build-isolation", "--no-index", "-e", str(PLUGIN),
]  # fmt: skip


def build_tools_missing() -> str | None:
    """Why this environment cannot build the plugin, or None if it can."""
    if importlib.util.find_spec("pip") is None:
        return "pip is not installed in this environment"
    try:
        version = importlib.metadata.version("setuptools")
    except importlib.metadata.PackageNotFoundError:
        return "setuptools is not installed (needed with --no-build-isolation): pip install 'setuptools>=70.1'"
    major, minor = (int(p) if p.isdigit() else 0 for p in (version.split(".") + ["0"])[:2])
    # setuptools < 70.1 needs the separate `wheel` package to build (editable) wheels.
    if (major, minor) < (70, 1) and importlib.util.find_spec("wheel") is None:
        return f"setuptools {version} needs the 'wheel' package to build: pip install 'setuptools>=70.1'"
    return None


def pip_install() -> None:
    reason = build_tools_missing()
    if reason:
        pytest.skip(reason)
    proc = subprocess.run(PIP_INSTALL, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{' '.join(PIP_INSTALL)} failed:\n{proc.stdout}\n{proc.stderr}"


def installed_from_here() -> bool:
    """Whether this environment already has the plugin installed, editable, from this checkout (what `make
    install` does), with the version and entry points its pyproject.toml declares now."""
    try:
        dist = importlib.metadata.distribution(DIST_NAME)
    except importlib.metadata.PackageNotFoundError:
        return False
    info = json.loads(dist.read_text("direct_url.json") or "{}")
    project = tomllib.loads((PLUGIN / "pyproject.toml").read_text())["project"]
    declared = {(group, name, value) for group, entries in project.get("entry-points", {}).items()
                for name, value in entries.items()}
    return (info.get("url") == PLUGIN.as_uri() and bool(info.get("dir_info", {}).get("editable"))
            and dist.version == project["version"] and {(e.group, e.name, e.value) for e in dist.entry_points} == declared)


def locked_install(tmp_path_factory, again: bool = False) -> None:
    """``pip_install`` under a file lock shared by a run's pytest-xdist workers, so two never install at
    once; unless ``again``, an install already made from this checkout is kept."""
    from filelock import FileLock

    with FileLock(str(shared_root(tmp_path_factory) / "plugin_install.lock")):
        if again or not installed_from_here():
            pip_install()


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> None:
    # `make test` runs the suite on two pytest-xdist workers. A reinstall removes the plugin for a moment, and
    # physdyn processes of the other worker that load plugins could see it half-installed then. `make
    # install` installs it before the tests, so that install is kept (test_installing_again_is_harmless, a
    # slow test, reinstalls). Without one, the first worker to need it installs it under a lock: that keeps
    # two installs apart, not other tests that read plugins while it runs.
    locked_install(tmp_path_factory)


def run_python(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=300, env=dict(os.environ)
    )


def test_plugin_depends_on_physdyn_only_never_on_torch():
    # physdyn pins torch exactly; a torch requirement here could make pip resolve a different one.
    project = tomllib.loads((PLUGIN / "pyproject.toml").read_text())["project"]
    assert project["name"] == DIST_NAME
    deps = project.get("dependencies", [])
    assert [d.split(">")[0].split("=")[0].split("<")[0].strip() for d in deps] == ["physdyn"]
    assert project["entry-points"]["physdyn.encoders"] == {"dgcnn": "physdyn_dgcnn"}


def test_installed_distribution_has_the_entry_point(installed, tmp_path):
    code = (
        "import importlib.metadata as m\n"
        f"d = m.distribution({DIST_NAME!r})\n"
        "print(d.version)\n"
        "print(sorted((e.group, e.name, e.value) for e in d.entry_points))\n"
        "print(d.requires)\n"
    )
    proc = run_python(["-c", code], tmp_path)
    assert proc.returncode == 0, proc.stderr
    version, eps, requires = proc.stdout.strip().splitlines()[-3:]
    assert version == "0.1.0"
    assert eps == "[('physdyn.encoders', 'dgcnn', 'physdyn_dgcnn')]"
    assert "torch" not in requires


def test_installed_plugin_is_registered_as_a_plugin(installed, tmp_path):
    code = (
        "from physdyn.registry import ENCODERS\n"
        "e = {e.name: e for e in ENCODERS.entries()}['dgcnn']\n"
        "print(e.source)\n"
        "enc = ENCODERS.build('dgcnn', {'k': 4, 'edge_widths': [8], 'embedding_width': 8})\n"
        "import torch\n"
        "print(tuple(enc(torch.rand(2, 10, 3)).shape))\n"
    )
    proc = run_python(["-c", code], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-2:] == [f"plugin {DIST_NAME}", "(2, 16)"]


@pytest.mark.slow  # the plugin's own suite (plugins/physdyn-dgcnn/tests) checks the same listing in the default run
def test_physdyn_components_lists_it(installed, tmp_path):
    proc = run_python(["-m", "physdyn.cli", "components"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    rows = [line.split() for line in proc.stdout.splitlines()]
    assert any(row[:3] == ["dgcnn", "plugin", DIST_NAME] for row in rows), proc.stdout
    assert "skipping" not in proc.stderr, proc.stderr  # no plugin failed to load


@pytest.mark.slow  # seconds of real simulation or installs: CI's slow pass runs it
def test_installing_again_is_harmless(installed, tmp_path, tmp_path_factory):
    locked_install(tmp_path_factory, again=True)
    proc = run_python(
        ["-c", "from physdyn.registry import ENCODERS; print(ENCODERS.names().count('dgcnn'))"], tmp_path
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "1"
