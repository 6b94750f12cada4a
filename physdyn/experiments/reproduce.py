"""`physdyn reproduce`: the paper's experiments as one resumable suite, and the results page built from it.

The suite is data: ``build_suite(scale)`` lists small ``RunSpec``s — datasets, encoder pretraining,
trainings and evaluations — and ``EXPERIMENTS`` names the evaluations each experiment reports. A scale
(``configs/reproduce/{tiny,cpu,paper}.yaml``, schema ``ScaleConfig``) only says how big: overrides of the
data presets and which training preset (with overrides) to use.

``run_suite`` executes the selected runs in dependency order under ``OUT``::

    OUT/reproduce.json                     the scale and every invocation (command, date, hardware)
    OUT/data/<name>/store.zarr             datasets: a complete store is reused, an incomplete one resumed
    OUT/pretrain/<name>/                   encoder.pt, finished.json
    OUT/train/<name>/                      a `physdyn fit` run: config.yaml, best/last.ckpt, finished.json
    OUT/eval/<name>/                       metrics.json, report.md, plots (written whole or not at all)
    OUT/<kind>/<name>/run.json             wall time of the invocation that finished the run

Finished work is skipped (finished.json, metrics.json, a complete store); a training with last.ckpt is
resumed. ``write_results`` turns whatever has finished into one Markdown page plus PNG plots; it never
tunes or selects anything on the test split, and says where a number disagrees with the paper.
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Dict, List, Sequence

import numpy as np

from physdyn.config import PRESETS, load_config, to_dict
from physdyn.errors import ConfigError, PhysdynError
from physdyn.eval.report import CURVE_MIN_SEQUENCES, UNITS, curve_end, draw_error_curves
from physdyn.eval.report import fmt_number as _num

CONFIGS = PRESETS  # the shipped presets: a plain `pip install` reproduces too
SCALES_DIR = CONFIGS / "reproduce"
SCALES = ("tiny", "cpu", "paper")
CATEGORIES = ("primitives", "bottles", "mugs", "trashcans", "speakers")
RUN_FILE = "run.json"
MANIFEST = "reproduce.json"

# The supplement's Table 1: relative roll-out errors on Speakers, non-toppling test sequences (percent).
PUBLISHED_TABLE1 = {
    "15 Hz": {"linear_velocity": 8.65, "angular_velocity": 7.59, "position": 8.10, "angle": 0.52},
    "30 Hz": {"linear_velocity": 4.92, "angular_velocity": 3.25, "position": 6.13, "angle": 0.43},
}
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
# Resolving a run's config
# --------------------------------------------------------------------------------------------------
def run_dir(out: Path, spec: RunSpec) -> Path:
    return Path(out) / spec.name


def store_path(out: Path, data_name: str) -> Path:
    return Path(out) / "data" / data_name / "store.zarr"


def data_config(scale: ScaleConfig, name: str):
    from physdyn.config import DataConfig

    return load_config(DataConfig, CONFIGS / DATASETS[name], list(scale.data.get(name, [])))


def experiment_config(scale: ScaleConfig, scale_file: Path, spec: RunSpec, out: Path):
    from physdyn.models.training import load_experiment_config

    preset, overrides = (scale.mlp_preset, scale.mlp_overrides) if spec.model == "mlp" else (scale.train_preset, scale.train_overrides)
    extra = [f"name={spec.short}", f"out_dir={run_dir(out, spec)}", f"data.store={store_path(out, spec.store)}"]
    if spec.encoder_from:
        extra.append(f"model.encoder_init={run_dir(out, RunSpec(f'pretrain/{spec.encoder_from}', 'pretrain')) / 'encoder.pt'}")
    return load_experiment_config(scale_file.parent / preset, list(overrides) + extra + list(spec.overrides))


def pretrain_config(scale: ScaleConfig, scale_file: Path, spec: RunSpec, out: Path):
    from physdyn.models.pretrain import load_pretrain_config

    extra = [f"name={spec.short}", f"out_dir={run_dir(out, spec)}"]
    return load_pretrain_config(scale_file.parent / scale.pretrain_preset, list(scale.pretrain_overrides) + extra)


# --------------------------------------------------------------------------------------------------
# The runner
# --------------------------------------------------------------------------------------------------
@dataclass
class RunOutcome:
    name: str
    status: str  # skipped | done | resumed
    wall_s: float


def is_finished(out: Path, spec: RunSpec) -> bool:
    d = run_dir(out, spec)
    if spec.kind == "data":
        return (d / RUN_FILE).is_file() and _store_complete(store_path(out, spec.short))
    if spec.kind in ("train", "pretrain"):
        return (d / "finished.json").is_file()
    return (d / "metrics.json").is_file()


def _store_complete(path: Path) -> bool:
    import zarr

    try:
        return bool(zarr.open_group(str(path), mode="r").attrs.get("complete"))
    except Exception:
        return False


def hardware() -> dict[str, Any]:
    import torch

    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    return {"platform": platform.platform(), "python": platform.python_version(), "cpu_count": os.cpu_count(),
            "torch": torch.__version__, "gpu": gpu}


def _now() -> str:
    return datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def _manifest(out: Path, scale: ScaleConfig, scale_file: Path, command: str, only: Sequence[str] | None) -> None:
    path = Path(out) / MANIFEST
    data = json.loads(path.read_text()) if path.is_file() else {"scale": scale.name, "scale_file": str(scale_file), "invocations": []}
    if data["scale"] != scale.name:
        raise PhysdynError(f"{out} holds runs of scale '{data['scale']}', not '{scale.name}'; choose another --out "
                           f"or pass --scale {data['scale']}")
    data["invocations"].append({"command": command, "date": _now(), "only": list(only or []), "hardware": hardware()})
    Path(out).mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1))


def _record_runs_done(out: Path, done: int) -> None:
    """Note on the latest invocation how many runs it made: one that only skipped finished runs made none
    of the page's numbers, so the page neither credits it nor takes its hardware."""
    path = Path(out) / MANIFEST
    data = json.loads(path.read_text())
    data["invocations"][-1]["runs_done"] = done
    path.write_text(json.dumps(data, indent=1))


