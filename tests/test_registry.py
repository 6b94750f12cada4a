"""The component registry: typed configs, duplicate names, entry-point plugins and broken plugins.

Every test uses a fresh ``Registry`` on its own entry-point group, so the global ENCODERS etc. are left
alone. Plugins are simulated without installing anything: a ``<name>-<version>.dist-info`` folder with an
``entry_points.txt`` on a temporary sys.path entry is all ``importlib.metadata`` needs to see a distribution.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
import types
import uuid
import warnings
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint
from pathlib import Path
from typing import List

import pytest
from omegaconf import OmegaConf

import physdyn.registry
from physdyn.errors import ConfigError
from physdyn.registry import ALL_REGISTRIES, Registry

HOOK = "_physdyn_test_registry_hook"  # the module a simulated plugin imports to reach the test's registry


# --------------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------------
def write_distribution(
    root: Path, dist: str, entry_points: dict[str, dict[str, str]], modules: dict[str, str]
) -> None:
    """A fake installed distribution under ``root``: metadata, entry points and top-level modules.

    entry_points: {group: {name: "module" or "module:attr"}}; modules: {module name: source}.
    """
    info = root / f"{dist.replace('-', '_')}-0.1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 0.1.0\n")
    lines = []
    for group, eps in entry_points.items():
        lines.append(f"[{group}]")
        lines += [f"{name} = {value}" for name, value in eps.items()]
        lines.append("")
    (info / "entry_points.txt").write_text("\n".join(lines))
    for module, source in modules.items():
        (root / f"{module}.py").write_text(textwrap.dedent(source))


@pytest.fixture
def uid() -> str:
    """A suffix that keeps module and group names of one test apart from every other's."""
    return uuid.uuid4().hex[:8]


@pytest.fixture
def fresh(monkeypatch, uid):
    """A fresh registry on its own entry-point group, reachable by simulated plugins as ``HOOK.REGISTRY``."""
    registry: Registry = Registry("widget", f"physdyn_test.widgets_{uid}")
    hook = types.ModuleType(HOOK)
    hook.REGISTRY = registry
    monkeypatch.setitem(sys.modules, HOOK, hook)
    before = set(sys.modules)
    yield registry
    for name in set(sys.modules) - before:  # forget the simulated plugins' modules
        if uid in name:
            del sys.modules[name]


def plugin_source(name: str, cls: str, doc: str = "A widget from a plugin.") -> str:
    return f'''
        from {HOOK} import REGISTRY

        @REGISTRY.register("{name}")
        class {cls}:
            """{doc}"""
    '''


# --------------------------------------------------------------------------------------------------
# Register, get, build
# --------------------------------------------------------------------------------------------------
def make_box(registry: Registry):
    @registry.register("box")
    class Box:
        """A component with a typed config."""

        @dataclass
        class Config:
            size: float = 1.0
            count: int = 2
            tags: List[str] = field(default_factory=list)

        def __init__(self, config: "Box.Config", colour: str = "red"):
            self.config = config
            self.colour = colour

    return Box


def test_register_get_and_build_with_a_typed_config(fresh):
    Box = make_box(fresh)
    assert fresh.get("box") is Box
    assert Box.registered_name == "box"
    assert fresh.names() == ["box"]

    box = fresh.build("box", {"size": 2, "tags": ["a"]}, colour="blue")
    assert isinstance(box, Box)
    assert isinstance(box.config, Box.Config)  # a real dataclass, not an OmegaConf node
    assert box.config == Box.Config(size=2.0, count=2, tags=["a"])
    assert box.colour == "blue"  # runtime kwargs pass through

    assert fresh.build("box").config == Box.Config()  # no params: the defaults
    from_yaml = fresh.resolve_config("box", OmegaConf.create({"count": "3"}))  # strings from YAML/CLI
    assert from_yaml == Box.Config(count=3)


@pytest.mark.parametrize(
    "params, key",
    [
        ({"sise": 2.0}, "model.box.sise"),  # unknown key
        ({"count": "lots"}, "model.box.count"),  # wrong type
        ({"size": [1.0]}, "model.box.size"),  # a list for a number
        ({"tags": "a"}, "model.box.tags"),  # a string for a list
    ],
)
def test_bad_params_raise_a_one_line_config_error_naming_the_key(fresh, params, key):
    make_box(fresh)
    with pytest.raises(ConfigError) as info:
        fresh.build("box", params, where="model.box")
    message = str(info.value)
    assert f"'{key}'" in message
    assert "\n" not in message


