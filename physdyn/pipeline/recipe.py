"""A predictor preset's recipe: how each of its stages is trained, as one ordered list of physdyn commands.

A preset (configs/predictor/NAME.yaml) may carry ``recipe:``, a list of steps::

    recipe:
      - {step: motion, command: fit, config: contact_prior, set: {model.contact_substeps: 8}}
      - {step: topple, command: fit-topple, options: {pointnet: true, num_points: 64}}
      - {step: model, command: export, set: {name: fast}}

``physdyn recipe NAME --data STORE --out DIR`` runs them in order. Each step reads the checkpoint of the step
before it (or the one its ``from`` names) and writes ``DIR/<step>.ckpt``; `fit` steps train in ``DIR/<step>/``.
Overrides ``STEP.KEY=VALUE`` change one step's option (``topple.steps=300``) or, for `fit` and `export`, one of
its config settings (``motion.trainer.max_steps=100``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from physdyn.errors import ConfigError

COMMANDS = ("fit", "fit-topple", "fit-outcome", "export")
STEP_KEYS = {"step", "command", "config", "set", "options", "from", "linear_from"}


@dataclass
class RecipeStep:
    """One command of a recipe. ``config``: the experiment preset a `fit` step trains; ``set``: config settings
    (`fit`: overrides; `export`: inference settings); ``options``: the command's flags by name (``num_points: 64``
    is ``--num-points 64``, ``pointnet: true`` is ``--pointnet``); ``source``/``linear_from``: earlier steps whose
    checkpoints this one reads (default: the step before)."""

    name: str
    command: str
    config: str | None = None
    settings: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)
    source: str | None = None
    linear_from: str | None = None


def read_recipe(entries: Any, where: str) -> list[RecipeStep]:
    """The steps of a preset's ``recipe`` list; a one-line ``ConfigError`` naming the step and key otherwise."""
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{where}: 'recipe' is a list of steps, each a mapping with step and command")
    steps: list[RecipeStep] = []
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict) or "step" not in entry or "command" not in entry:
            raise ConfigError(f"{where}: recipe step {i + 1} needs 'step' (its name) and 'command' ({', '.join(COMMANDS)})")
        unknown = sorted(set(entry) - STEP_KEYS)
        if unknown:
            raise ConfigError(f"{where}: recipe step '{entry['step']}' has unknown key '{unknown[0]}'; "
                              f"a step has {', '.join(sorted(STEP_KEYS))}")
        if entry["command"] not in COMMANDS:
            raise ConfigError(f"{where}: recipe step '{entry['step']}': command '{entry['command']}' is not one of "
                              f"{', '.join(COMMANDS)}")
        known = {s.name for s in steps}
        for key in ("from", "linear_from"):
            if entry.get(key) is not None and entry[key] not in known:
                raise ConfigError(f"{where}: recipe step '{entry['step']}': {key} '{entry[key]}' names no earlier step")
        if entry["command"] == "fit" and not entry.get("config"):
            raise ConfigError(f"{where}: recipe step '{entry['step']}': a fit step names its experiment as 'config'")
        steps.append(RecipeStep(str(entry["step"]), entry["command"], entry.get("config"), dict(entry.get("set") or {}),
                                dict(entry.get("options") or {}), entry.get("from"), entry.get("linear_from")))
    if steps[0].command != "fit":
        raise ConfigError(f"{where}: a recipe starts with a fit step: the later steps read its checkpoint")
    return steps


def with_overrides(steps: list[RecipeStep], overrides: list[str]) -> list[RecipeStep]:
    """``steps`` with ``STEP.KEY=VALUE`` overrides applied (values parsed as YAML: ``300``, ``[32, 64]``,
    ``true``): a `fit` or `export` step's KEY is a config setting, another's an option."""
    import yaml

    by_name = {s.name: s for s in steps}
    for text in overrides:
        key, sep, value = text.partition("=")
        name, dot, setting = key.partition(".")
        if not sep or not dot or not setting:
            raise ConfigError(f"override '{text}': expected STEP.KEY=VALUE, e.g. topple.steps=300")
        if name not in by_name:
            raise ConfigError(f"override '{text}': no step '{name}' in this recipe; its steps: {', '.join(by_name)}")
        step = by_name[name]
        target = step.settings if step.command in ("fit", "export") else step.options
        target[setting] = yaml.safe_load(value)
    return steps


def outputs(steps: list[RecipeStep], out_dir: Path) -> dict[str, Path]:
    """The checkpoint each step leaves: ``best.ckpt`` of a `fit` step's run folder, else ``<step>.ckpt``."""
    return {s.name: out_dir / s.name / "best.ckpt" if s.command == "fit" else out_dir / f"{s.name}.ckpt" for s in steps}


def command_line(steps: list[RecipeStep], index: int, stores: list[str], out_dir: Path) -> list[str]:
    """The `physdyn` arguments of step ``index``: its inputs are earlier steps' outputs under ``out_dir``; `fit`
    trains on the first of ``stores``, `fit-topple` and `fit-outcome` on all of them."""
    step, made = steps[index], outputs(steps, out_dir)
    if step.command == "fit":
        settings = {"data.store": stores[0], "out_dir": str(out_dir / step.name), **step.settings}
        return ["fit", "--config", str(step.config), *(f"{k}={_value(v)}" for k, v in settings.items())]
    source = str(made[step.source or steps[index - 1].name])
    if step.command == "export":
        raise ConfigError(f"recipe step '{step.name}' is an export: run it with export_arguments")
    argv = [step.command, "--checkpoint", source, "--out", str(made[step.name]), "--overwrite"]
    for store in stores:
        argv += ["--data", store]
    for key, value in step.options.items():
        flag = "--" + key.replace("_", "-")
        if value is True:
            argv.append(flag)
        elif value not in (False, None):
            argv += [flag, *map(str, value if isinstance(value, list) else [value])]
    return argv


def export_arguments(steps: list[RecipeStep], index: int, out_dir: Path) -> dict[str, Any]:
    """The arguments of ``physdyn.models.export.export_checkpoint`` for export step ``index``."""
    step, made = steps[index], outputs(steps, out_dir)
    return {"src": made[step.source or steps[index - 1].name], "dst": made[step.name], "overwrite": True,
            "settings": [f"{k}={_value(v)}" for k, v in step.settings.items()],
            "linear_from": made[step.linear_from] if step.linear_from else None}


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return "[" + ",".join(map(str, value)) + "]"
    return str(value)