class SuiteRunner:
    """Executes RunSpecs under ``out``; stores are loaded once and shared by the runs that read them."""

    def __init__(self, scale: ScaleConfig, scale_file: Path, out: str | Path, workers: int | None = None,
                 log: Callable[[str], None] = print):
        self.scale, self.scale_file, self.out = scale, scale_file, Path(out)
        self.workers = workers if workers is not None else scale.workers
        self.log = log
        self._stores: dict[str, Any] = {}

    def store(self, name: str):
        from physdyn.data.store import load_store

        if name not in self._stores:
            self._stores[name] = load_store(str(store_path(self.out, name)))
        return self._stores[name]

    def run(self, specs: Sequence[RunSpec]) -> list[RunOutcome]:
        outcomes = []
        for i, spec in enumerate(specs, 1):
            if is_finished(self.out, spec):
                self.log(f"[{i}/{len(specs)}] skip {spec.name} (finished)")
                outcomes.append(RunOutcome(spec.name, "skipped", 0.0))
                continue
            self.log(f"[{i}/{len(specs)}] run {spec.name}")
            started = time.time()
            resumed = getattr(self, f"_run_{spec.kind}")(spec)
            wall = time.time() - started
            d = run_dir(self.out, spec)
            d.mkdir(parents=True, exist_ok=True)
            (d / RUN_FILE).write_text(json.dumps({"name": spec.name, "kind": spec.kind, "scale": self.scale.name,
                                                  "wall_s": wall, "resumed": resumed, "finished": _now()}, indent=1))
            status = "resumed" if resumed else "done"
            self.log(f"[{i}/{len(specs)}] {status} {spec.name} in {wall:.1f} s")
            outcomes.append(RunOutcome(spec.name, status, wall))
        return outcomes

    def _run_data(self, spec: RunSpec) -> bool:
        from physdyn.data.store import store_exists
        from physdyn.sim.generate import generate_dataset

        cfg = data_config(self.scale, spec.short)
        path = store_path(self.out, spec.short)
        path.parent.mkdir(parents=True, exist_ok=True)
        (path.parent / "config.yaml").write_text(_yaml(to_dict(cfg)))
        if _store_complete(path):
            return False
        resume = store_exists(str(path))
        generate_dataset(cfg, str(path), workers=self.workers, resume=resume, progress=False)
        self._stores.pop(spec.short, None)
        return resume

    def _run_pretrain(self, spec: RunSpec) -> bool:
        from physdyn.models.pretrain import pretrain

        cfg = pretrain_config(self.scale, self.scale_file, spec, self.out)
        d = run_dir(self.out, spec)
        started_before = d.exists() and any(d.iterdir())
        pretrain(cfg, overwrite=True)  # no mid-run checkpoint to continue from: an interrupted one starts over
        return started_before

    def _run_train(self, spec: RunSpec) -> bool:
        from physdyn.models.training import fit

        cfg = experiment_config(self.scale, self.scale_file, spec, self.out)
        d = run_dir(self.out, spec)
        resume = (d / "last.ckpt").is_file()
        fit(cfg, resume=resume, overwrite=not resume, store=self.store(spec.store))
        return resume

    def _run_eval(self, spec: RunSpec) -> bool:
        from physdyn.eval.baselines import load_checkpoint
        from physdyn.eval.evaluate import compare
        from physdyn.eval.report import write_report

        model = load_checkpoint(run_dir(self.out, RunSpec(f"train/{spec.model}", "train")) / "best.ckpt")
        model.eval()
        result = compare(model, self.store(spec.store), spec.baselines, split="test", warm_start=spec.warm_start,
                         categories=list(spec.categories) or None, batch_size=self.scale.eval_batch_size)
        result["spec"] = {"model": spec.model, "store": spec.store, "categories": list(spec.categories),
                          "warm_start": spec.warm_start, "baselines": list(spec.baselines)}
        d = run_dir(self.out, spec)
        tmp = d.with_name(d.name + ".partial")
        shutil.rmtree(tmp, ignore_errors=True)
        write_report(result, tmp, overwrite=True)
        if d.exists():
            shutil.rmtree(d)
        tmp.rename(d)  # metrics.json appears with the whole report or not at all
        return False


