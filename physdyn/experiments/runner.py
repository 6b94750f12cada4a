"""Running the reproduce suite: each selected run in dependency order under ``OUT``, finished work
skipped and interrupted work resumed, every invocation recorded in ``OUT/reproduce.json``.

Finished work is skipped (finished.json, metrics.json, a complete store); a training with last.ckpt is
resumed, an incomplete store continued. The folder layout is ``suite.py``'s.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import platform
import queue
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import torch
import zarr
from omegaconf import OmegaConf

from physdyn.config import to_dict
from physdyn.data.simulated_store import generate_dataset
from physdyn.data.store import load_store, store_exists
from physdyn.errors import PhysdynError
from physdyn.files import write_text_atomic
from physdyn.eval.baselines import load_checkpoint
from physdyn.eval.evaluate import compare
from physdyn.eval.report import write_report
from physdyn.experiments.results_page import write_results
from physdyn.experiments.suite import (MANIFEST, RUN_FILE, RunSpec, ScaleConfig, build_suite, data_config,
                                       experiment_config, load_scale, pretrain_config, run_dir, select_runs,
                                       store_path, utc_now)
from physdyn.models.pretrain import pretrain
from physdyn.models.training import fit
from physdyn.write_lock import write_lock

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
    try:
        return bool(zarr.open_group(str(path), mode="r").attrs.get("complete"))
    except Exception:
        return False


def hardware() -> dict[str, Any]:
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    return {"platform": platform.platform(), "python": platform.python_version(), "cpu_count": os.cpu_count(),
            "torch": torch.__version__, "gpu": gpu}


def _manifest(out: Path, scale: ScaleConfig, scale_file: Path, command: str, only: Sequence[str] | None) -> None:
    path = Path(out) / MANIFEST
    data = json.loads(path.read_text()) if path.is_file() else {"scale": scale.name, "scale_file": str(scale_file), "invocations": []}
    if data["scale"] != scale.name:
        raise PhysdynError(f"{out} holds runs of scale '{data['scale']}', not '{scale.name}'; choose another --out "
                           f"or pass --scale {data['scale']}")
    data["invocations"].append({"command": command, "date": utc_now(), "only": list(only or []), "hardware": hardware()})
    Path(out).mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(data, indent=1))


def _record_runs_done(out: Path, done: int) -> None:
    """Note on the latest invocation how many runs it made: one that only skipped finished runs made none
    of the page's numbers, so the page neither credits it nor takes its hardware."""
    path = Path(out) / MANIFEST
    data = json.loads(path.read_text())
    data["invocations"][-1]["runs_done"] = done
    write_text_atomic(path, json.dumps(data, indent=1))


