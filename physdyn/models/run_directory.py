"""Run directories of `physdyn fit` and `physdyn pretrain`: where a run lives, never reusing one silently,
and what a resumed run may change."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from physdyn.config import ExperimentConfig, config_from_dict, to_dict
from physdyn.errors import PhysdynError
from physdyn.files import write_text_atomic

FINISHED = "finished.json"


def run_directory(cfg: ExperimentConfig | Any) -> Path:
    return Path(cfg.out_dir) if cfg.out_dir else Path("runs") / cfg.name


def is_global_zero_process() -> bool:
    """False in the extra processes of a multi-process run (Lightning/torchrun set these variables)."""
    return all(int(os.environ.get(k, "0") or 0) == 0 for k in ("LOCAL_RANK", "NODE_RANK", "RANK"))


RUN_ENTRIES = {"config.yaml", "best.ckpt", "last.ckpt", FINISHED, "csv", "tensorboard", "encoder.pt", "lightning_logs"}


def looks_like_a_run(out_dir: Path) -> bool:
    """Whether a folder was written by `physdyn fit`/`pretrain`: its config.yaml and nothing but run
    artefacts (benchmark scripts may add their own ``*.json`` beside them)."""
    names = {p.name for p in out_dir.iterdir()}
    return "config.yaml" in names and all(n in RUN_ENTRIES or n.endswith((".json", ".ckpt", ".pt")) for n in names)


def prepare_run_directory(out_dir: Path, resume: bool, overwrite: bool, what: str = "physdyn fit",
                          resumable: bool = True) -> None:
    """Refuse to reuse a run directory unless asked; only the first process of a run touches it.
    ``what`` (the command) and ``resumable`` (whether it has --resume) shape the advice in the errors."""
    if not is_global_zero_process():
        return
    if out_dir.exists() and any(out_dir.iterdir()):
        if overwrite:
            if not looks_like_a_run(out_dir):  # --overwrite replaces a run, never a folder of the user's
                example = sorted(p.name for p in out_dir.iterdir())[0]
                raise PhysdynError(
                    f"{out_dir} holds files that are not a physdyn run (e.g. {example}); --overwrite only replaces "
                    f"run directories: choose another name=... or out_dir=..."
                )
            shutil.rmtree(out_dir)
        elif not resume:
            if (out_dir / FINISHED).exists():
                raise PhysdynError(
                    f"{out_dir} holds a finished run; pass --overwrite to replace it, or choose another "
                    f"name=... or out_dir=..."
                )
            if not resumable:
                raise PhysdynError(f"{out_dir} holds an earlier {what} run; pass --overwrite to start over, or "
                                   f"choose another out_dir=...")
            raise PhysdynError(
                f"{out_dir} holds an interrupted run; pass --resume to continue it or --overwrite to start over"
            )
    out_dir.mkdir(parents=True, exist_ok=True)


# Keys a resumed run may change: how long it trains and how it reports, not what it learns.
RESUMABLE_KEYS = ("trainer.max_steps", "trainer.max_epochs", "trainer.val_check_interval", "progress_bar", "cpu_threads",
                  "data.num_workers", "ckpt_path", "out_dir")


def _flatten(tree: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(tree, dict):
        out: dict[str, Any] = {}
        for key, value in tree.items():
            out.update(_flatten(value, f"{prefix}{key}."))
        return out
    return {prefix[:-1]: tree}


def check_resumed_config(cfg: Any, saved_yaml: Path) -> None:
    """Refuse to resume a run with a config that changes what it learns; names the keys that differ."""
    if not saved_yaml.is_file():
        return
    # Read through the schema: a key added to physdyn since the run started takes its default there too,
    # so an unchanged config of an older run still resumes.
    saved = _flatten(to_dict(config_from_dict(type(cfg), OmegaConf.to_container(OmegaConf.load(saved_yaml)), str(saved_yaml))))
    now = _flatten(to_dict(cfg))
    changed = sorted(k for k in set(saved) | set(now)
                     if saved.get(k) != now.get(k) and not k.startswith(RESUMABLE_KEYS))
    if changed:
        shown = ", ".join(f"{k} ({saved.get(k)!r} -> {now.get(k)!r})" for k in changed[:4])
        more = f" and {len(changed) - 4} more" if len(changed) > 4 else ""
        raise PhysdynError(
            f"--resume: the config differs from {saved_yaml} in {shown}{more}; resume with the run's own config "
            f"(only {', '.join(RESUMABLE_KEYS[:3])} and logging may change) or start a new run (name=...)"
        )


def save_config_yaml(cfg: Any, path: Path) -> None:
    if is_global_zero_process():
        write_text_atomic(path, OmegaConf.to_yaml(OmegaConf.create(to_dict(cfg))))