def _yaml(data: dict) -> str:
    from omegaconf import OmegaConf

    return OmegaConf.to_yaml(OmegaConf.create(data))


def run_suite(scale: str | Path, out: str | Path, only: Sequence[str] | None = None, workers: int | None = None,
              results: str | Path | None = None, command: str = "", log: Callable[[str], None] = print) -> list[RunOutcome]:
    """Run (or skip, or resume) the selected experiments at ``scale`` under ``out``; then write the results
    page to ``results`` when given. Returns one outcome per run."""
    cfg, path = load_scale(scale)
    specs = select_runs(build_suite(), only)
    _manifest(Path(out), cfg, path, command or f"run_suite({scale!r}, {str(out)!r}, only={list(only or [])})", only)
    outcomes = SuiteRunner(cfg, path, out, workers, log).run(specs)
    done = sum(o.status != "skipped" for o in outcomes)
    _record_runs_done(Path(out), done)
    log(f"reproduce: {done} run(s) done, {len(outcomes) - done} skipped (finished earlier), in {out}")
    if results is not None:
        write_results(out, results, command=command)
        log(f"reproduce: wrote {results}")
    return outcomes


# --------------------------------------------------------------------------------------------------
# The results page
# --------------------------------------------------------------------------------------------------
SHORT = {"linear_velocity": "v", "angular_velocity": "ω", "position": "p", "angle_deg": "|θ|", "angle": "|θ|"}
ERR_COLS = ("position", "angle_deg", "linear_velocity", "angular_velocity")
BASELINE_LABEL = {"stay_put": "stay put (baseline)", "coulomb_slide": "Coulomb sliding (baseline, true μ)"}
DIFFERENCES = [
    "Shapes are procedural families (primitives, bottles, mugs, trashcans, speakers) generated by physdyn, "
    "not the paper's ShapeNet models; category sizes follow the paper's simulation counts at the paper scale.",
    "Simulation is PyBullet (pybullet's Bullet build), not Bullet inside Unity; friction 0.5 x 0.5 gives an "
    "effective Coulomb μ = 0.25, a stable resting pose is drawn before each push, and the push is a force over "
    "one physics step (docs/simulation.md).",
    "Encoder pretraining uses the procedural families as classes, not ModelNet40 (unless the pretraining "
    "preset is pointed at a ModelNet40 folder); the paper's models all start from pretrained weights, here only "
    "the `pretraining` experiment's model does.",
    "The checkpoint with the lowest validation loss is evaluated, as in the paper; nothing is tuned on the test split.",
]


