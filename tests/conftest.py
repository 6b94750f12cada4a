"""Shared fixtures: small but real simulated stores, made once per pytest run."""

from __future__ import annotations

import ast
import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from physdyn.config import DataConfig, load_config

REPO = Path(__file__).resolve().parents[1]
QUICKSTART_DATA = REPO / "configs" / "data" / "quickstart.yaml"

# The real quickstart preset shrunk: every category, a few shapes, a few pushes each.
TINY_OVERRIDES = [f"families.{name}.shapes=5" for name in ("primitives", "bottles", "mugs", "trashcans", "speakers")] + [
    f"families.{name}.sims_per_shape=6" for name in ("primitives", "bottles", "mugs", "trashcans", "speakers")
] + ["shapes_per_block=2"]


def tiny_data_config(*extra: str) -> DataConfig:
    return load_config(DataConfig, QUICKSTART_DATA, TINY_OVERRIDES + list(extra))


def shared_root(tmp_path_factory) -> Path:
    """The run's temporary folder that its pytest-xdist workers share (their own temporary folders lie in
    it), or the run's own without xdist: where work done once for the whole run, under a lock, goes."""
    root = tmp_path_factory.getbasetemp()
    return root.parent if os.environ.get("PYTEST_XDIST_WORKER") else root


def shared_store(tmp_path_factory, name: str, *extra: str) -> str:
    """A tiny store simulated once per pytest run. `make test` runs the suite on two pytest-xdist workers:
    the first to ask simulates the store (12 s) under a lock in the run's common temporary folder, and the
    other reads it, rather than both simulating it at once. It is written beside its path and renamed, so a
    worker never reads half a store. Tests only read these stores."""
    from filelock import FileLock

    from physdyn.data.simulated_store import generate_dataset

    out = shared_root(tmp_path_factory) / "shared_stores" / name
    out.parent.mkdir(exist_ok=True)
    with FileLock(str(out) + ".lock"):
        if not out.exists():
            partial = out.with_name(out.name + ".partial")
            shutil.rmtree(partial, ignore_errors=True)
            generate_dataset(tiny_data_config(*extra), str(partial), workers=1, progress=False)
            os.replace(partial, out)
    return str(out)


SHARED_STORES = {"tiny.zarr": (), "tiny_hull.zarr": ("points_method=hull_surface", "num_points=64")}


@pytest.fixture(scope="session", autouse=True)
def _stores_made_side_by_side(tmp_path_factory) -> None:
    """On two or more xdist workers, each starts by making a different store, so both are made at once (12 s
    each) instead of one worker waiting on the lock while the other makes the one they both first need. One
    process alone makes each store when a test first asks for it."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if not worker.startswith("gw"):
        return
    names = list(SHARED_STORES)
    first = int(worker[2:]) % len(names)
    for name in names[first:] + names[:first]:
        shared_store(tmp_path_factory, name, *SHARED_STORES[name])


@pytest.fixture(scope="session")
def tiny_store(tmp_path_factory) -> str:
    """Path of a complete, real store: 25 shapes over the five categories, 150 simulated pushes."""
    return shared_store(tmp_path_factory, "tiny.zarr", *SHARED_STORES["tiny.zarr"])


@pytest.fixture(scope="session")
def tiny_hull_store(tmp_path_factory) -> str:
    """The tiny store's shapes and pushes with ``hull_surface`` clouds of 64 points (the hull's vertices first)."""
    return shared_store(tmp_path_factory, "tiny_hull.zarr", *SHARED_STORES["tiny_hull.zarr"])


def run_cli(*args: str, timeout: float = 300, check: bool = False) -> subprocess.CompletedProcess:
    """Run `physdyn ARGS` as a user would (a fresh process), capturing its output."""
    proc = subprocess.run([sys.executable, "-m", "physdyn.cli", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO)
    if check and proc.returncode != 0:
        raise AssertionError(f"physdyn {' '.join(args)} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return proc


def refuse_pybullet(monkeypatch) -> None:
    """From here on in the test, PyBullet refuses to run: any simulation inside a prediction fails."""
    import pybullet

    def refuse(*args, **kwargs):
        raise AssertionError("PyBullet ran inside the prediction")

    for name in ("connect", "stepSimulation"):
        monkeypatch.setattr(pybullet, name, refuse)


def module_level_imports(module: str) -> tuple[set[str], set[str]]:
    """What importing ``module`` imports, its package's modules followed through what runs when they are
    imported (module level, inside ``try``/``if``/``with`` and class bodies; not functions, not ``if
    TYPE_CHECKING:``), with every parent package and ``from package import submodule`` -> (the physdyn
    modules seen, the top-level packages reached)."""

    def statements(body):
        for node in body:
            if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
                yield from statements(node.orelse)
            elif isinstance(node, (ast.If, ast.Try, ast.With, ast.ClassDef)):
                for part in ("body", "orelse", "finalbody"):
                    yield from statements(getattr(node, part, []))
                for handler in getattr(node, "handlers", []):
                    yield from statements(handler.body)
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                yield node

    def modules(name: str) -> list[str]:  # the module and its parent packages (importing it runs them all)
        parts = name.split(".")
        return [".".join(parts[:i]) for i in range(2, len(parts) + 1)]

    seen, todo, reached = set(), [module], set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        tree = ast.parse(open(importlib.util.find_spec(name).origin).read())
        for node in statements(tree.body):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            for imported in names:
                reached.add(imported.split(".")[0])
                if imported.startswith("physdyn."):
                    todo.extend(modules(imported))
                    if isinstance(node, ast.ImportFrom) and importlib.util.find_spec(imported).submodule_search_locations:
                        # `from physdyn.package import submodule`
                        todo.extend(f"{imported}.{a.name}" for a in node.names
                                    if importlib.util.find_spec(f"{imported}.{a.name}") is not None)
    return seen, reached
