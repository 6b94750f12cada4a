"""The paper's experiments as data: the scales, every run of the suite, the experiments that read them,
and where each run lives under the output folder.

``build_suite()`` lists small ``RunSpec``s — datasets, encoder pretraining, trainings and evaluations — and
``EXPERIMENTS`` names the evaluations each experiment reports. A scale (``configs/reproduce/{tiny,cpu,paper}.yaml``,
schema ``ScaleConfig``) only says how big: overrides of the data presets and which training preset (with
overrides) to use. ``runner.py`` executes the runs; ``results_page.py`` writes the page from what finished.

Under ``OUT`` a run lives in ``OUT/<kind>/<name>/`` (its ``RunSpec.name``)::

    OUT/reproduce.json                     the scale and every invocation (command, date, hardware)
    OUT/data/<name>/store.zarr             datasets: a complete store is reused, an incomplete one resumed
    OUT/pretrain/<name>/                   encoder.pt, finished.json
    OUT/train/<name>/                      a `physdyn fit` run: config.yaml, best/last.ckpt, finished.json
    OUT/eval/<name>/                       metrics.json, report.md, plots (written whole or not at all)
    OUT/<kind>/<name>/run.json             wall time of the invocation that finished the run
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Dict, List, Sequence

from physdyn.config import PRESETS, DataConfig, load_config
from physdyn.errors import ConfigError

CONFIGS = PRESETS  # the shipped presets: a plain `pip install` reproduces too
SCALES_DIR = CONFIGS / "reproduce"
SCALES = ("tiny", "cpu", "paper")
CATEGORIES = ("primitives", "bottles", "mugs", "trashcans", "speakers")
RUN_FILE = "run.json"
MANIFEST = "reproduce.json"
FRICTION_WARM_STARTS = (0, 1, 3, 5)


# --------------------------------------------------------------------------------------------------
# Scales
# --------------------------------------------------------------------------------------------------
@dataclass
class ScaleConfig:
    """How big one scale is. Preset paths are relative to the scale's YAML file."""

    name: str = ""
    description: str = ""
    # dataset name (combined, speakers, speakers_30hz, friction) -> overrides of configs/data/<name>.yaml
    data: Dict[str, List[str]] = field(default_factory=dict)
    train_preset: str = "../experiment/quickstart.yaml"
    train_overrides: List[str] = field(default_factory=list)
    mlp_preset: str = "../experiment/mlp_baseline.yaml"
    mlp_overrides: List[str] = field(default_factory=list)
    pretrain_preset: str = "../experiment/pretrain.yaml"
    pretrain_overrides: List[str] = field(default_factory=list)
    workers: int = 2  # simulation worker processes
    eval_batch_size: int = 256


def load_scale(scale: str | Path) -> tuple[ScaleConfig, Path]:
    """A scale by name (tiny, cpu, paper) or YAML path; returns the config and its file."""
    path = Path(scale)
    if str(scale) in SCALES:
        path = SCALES_DIR / f"{scale}.yaml"
    elif not path.suffix:
        raise ConfigError(f"unknown scale '{scale}'; use one of {', '.join(SCALES)} or a YAML file")
    cfg = load_config(ScaleConfig, path)
    cfg.name = cfg.name or path.stem
    for key in DATASETS:
        cfg.data.setdefault(key, [])
    unknown = set(cfg.data) - set(DATASETS)
    if unknown:
        raise ConfigError(f"{path}: unknown dataset '{sorted(unknown)[0]}' under data; known: {', '.join(DATASETS)}")
    return cfg, path


# --------------------------------------------------------------------------------------------------
# The suite as data
# --------------------------------------------------------------------------------------------------
# Dataset name -> data preset. Single, Combined, Leave-out and Topple share the combined store (the same
# test shapes for every training procedure); the Speakers experiments have their own stores, whose
# 80/20 shape splits agree with each other (the split depends on the seed and the shapes only).
DATASETS = {
    "combined": "data/combined.yaml",
    "speakers": "data/speakers.yaml",
    "speakers_30hz": "data/speakers_30hz.yaml",
    "friction": "data/friction.yaml",
}
BASELINES = ("stay_put", "coulomb_slide")