def _load_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


class _Results:
    """Reads the finished runs of an output folder."""

    def __init__(self, out: Path):
        self.out = out
        self._cache: dict[str, dict | None] = {}

    def metrics(self, name: str) -> dict | None:
        if name not in self._cache:
            self._cache[name] = _load_json(self.out / name / "metrics.json")
        return self._cache[name]

    def model(self, name: str) -> dict | None:
        m = self.metrics(name)
        return m["results"][m["model"]] if m else None

    def baseline(self, name: str, which: str) -> dict | None:
        m = self.metrics(name)
        return (m or {}).get("results", {}).get(which)


def _pct(x: Any) -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{100 * x:.2f} %"


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(r) + " |" for r in rows] + [""]


def _nt(result: dict) -> dict:
    return result["rollout"]["non_toppling"]


def _err_cells(result: dict | None) -> list[str]:
    if result is None:
        return ["not run"] + ["" for _ in ERR_COLS] + ["", ""]
    nt = _nt(result)
    return ([str(nt["count"])] + [_num(nt["rollout"][k]) for k in ERR_COLS]
            + [_num(nt["final_position_m"]["median"]), _num(nt["final_rotation_deg"]["median"])])


ERR_HEAD = ["n"] + [f"{SHORT[k]} ({UNITS[k]}/step)" for k in ERR_COLS] + ["final p, median (m)", "final rot., median (deg)"]


def _missing(names: Sequence[str], res: _Results) -> list[str]:
    return [n for n in names if res.metrics(n) is None]


def _headline(result: dict | None, key: str = "position") -> float:
    return float("nan") if result is None or _nt(result)["rollout"][key] is None else float(_nt(result)["rollout"][key])


def _lt(a: float, b: float) -> bool:
    return math.isfinite(a) and math.isfinite(b) and a < b


