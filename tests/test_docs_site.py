"""The documentation site: the CLI reference covers every command, the nav names only pages that exist, and
(slow) the whole site builds with `mkdocs build --strict`, as `make docs` does."""

from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from physdyn.cli import build_parser

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
GENERATOR = DOCS / "scripts" / "gen_cli_ref.py"


def _generator():
    spec = importlib.util.spec_from_file_location("gen_cli_ref", GENERATOR)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    found: dict[str, argparse.ArgumentParser] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            found.update(action.choices)
    return found


def _nav_entries(nav) -> list[str]:
    """Every page path named in mkdocs.yml's nav, in order."""
    out: list[str] = []
    for item in nav:
        if isinstance(item, str):
            out.append(item)
        elif isinstance(item, dict):
            for value in item.values():
                out.extend(_nav_entries(value) if isinstance(value, list) else [value])
    return out


def _mkdocs_config() -> dict:
    return yaml.safe_load((REPO / "mkdocs.yml").read_text())


def test_cli_reference_has_one_page_per_subcommand():
    parser = build_parser()
    commands = _subcommands(parser)
    assert len(commands) >= 10, sorted(commands)
    pages = _generator().pages(parser)
    cli = {path.split("/")[-1] for path in pages}
    assert cli - {"index.md", "SUMMARY.md"} == {f"{name}.md" for name in commands}
    index, summary = pages["reference/cli/index.md"], pages["reference/cli/SUMMARY.md"]
    for name, sub in commands.items():
        page = pages[f"reference/cli/{name}.md"]
        assert page.startswith(f"# physdyn {name}\n"), page[:80]
        assert "```text\nusage: physdyn " + name in page
        assert f"({name}.md)" in index and f"({name}.md)" in summary
        for nested in _subcommands(sub):  # `physdyn data info`: its own section of the parent's page
            assert f"\n## physdyn {name} {nested}\n" in page
            assert f"usage: physdyn {name} {nested}" in page


def test_cli_reference_does_not_depend_on_the_terminal(monkeypatch):
    gen = _generator()
    monkeypatch.setenv("COLUMNS", "200")
    wide = gen.pages()
    monkeypatch.setenv("COLUMNS", "50")
    assert gen.pages() == wide
    assert os.environ["COLUMNS"] == "50"  # restored after generating


def test_every_nav_page_exists():
    config = _mkdocs_config()
    generated = set(_generator().pages())
    entries = _nav_entries(config["nav"])
    assert "index.md" in entries and "reference/api.md" in entries and "config.md" in entries
    missing = []
    for entry in entries:
        if entry.endswith("/"):  # a generated section: literate-nav reads its SUMMARY.md
            if f"{entry}SUMMARY.md" not in generated:
                missing.append(entry)
        elif not (DOCS / entry).is_file() and entry not in generated:
            missing.append(entry)
    assert not missing, f"mkdocs.yml's nav names pages that do not exist: {missing}"
    assert len(entries) == len(set(entries)), "a page is listed twice in the nav"


def test_docs_extra_installs_every_plugin_the_site_uses():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    extra = " ".join(tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]["docs"])
    config = _mkdocs_config()
    assert config["theme"]["name"] == "material" and "mkdocs-material" in extra
    packages = {"gen-files": "mkdocs-gen-files", "literate-nav": "mkdocs-literate-nav", "mkdocstrings": "mkdocstrings"}
    for plugin in config["plugins"]:
        name = plugin if isinstance(plugin, str) else next(iter(plugin))
        if name != "search":  # built into mkdocs
            assert packages[name] in extra, name


@pytest.mark.slow  # the whole site: about 20 s on two cores
def test_site_builds_strict(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocs_gen_files")
    pytest.importorskip("mkdocstrings")
    if shutil.which("mkdocs") is None and importlib.util.find_spec("mkdocs") is None:
        pytest.skip("mkdocs is not installed (pip install -e '.[docs]')")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1", DISABLE_MKDOCS_2_WARNING="true")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=REPO, capture_output=True, text=True, env=env, timeout=600)
    warnings = [line for line in proc.stderr.splitlines() if line.startswith(("WARNING", "ERROR"))]
    assert proc.returncode == 0, "\n".join(warnings) or proc.stderr[-3000:]
    site = tmp_path / "site"
    assert (site / "reference" / "cli" / "data" / "index.html").is_file()
    api = (site / "reference" / "api" / "index.html").read_text()
    for name in ("load_predictor", "Predictor", "Registry", "PhysdynError"):
        assert name in api
    assert "ExperimentConfig" in (site / "config" / "index.html").read_text()