@dataclass(frozen=True)
class RunSpec:
    """One unit of work. kind: data | pretrain | train | eval. ``needs``: runs it reads.

    train: ``store`` (a data run), ``model`` ("lstm" or "mlp": the scale's preset), ``overrides``,
    ``encoder_from`` (a pretrain run). eval: ``model`` (a train run), ``store``, ``categories``,
    ``warm_start``, ``baselines``.
    """

    name: str
    kind: str
    store: str = ""
    model: str = ""
    overrides: tuple[str, ...] = ()
    encoder_from: str = ""
    categories: tuple[str, ...] = ()
    warm_start: int = 0
    baselines: tuple[str, ...] = BASELINES
    needs: tuple[str, ...] = ()

    @property
    def short(self) -> str:
        return self.name.split("/", 1)[1]


def _train(name: str, store: str, model: str = "lstm", overrides: Sequence[str] = (), encoder_from: str = "") -> RunSpec:
    needs = (f"data/{store}",) + ((f"pretrain/{encoder_from}",) if encoder_from else ())
    return RunSpec(f"train/{name}", "train", store=store, model=model, overrides=tuple(overrides),
                   encoder_from=encoder_from, needs=needs)


def _eval(name: str, model: str, store: str, categories: Sequence[str] = (), warm_start: int = 0,
          baselines: Sequence[str] = BASELINES) -> RunSpec:
    return RunSpec(f"eval/{name}", "eval", store=store, model=model, categories=tuple(categories),
                   warm_start=warm_start, baselines=tuple(baselines), needs=(f"train/{model}", f"data/{store}"))


def build_suite(categories: Sequence[str] = CATEGORIES) -> list[RunSpec]:
    """Every run of the suite, each after the runs it needs."""
    runs = [RunSpec(f"data/{name}", "data") for name in DATASETS]
    runs.append(RunSpec("pretrain/encoder", "pretrain"))
    for c in categories:  # Single: train and test on one category
        runs.append(_train(f"single-{c}", "combined", overrides=[f"data.categories=[{c}]"]))
    runs.append(_train("combined", "combined"))
    for c in categories:  # Leave-out: train on the other categories
        runs.append(_train(f"leaveout-{c}", "combined", overrides=[f"data.exclude_categories=[{c}]"]))
    runs.append(_train("speakers-lstm", "speakers"))
    runs.append(_train("speakers-mlp", "speakers", model="mlp"))
    runs.append(_train("speakers-30hz", "speakers_30hz", overrides=["data.window=30"]))  # 1 s windows at 30 Hz
    runs.append(_train("friction", "friction"))
    runs.append(_train("speakers-pretrained", "speakers", encoder_from="encoder"))
    for c in categories:
        runs.append(_eval(f"single-{c}", f"single-{c}", "combined", [c]))
        runs.append(_eval(f"combined-{c}", "combined", "combined", [c]))
        runs.append(_eval(f"leaveout-{c}", f"leaveout-{c}", "combined", [c]))
    runs.append(_eval("speakers-lstm", "speakers-lstm", "speakers"))
    runs.append(_eval("speakers-mlp", "speakers-mlp", "speakers", baselines=()))
    runs.append(_eval("speakers-30hz", "speakers-30hz", "speakers_30hz"))
    for k in FRICTION_WARM_STARTS:
        runs.append(_eval(f"friction-warm{k}", "friction", "friction", warm_start=k, baselines=BASELINES if k == 0 else ()))
    runs.append(_eval("speakers-pretrained", "speakers-pretrained", "speakers", baselines=()))
    return runs


def _per_category(prefix: str) -> list[str]:
    return [f"eval/{prefix}-{c}" for c in CATEGORIES]