def _section_generalisation(res: _Results, plots: dict[str, str]) -> list[str]:
    lines = ["## Single, Combined and Leave-out (supplement Figure 6)", "",
             "Roll-out errors per step on the **non-toppling test sequences** of each category (mean over steps, then "
             "sequences); Single trains on the category alone, Combined on all five, Leave-out on the other four. "
             "The baselines are evaluated on the same sequences.", ""]
    rows, findings = [], []
    for c in CATEGORIES:
        single, comb, leave = (res.model(f"eval/{p}-{c}") for p in ("single", "combined", "leaveout"))
        base_src = next((n for n in (f"eval/combined-{c}", f"eval/single-{c}", f"eval/leaveout-{c}") if res.metrics(n)), None)
        for label, r in (("Single", single), ("Combined", comb), ("Leave-out", leave)):
            rows.append([c, label] + _err_cells(r))
        for b in BASELINES:
            rows.append([c, BASELINE_LABEL[b]] + _err_cells(res.baseline(base_src, b) if base_src else None))
        coul = _headline(res.baseline(base_src, "coulomb_slide")) if base_src else float("nan")
        behind = [f"{label} {_num(_headline(r))}" for label, r in (("Single", single), ("Combined", comb), ("Leave-out", leave))
                  if r is not None and math.isfinite(coul) and not _lt(_headline(r), coul)]
        if behind:
            findings.append(f"- {c}: position error not below Coulomb sliding's ({_num(coul)} m/step): {', '.join(behind)} "
                            "m/step. The paper's learned models track the true motion closely; a constant-μ sliding model "
                            "that is told the true friction is a strong baseline here.")
        s_pos, l_pos = _headline(single), _headline(leave)
        if math.isfinite(s_pos) and math.isfinite(l_pos) and l_pos <= s_pos:
            findings.append(f"- {c}: Leave-out ({_num(l_pos)} m/step) is not worse than Single ({_num(s_pos)} m/step) "
                            "on position, although the Leave-out model never saw this category.")
    lines += _table(["category", "trained as"] + ERR_HEAD, rows)
    if "generalisation" in plots:
        lines += [f"![Roll-out errors per category]({plots['generalisation']})", ""]
    lines += ["Where these numbers disagree with the paper:", ""] + (findings or ["- nothing flagged (or not run)."]) + [""]
    return lines


def _section_topple(res: _Results) -> list[str]:
    lines = ["## Topple classification per category", "",
             "A test sequence is predicted to topple when any step's probability is at least 0.5 (all test sequences, "
             "toppling and not). Accuracy (F1) of each training procedure; `share` is the toppling share of the test "
             "sequences.", ""]
    rows = []
    for c in CATEGORIES:
        row = [c]
        share = None
        for p in ("combined", "single", "leaveout"):
            r = res.model(f"eval/{p}-{c}")
            t = (r or {}).get("topple")
            row.append("not run" if r is None else ("no topple head" if not t else f"{_num(t['accuracy'], 3)} ({_num(t.get('f1'), 3)})"))
            if r is not None and share is None:
                n_all, n_t = r["rollout"]["all"]["count"], r["rollout"]["toppling"]["count"]
                share = n_t / n_all if n_all else float("nan")
        rows.append(row + [_pct(share)])
    return lines + _table(["category", "Combined acc. (F1)", "Single acc. (F1)", "Leave-out acc. (F1)", "share"], rows)


def _speakers_rows(res: _Results, entries: Sequence[tuple[str, str]], baseline_src: str | None) -> list[list[str]]:
    rows = []
    for label, name in entries:
        r = res.model(name)
        t = (r or {}).get("topple")
        rel = _nt(r)["relative"] if r else {}
        rows.append([label] + _err_cells(r) + [_pct(rel.get("position")), _num(t["accuracy"], 3) if t else "n/a"])
    for b in BASELINES:
        r = res.baseline(baseline_src, b) if baseline_src else None
        if r is not None:
            rows.append([BASELINE_LABEL[b]] + _err_cells(r) + [_pct(_nt(r)["relative"].get("position")), "n/a"])
    return rows


def _section_mlp(res: _Results, plots: dict[str, str]) -> list[str]:
    lines = ["## LSTM against the MLP baseline (Speakers)", "",
             "The paper's state predictor (LSTM) against the same model with a per-step MLP instead (supplement 4.4); "
             "non-toppling Speakers test sequences.", ""]
    lines += _table(["model"] + ERR_HEAD + ["rel. p", "topple acc."],
                    _speakers_rows(res, [("LSTM", "eval/speakers-lstm"), ("MLP", "eval/speakers-mlp")], "eval/speakers-lstm"))
    lstm, mlp = _headline(res.model("eval/speakers-lstm")), _headline(res.model("eval/speakers-mlp"))
    if math.isfinite(lstm) and math.isfinite(mlp):
        if mlp <= lstm:
            lines += [f"**This contradicts the paper**: the MLP's position error ({_num(mlp)} m/step) is not above the "
                      f"LSTM's ({_num(lstm)} m/step); the paper found the LSTM clearly better. The numbers stand as measured.", ""]
        else:
            lines += [f"As in the paper, the LSTM is better: position error {_num(lstm)} vs {_num(mlp)} m/step for the MLP.", ""]
    if "mlp" in plots:
        lines += [f"![LSTM vs MLP error over time]({plots['mlp']})", ""]
    return lines