def test_unknown_key_suggests_the_right_one(fresh):
    make_box(fresh)
    with pytest.raises(ConfigError, match="sise.*Did you mean.*size"):
        fresh.resolve_config("box", {"sise": 2.0})


def test_component_without_config_takes_no_parameters(fresh):
    @fresh.register("plain")
    class Plain:
        def __init__(self, scale: int = 1):
            self.scale = scale

    assert fresh.build("plain", scale=3).scale == 3
    assert fresh.resolve_config("plain") is None
    with pytest.raises(ConfigError, match="takes no parameters"):
        fresh.build("plain", {"scale": 3}, where="model.plain")


def test_unknown_name_lists_the_registered_ones(fresh):
    make_box(fresh)
    with pytest.raises(ConfigError, match=r"unknown widget 'boxx'; registered: box"):
        fresh.get("boxx")
    empty: Registry = Registry("gadget", f"physdyn_test.empty_{uuid.uuid4().hex}")
    with pytest.raises(ConfigError, match="registered: none"):
        empty.build("anything")


def test_duplicate_names_are_rejected(fresh):
    Box = make_box(fresh)

    class Other:
        pass

    with pytest.raises(ValueError, match="'box' is registered twice"):
        fresh.register("box")(Other)
    assert fresh.get("box") is Box  # the first one stays
    assert fresh.register("box")(Box) is Box  # the same class again (a module re-imported) is fine


def test_builtin_modules_are_imported_on_first_lookup(fresh, tmp_path, monkeypatch, uid):
    module = f"builtin_widgets_{uid}"
    (tmp_path / f"{module}.py").write_text(textwrap.dedent(plugin_source("cog", "Cog", "A built-in.")))
    monkeypatch.syspath_prepend(str(tmp_path))
    registry: Registry = Registry("widget", fresh.group, builtin_modules=(module,))
    sys.modules[HOOK].REGISTRY = registry

    assert module not in sys.modules  # lazy: nothing imported before the first lookup
    (entry,) = registry.entries()
    assert (entry.name, entry.source) == ("cog", "built-in")
    assert entry.config_class is None


# --------------------------------------------------------------------------------------------------
# Entry-point discovery
# --------------------------------------------------------------------------------------------------
def test_plugins_are_discovered_through_entry_points(fresh, tmp_path, monkeypatch, uid):
    write_distribution(
        tmp_path,
        "fake-widgets",
        {fresh.group: {"sprocket": f"sprockets_{uid}", "gear": f"gears_{uid}:Gear"}},
        {
            f"sprockets_{uid}": plugin_source("sprocket", "Sprocket"),  # a module whose import registers
            f"gears_{uid}": plugin_source("gear", "Gear"),  # an object: importing its module registers
        },
    )
    monkeypatch.syspath_prepend(str(tmp_path))

    @fresh.register("cog")
    class Cog:
        """Registered directly, as a built-in is."""

    entries = {e.name: e for e in fresh.entries()}
    assert sorted(entries) == ["cog", "gear", "sprocket"]
    assert entries["sprocket"].source == "plugin fake-widgets"
    assert entries["gear"].source == "plugin fake-widgets"
    assert entries["gear"].cls.__module__ == f"gears_{uid}"
    assert entries["cog"].source == "built-in"


def test_a_broken_plugin_warns_with_its_name_and_is_skipped(fresh, tmp_path, monkeypatch, uid):
    write_distribution(
        tmp_path,
        "fine-widgets",
        {fresh.group: {"sprocket": f"sprockets_{uid}"}},
        {f"sprockets_{uid}": plugin_source("sprocket", "Sprocket")},
    )
    write_distribution(
        tmp_path,
        "broken-widgets",
        {fresh.group: {"cracked": f"cracked_{uid}", "missing": f"not_there_{uid}"}},
        {f"cracked_{uid}": "raise RuntimeError('this plugin is broken on purpose')\n"},
    )
    monkeypatch.syspath_prepend(str(tmp_path))

    with pytest.warns(UserWarning) as record:
        names = fresh.names()
    messages = [str(w.message) for w in record]
    assert names == ["sprocket"]  # the good plugin still loads
    cracked = [m for m in messages if "'cracked'" in m]
    assert cracked and "broken-widgets" in cracked[0] and "RuntimeError" in cracked[0]
    assert "broken on purpose" in cracked[0]
    missing = [m for m in messages if "'missing'" in m]
    assert missing and "ModuleNotFoundError" in missing[0]
    # Discovery runs once: a later lookup neither re-imports nor warns again.
    with warnings.catch_warnings(record=True) as again:
        warnings.simplefilter("always")
        assert fresh.names() == ["sprocket"]
        with pytest.raises(ConfigError, match="unknown widget 'cracked'"):
            fresh.get("cracked")
    assert not again, [str(w.message) for w in again]