class SuiteRunner:
    """Executes RunSpecs under ``out``; stores are loaded once and shared by the runs that read them.
    ``jobs`` > 1: that many runs at once, each in its own process (``_run_in_parallel``)."""

    def __init__(self, scale: ScaleConfig, scale_file: Path, out: str | Path, workers: int | None = None,
                 log: Callable[[str], None] = print, jobs: int = 1):
        self.scale, self.scale_file, self.out = scale, scale_file, Path(out)
        self.workers = workers if workers is not None else scale.workers
        self.log = log
        self.jobs = max(1, int(jobs))
        self._stores: dict[str, Any] = {}

    def store(self, name: str):
        if name not in self._stores:
            self._stores[name] = load_store(str(store_path(self.out, name)))
        return self._stores[name]

    def run(self, specs: Sequence[RunSpec]) -> list[RunOutcome]:
        if self.jobs > 1:
            return self._run_in_parallel(specs)
        outcomes = []
        for i, spec in enumerate(specs, 1):
            if is_finished(self.out, spec):
                self.log(f"[{i}/{len(specs)}] skip {spec.name} (finished)")
                outcomes.append(RunOutcome(spec.name, "skipped", 0.0))
                continue
            self.log(f"[{i}/{len(specs)}] run {spec.name}")
            outcome = self.run_one(spec)
            self.log(f"[{i}/{len(specs)}] {outcome.status} {spec.name} in {outcome.wall_s:.1f} s")
            outcomes.append(outcome)
        return outcomes

    def run_one(self, spec: RunSpec) -> RunOutcome:
        """One run, recorded in its folder's run.json."""
        started = time.time()
        resumed = getattr(self, f"_run_{spec.kind}")(spec)
        wall = time.time() - started
        d = run_dir(self.out, spec)
        d.mkdir(parents=True, exist_ok=True)
        write_text_atomic(d / RUN_FILE, json.dumps({"name": spec.name, "kind": spec.kind, "scale": self.scale.name,
                                                    "wall_s": wall, "resumed": resumed, "finished": utc_now()},
                                                   indent=1))
        return RunOutcome(spec.name, "resumed" if resumed else "done", wall)

    def _run_in_parallel(self, specs: Sequence[RunSpec]) -> list[RunOutcome]:
        """Up to ``jobs`` runs at once, each in a process of its own with cpu_count / jobs torch threads; a run
        starts once the runs it needs among ``specs`` are finished. Trainings dominate the suite and each
        gains little from a second thread (a small model, batches of 64), so two at once on two cores take
        0.6-0.7x the time of one after another (docs/reproduce.md). On a failure no new run starts, the running ones finish,
        and the first error is raised."""
        names = {s.name for s in specs}
        outcomes: dict[str, RunOutcome] = {}
        pending: list[RunSpec] = []
        for i, spec in enumerate(specs, 1):
            if is_finished(self.out, spec):
                self.log(f"[{i}/{len(specs)}] skip {spec.name} (finished)")
                outcomes[spec.name] = RunOutcome(spec.name, "skipped", 0.0)
            else:
                pending.append(spec)
        number = {s.name: i for i, s in enumerate(specs, 1)}
        threads = max(1, (os.cpu_count() or 1) // self.jobs)
        context = multiprocessing.get_context("spawn")  # fresh interpreters: no torch or PyBullet state forked
        results = context.Queue()
        running: dict[str, Any] = {}
        failure: str | None = None
        try:
            while pending or running:
                while failure is None and pending and len(running) < self.jobs:
                    ready = next((s for s in pending if all(n not in names or n in outcomes for n in s.needs)), None)
                    if ready is None:
                        break
                    pending.remove(ready)
                    self.log(f"[{number[ready.name]}/{len(specs)}] run {ready.name}")
                    process = context.Process(target=_run_in_process, name=ready.name, args=(
                        str(self.scale_file), str(self.out), self.workers, ready, threads, results))
                    process.start()
                    running[ready.name] = process
                if not running:
                    break
                try:
                    name, outcome, error = results.get(timeout=1.0)
                except queue.Empty:  # a process killed from outside reports nothing: notice that it is gone
                    gone = next((n for n, p in running.items() if not p.is_alive() and p.exitcode), None)
                    if gone is None:
                        continue
                    name, outcome, error = gone, None, f"its process ended with exit code {running[gone].exitcode}"
                running.pop(name).join()
                if error is not None:
                    failure = failure or f"{name}: {error}"
                    pending.clear()
                    continue
                outcomes[name] = outcome
                self.log(f"[{number[name]}/{len(specs)}] {outcome.status} {name} in {outcome.wall_s:.1f} s")
        finally:
            for process in running.values():  # interrupted: a training stopped now resumes from its last.ckpt
                process.terminate()
                process.join()
        if failure is not None:
            raise PhysdynError(failure + "; the runs that finished are kept: run the same command again to go on")
        return [outcomes[s.name] for s in specs]

    def _run_data(self, spec: RunSpec) -> bool:
        cfg = data_config(self.scale, spec.short)
        path = store_path(self.out, spec.short)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path.parent / "config.yaml", _yaml(to_dict(cfg)))
        if _store_complete(path):
            return False
        resume = store_exists(str(path))
        generate_dataset(cfg, str(path), workers=self.workers, resume=resume, progress=False)
        self._stores.pop(spec.short, None)
        return resume

    def _run_pretrain(self, spec: RunSpec) -> bool:
        cfg = pretrain_config(self.scale, self.scale_file, spec, self.out)
        d = run_dir(self.out, spec)
        started_before = d.exists() and any(d.iterdir())
        pretrain(cfg, overwrite=True)  # no mid-run checkpoint to continue from: an interrupted one starts over
        return started_before

    def _run_train(self, spec: RunSpec) -> bool:
        cfg = experiment_config(self.scale, self.scale_file, spec, self.out)
        d = run_dir(self.out, spec)
        resume = (d / "last.ckpt").is_file()
        fit(cfg, resume=resume, overwrite=not resume, store=self.store(spec.store))
        return resume

    def _run_eval(self, spec: RunSpec) -> bool:
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


def _run_in_process(scale_file: str, out: str, workers: int, spec: RunSpec, threads: int, results: Any) -> None:
    """One run of ``SuiteRunner._run_in_parallel`` in its own process: (name, outcome, None) or (name, None,
    the error in one line) on ``results``."""
    torch.set_num_threads(threads)
    try:
        scale, path = load_scale(scale_file)
        outcome, error = SuiteRunner(scale, path, out, workers, log=lambda line: None).run_one(spec), None
    except BaseException as e:  # noqa: BLE001 - reported to the parent, which stops the suite
        outcome, error = None, str(e).splitlines()[0] if str(e) else type(e).__name__
    results.put((spec.name, outcome, error))


def _yaml(data: dict) -> str:
    return OmegaConf.to_yaml(OmegaConf.create(data))


def run_suite(scale: str | Path, out: str | Path, only: Sequence[str] | None = None, workers: int | None = None,
              results: str | Path | None = None, command: str = "", log: Callable[[str], None] = print,
              jobs: int = 1) -> list[RunOutcome]:
    """Run (or skip, or resume) the selected experiments at ``scale`` under ``out``, ``jobs`` at once; then
    write the results page to ``results`` when given. Returns one outcome per run."""
    cfg, path = load_scale(scale)
    specs = select_runs(build_suite(), only)
    with write_lock(out):  # one `reproduce` per output folder; its stores and runs take their own locks too
        return _run_suite_locked(cfg, path, specs, out, only, workers, results, command or
                                 f"run_suite({scale!r}, {str(out)!r}, only={list(only or [])})", log, jobs)


def _run_suite_locked(cfg: ScaleConfig, path: Path, specs: list[RunSpec], out: str | Path, only: Sequence[str] | None,
                      workers: int | None, results: str | Path | None, command: str,
                      log: Callable[[str], None], jobs: int = 1) -> list[RunOutcome]:
    _manifest(Path(out), cfg, path, command, only)
    outcomes = SuiteRunner(cfg, path, out, workers, log, jobs).run(specs)
    done = sum(o.status != "skipped" for o in outcomes)
    _record_runs_done(Path(out), done)
    log(f"reproduce: {done} run(s) done, {len(outcomes) - done} skipped (finished earlier), in {out}")
    if results is not None:
        write_results(out, results, command=command)
        log(f"reproduce: wrote {results}")
    return outcomes