def _section_rate(res: _Results, plots: dict[str, str]) -> list[str]:
    lines = ["## 15 Hz against 30 Hz (supplement Table 1)", "",
             "*Relative* roll-out errors on the non-toppling Speakers test sequences (sum of |error| over sum of |true "
             "change| per sequence, averaged over sequences), the 30 Hz model trained on 30-step windows (1 s, as at "
             "15 Hz). The supplement's published numbers are beside ours.", ""]
    rows, ours = [], {}
    for rate, name in (("15 Hz", "eval/speakers-lstm"), ("30 Hz", "eval/speakers-30hz")):
        r = res.model(name)
        ours[rate] = _nt(r)["relative"] if r else None
        for who, values in (("published", {k: v / 100 for k, v in PUBLISHED_TABLE1[rate].items()}), ("ours", ours[rate])):
            cells = [_pct(values[k]) for k in ("linear_velocity", "angular_velocity", "position", "angle")] if values else ["not run"] * 4
            rows.append([rate, who] + cells)
    lines += _table(["rate", "source", "v", "ω", "P", "|θ|"], rows)
    if ours["15 Hz"] and ours["30 Hz"]:
        worse = [SHORT[k] for k in ("linear_velocity", "angular_velocity", "position", "angle")
                 if not _lt(ours["30 Hz"][k], ours["15 Hz"][k])]
        if worse:
            lines += [f"**This contradicts the paper** for {', '.join(worse)}: the 30 Hz model's relative error is not "
                      f"below the 15 Hz model's, while the supplement found 30 Hz better on all four.", ""]
        else:
            lines += ["As in the supplement, 30 Hz gives lower relative errors on all four quantities.", ""]
    if "rate" in plots:
        lines += [f"![15 Hz vs 30 Hz error over time]({plots['rate']})", ""]
    return lines


def _section_friction(res: _Results, plots: dict[str, str]) -> list[str]:
    lines = ["## Friction generalisation (supplement Figure 1)", "",
             "A model trained on Speakers with a random effective friction μ in [0.1, 0.5] per simulation, rolled out with "
             "0, 1, 3 or 5 additional true velocity steps (warm start), against the model trained and tested with "
             "constant friction (μ = 0.25). Non-toppling test sequences of each model's own store.", ""]
    entries = [(f"random friction, warm start {k}", f"eval/friction-warm{k}") for k in FRICTION_WARM_STARTS]
    entries.append(("constant friction (Speakers LSTM)", "eval/speakers-lstm"))
    lines += _table(["model"] + ERR_HEAD + ["rel. p", "topple acc."], _speakers_rows(res, entries, "eval/friction-warm0"))
    pos = [_headline(res.model(f"eval/friction-warm{k}")) for k in FRICTION_WARM_STARTS]
    if all(math.isfinite(p) for p in pos):
        if all(b <= a for a, b in zip(pos, pos[1:])):
            lines += ["As in the supplement, the position error falls as more true velocity steps are given.", ""]
        else:
            lines += ["**This contradicts the supplement**: the position error does not fall steadily with more warm-start "
                      f"steps ({', '.join(_num(p) for p in pos)} m/step for 0/1/3/5).", ""]
    if "friction" in plots:
        lines += [f"![Friction: error over time]({plots['friction']})", ""]
    return lines