# Experiment name -> the evaluations its table reads (their trainings and datasets follow from ``needs``).
EXPERIMENTS: dict[str, list[str]] = {
    "single": _per_category("single"),
    "combined": _per_category("combined"),
    "leave-out": _per_category("leaveout"),
    "lstm-vs-mlp": ["eval/speakers-lstm", "eval/speakers-mlp"],
    "sampling-rate": ["eval/speakers-lstm", "eval/speakers-30hz"],
    "friction": [f"eval/friction-warm{k}" for k in FRICTION_WARM_STARTS] + ["eval/speakers-lstm"],
    "topple": _per_category("combined"),
    "pretraining": ["eval/speakers-lstm", "eval/speakers-pretrained"],
}
EXPERIMENT_HELP = {
    "single": "train and test on each category (5 models)",
    "combined": "train on all five categories, test per category",
    "leave-out": "for each category, train on the other four and test on it (5 models)",
    "lstm-vs-mlp": "the LSTM against the MLP baseline on Speakers",
    "sampling-rate": "15 Hz against 30 Hz Speakers (30-step windows), relative errors (supplement Table 1)",
    "friction": "random friction, warm starts 0/1/3/5, against constant friction (supplement Figure 1)",
    "topple": "topple classification accuracy per category (the Combined model; Single/Leave-out if run)",
    "pretraining": "encoder pretrained on shape classification vs trained from scratch (Speakers)",
}


def select_runs(runs: Sequence[RunSpec], only: Sequence[str] | None = None) -> list[RunSpec]:
    """The runs of the named experiments (all when ``only`` is empty) and everything they need, in order."""
    if not only:
        return list(runs)
    unknown = [e for e in only if e not in EXPERIMENTS]
    if unknown:
        raise ConfigError(f"--only: unknown experiment '{unknown[0]}'; choose from {', '.join(EXPERIMENTS)}")
    by_name = {r.name: r for r in runs}
    wanted: set[str] = set()
    stack = [name for e in only for name in EXPERIMENTS[e] if name in by_name]
    while stack:
        name = stack.pop()
        if name not in wanted:
            wanted.add(name)
            stack += list(by_name[name].needs)
    return [r for r in runs if r.name in wanted]


# --------------------------------------------------------------------------------------------------
# Where runs live, and their resolved configs
# --------------------------------------------------------------------------------------------------
def run_dir(out: Path, spec: RunSpec) -> Path:
    return Path(out) / spec.name


def store_path(out: Path, data_name: str) -> Path:
    return Path(out) / "data" / data_name / "store.zarr"


def utc_now() -> str:
    """The date written in run.json, reproduce.json and on the results page."""
    return datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def data_config(scale: ScaleConfig, name: str):
    return load_config(DataConfig, CONFIGS / DATASETS[name], list(scale.data.get(name, [])))


def experiment_config(scale: ScaleConfig, scale_file: Path, spec: RunSpec, out: Path):
    # models pulls in torch and Lightning; `physdyn reproduce --help` reads this module for its listing
    from physdyn.models.training import load_experiment_config

    preset, overrides = (scale.mlp_preset, scale.mlp_overrides) if spec.model == "mlp" else (scale.train_preset, scale.train_overrides)
    extra = [f"name={spec.short}", f"out_dir={run_dir(out, spec)}", f"data.store={store_path(out, spec.store)}"]
    if spec.encoder_from:
        extra.append(f"model.encoder_init={run_dir(out, RunSpec(f'pretrain/{spec.encoder_from}', 'pretrain')) / 'encoder.pt'}")
    return load_experiment_config(scale_file.parent / preset, list(overrides) + extra + list(spec.overrides))


def pretrain_config(scale: ScaleConfig, scale_file: Path, spec: RunSpec, out: Path):
    from physdyn.models.pretrain import load_pretrain_config  # torch and Lightning, as above

    extra = [f"name={spec.short}", f"out_dir={run_dir(out, spec)}"]
    return load_pretrain_config(scale_file.parent / scale.pretrain_preset, list(scale.pretrain_overrides) + extra)