def test_entry_point_without_a_distribution_is_named_by_its_value(fresh, monkeypatch, uid):
    # Entry points handed over by other means (here a monkeypatched lookup) may carry no distribution.
    source = plugin_source("late", "Late")

    class LateLoader(EntryPoint):
        def load(self):  # what loading a module does: run it, which registers
            module = types.ModuleType(f"late_{uid}")
            exec(textwrap.dedent(source), module.__dict__)
            return module

    monkeypatch.setattr(
        physdyn.registry, "entry_points", lambda group: [LateLoader("late", f"late_{uid}", group)]
    )
    (entry,) = fresh.entries()
    assert entry.source == f"plugin late_{uid}"


def test_the_documented_entry_point_groups_are_the_registries_and_the_example_plugins():
    # What a plugin author reads (the plugin guide's table of kinds) and copies (the example plugin's
    # pyproject) must name the groups the registries actually scan.
    import re
    import tomllib

    from tests.conftest import REPO

    groups = {registry.group for registry in ALL_REGISTRIES.values()}
    guide = (REPO / "docs" / "plugins.md").read_text()
    table = guide.split("| entry-point group |", 1)[1].split("\n\n", 1)[0]
    documented = {re.findall(r"`(physdyn\.[a-z_]+)`", row)[-1] for row in table.splitlines()[2:]}
    assert documented == groups
    plugin = tomllib.loads((REPO / "plugins" / "physdyn-dgcnn" / "pyproject.toml").read_text())
    assert set(plugin["project"]["entry-points"]) <= groups and "physdyn.encoders" in plugin["project"]["entry-points"]


# --------------------------------------------------------------------------------------------------
# The command line with a broken plugin installed
# --------------------------------------------------------------------------------------------------
@pytest.fixture
def broken_plugin_env(tmp_path, uid) -> dict[str, str]:
    """Environment for a subprocess that sees a broken plugin in every physdyn group."""
    site = tmp_path / "site"
    site.mkdir()
    module = f"broken_physdyn_plugin_{uid}"
    groups = [registry.group for registry in ALL_REGISTRIES.values()]
    write_distribution(
        site,
        "physdyn-broken-example",
        {group: {"shattered": module} for group in groups},
        {module: "raise ImportError('this plugin is broken on purpose')\n"},
    )
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(site), env.get("PYTHONPATH", "")) if p)
    return env


def run_cli(args: list[str], env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "physdyn.cli", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_help_works_with_a_broken_plugin(broken_plugin_env, tmp_path):
    proc = run_cli(["--help"], broken_plugin_env, tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "components" in proc.stdout
    assert "Traceback" not in proc.stderr


def test_components_warns_about_a_broken_plugin_and_goes_on(broken_plugin_env, tmp_path):
    proc = run_cli(["components"], broken_plugin_env, tmp_path)
    if proc.returncode != 0 and "No module named 'physdyn." in proc.stderr:
        pytest.skip(f"a physdyn built-in package is not written yet: {proc.stderr.strip().splitlines()[-1]}")
    assert proc.returncode == 0, proc.stderr
    assert "'shattered'" in proc.stderr and "physdyn-broken-example" in proc.stderr
    assert "broken on purpose" in proc.stderr
    assert "shattered" not in proc.stdout  # skipped, not listed
    assert "encoders (entry-point group physdyn.encoders)" in proc.stdout


def test_components_options_lists_each_components_settings_and_defaults(capsys):
    from physdyn.cli import main
    from physdyn.models.predictors.lstm import LSTMPredictor

    assert main(["components", "--options"]) == 0
    out = capsys.readouterr().out
    lstm = out[out.index("  lstm "):out.index("  mlp ")]
    lines = [line.strip() for line in lstm.splitlines()[1:]]
    for f in dataclasses.fields(LSTMPredictor.Config):  # every setting, on its own line with its type and default
        assert f"{f.name}: {f.type} = {f.default!r}" in lines
    head = out[out.index("  no_topple "):]
    assert "(no settings)" in head.splitlines()[1]
    assert main(["components"]) == 0 and "forget_bias" not in capsys.readouterr().out  # only when asked