def _section_pretraining(res: _Results) -> list[str]:
    lines = ["## Encoder pretraining on and off (Speakers)", "",
             "The same model trained on Speakers from a shape encoder pretrained on shape classification "
             "(`physdyn pretrain`) and from scratch. The paper always started from pretrained PointNet weights and "
             "reported no ablation, so there is no published number to compare with.", ""]
    lines += _table(["encoder"] + ERR_HEAD + ["rel. p", "topple acc."],
                    _speakers_rows(res, [("from scratch", "eval/speakers-lstm"), ("pretrained", "eval/speakers-pretrained")], None))
    fin = _load_json(res.out / "pretrain" / "encoder" / "finished.json")
    if fin:
        acc = fin.get("metrics", {}).get("val/acc")
        lines += [f"Pretraining classified {len(fin.get('classes', []))} shape classes with validation accuracy {_num(acc, 3)}.", ""]
    return lines


def _section_runs(res: _Results) -> list[str]:
    lines = ["## Runs and wall times", "",
             "Wall time of the invocation that finished each run (a resumed run counts only its last part). "
             "Resolved configs: `config.yaml` in each run folder; metrics: `metrics.json` of each evaluation.", ""]
    rows, total = [], 0.0
    for spec in build_suite():
        info = _load_json(res.out / spec.name / RUN_FILE)
        if info is None:
            rows.append([f"`{spec.name}`", "not run", "", ""])
            continue
        total += info["wall_s"]
        rows.append([f"`{spec.name}`", "resumed" if info.get("resumed") else "finished", f"{info['wall_s']:.1f}", info.get("finished", "")])
    lines += _table(["run", "status", "wall time (s)", "finished"], rows)
    lines += [f"Total: {total / 60:.1f} min of recorded wall time.", ""]
    return lines


# A curve's late steps average over the few sequences that are still moving (the longest slides), so its
# tail would be one or two sequences' noise; curves stop once fewer than this many sequences remain.
def plotted_steps(curves: dict) -> int:
    """How many leading steps of an error curve to plot (``report.curve_end``, the test report's rule)."""
    count = curves.get("count") or [CURVE_MIN_SEQUENCES] * len(curves["position_m"])
    return curve_end(count)


def _plot_curves(series: list[tuple[str, dict | None]], path: Path, title: str) -> bool:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = [(label, r) for label, r in series if r is not None]
    if not series:
        return False
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for label, r in series:
        curves = r["curves"].get("non_toppling") or r["curves"]["all"]
        draw_error_curves(axes, label, curves, r["rate_hz"], plotted_steps(curves))
    axes[0].set(xlabel="time (s)", ylabel="position error (m)", title=f"{title}: position")
    axes[1].set(xlabel="time (s)", ylabel="rotation error (deg)", title=f"{title}: rotation")
    axes[0].legend(fontsize=7)
    fig.text(0.5, 0.01, f"median over the sequences still moving at each time (band: interquartile range); a "
             f"curve ends where fewer than a quarter of them, or {CURVE_MIN_SEQUENCES}, remain", ha="center",
             fontsize=8, color="0.35")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def _plot_generalisation(res: _Results, path: Path) -> bool:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    procs = [("Single", "single"), ("Combined", "combined"), ("Leave-out", "leaveout")]
    if all(res.model(f"eval/{p}-{c}") is None for _, p in procs for c in CATEGORIES):
        return False
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    width = 0.2
    x = np.arange(len(CATEGORIES))
    for ax, key in zip(axes, ("position", "angle_deg")):
        for i, (label, p) in enumerate(procs):
            values = [_headline(res.model(f"eval/{p}-{c}"), key) for c in CATEGORIES]
            ax.bar(x + i * width, values, width, label=label)
        coul = [_headline(res.baseline(f"eval/combined-{c}", "coulomb_slide"), key) if res.metrics(f"eval/combined-{c}") else np.nan
                for c in CATEGORIES]
        ax.bar(x + 3 * width, coul, width, label="Coulomb sliding", color="grey")
        ax.set_xticks(x + 1.5 * width, CATEGORIES, rotation=20)
        ax.set_title(f"roll-out {SHORT[key]} error ({UNITS[key]}/step), non-toppling")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def _plots(res: _Results, folder: Path, link_prefix: str) -> dict[str, str]:
    folder.mkdir(parents=True, exist_ok=True)
    made = {}
    jobs = {
        "generalisation": lambda p: _plot_generalisation(res, p),
        "mlp": lambda p: _plot_curves([("LSTM", res.model("eval/speakers-lstm")), ("MLP", res.model("eval/speakers-mlp")),
                                       ("Coulomb sliding", res.baseline("eval/speakers-lstm", "coulomb_slide"))], p, "LSTM vs MLP"),
        "rate": lambda p: _plot_curves([("15 Hz", res.model("eval/speakers-lstm")), ("30 Hz", res.model("eval/speakers-30hz"))], p, "15 vs 30 Hz"),
        "friction": lambda p: _plot_curves([(f"random μ, warm {k}", res.model(f"eval/friction-warm{k}")) for k in FRICTION_WARM_STARTS]
                                           + [("constant μ", res.model("eval/speakers-lstm"))], p, "Friction"),
    }
    for key, job in jobs.items():
        path = folder / f"{key}.png"
        if job(path):
            made[key] = f"{link_prefix}/{path.name}"
        elif path.exists():
            path.unlink()  # a stale plot from an earlier page would contradict the tables
    return made


def write_results(out: str | Path, results: str | Path, command: str = "") -> Path:
    """Write the results page ``results`` (Markdown) and its plots in ``<results dir>/<stem>/`` from the
    finished runs under ``out``. Generated, never hand-edited: rerun to refresh."""
    out, results = Path(out), Path(results)
    manifest = _load_json(out / MANIFEST)
    if manifest is None:
        raise PhysdynError(f"{out} holds no reproduce runs ({MANIFEST} missing); run `physdyn reproduce --out {out}` first")
    scale, scale_file = load_scale(manifest["scale"] if manifest["scale"] in SCALES else manifest.get("scale_file", manifest["scale"]))
    res = _Results(out)
    results.parent.mkdir(parents=True, exist_ok=True)
    plots = _plots(res, results.parent / results.stem, results.stem)
    # Older manifests have no runs_done: count those invocations as having made runs.
    makers = [inv for inv in manifest["invocations"] if inv.get("runs_done", 1) > 0] or manifest["invocations"][-1:]
    idle = len(manifest["invocations"]) - len(makers)
    hw = makers[-1]["hardware"]
    lines = [
        "# Reproducing Rempe et al. (WACV 2020): results", "",
        f"<!-- Generated by `physdyn reproduce`; do not edit by hand. Regenerate with: "
        f"physdyn reproduce --report-only --out {out} --results {results} -->", "",
        f"- **Scale:** `{scale.name}` — {scale.description.strip()}",
        f"- **Hardware:** {hw['platform']}, {hw['cpu_count']} CPUs, Python {hw['python']}, torch {hw['torch']}, "
        f"GPU: {hw['gpu'] or 'none'}",
        f"- **Page written:** {_now()}" + (f" by `{command}`" if command else ""),
        "- **Runs made by:**",
    ]
    lines += [f"  - `{inv['command']}` on {inv['date']}"
              + (f" ({inv['runs_done']} runs)" if "runs_done" in inv else "") for inv in makers]
    if idle:
        lines += [f"  - and {idle} later invocation(s) that found every selected run finished"]
    lines += ["", "All errors are on the test split (shapes never seen in training). Runs that were not made (see "
              "`--only`) show as *not run*.", "", "## What differs from the paper", ""]
    lines += [f"- {d}" for d in DIFFERENCES]
    if scale.name != "paper":
        lines += [f"- **Scale `{scale.name}`**: {scale.description.strip()} Expect larger errors than the paper's."]
    lines += [""]
    lines += _section_generalisation(res, plots)
    lines += _section_mlp(res, plots)
    lines += _section_rate(res, plots)
    lines += _section_friction(res, plots)
    lines += _section_topple(res)
    lines += _section_pretraining(res)
    lines += _section_runs(res)
    results.write_text("\n".join(lines))
    return results
