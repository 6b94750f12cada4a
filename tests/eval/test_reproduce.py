"""`physdyn reproduce`: the whole suite at the tiny scale, skipping finished runs, resuming interrupted ones,
and the results page with every table. Everything is written under tmp_path, never to the repo's docs/."""

from __future__ import annotations

import json
import shutil
import time

import pytest
import torch

from physdyn.errors import PhysdynError
from physdyn.experiments import results_page, runner, suite
from tests.conftest import run_cli

torch.set_num_threads(1)

SECTIONS = (
    "## Single, Combined and Leave-out", "## LSTM against the MLP baseline", "## 15 Hz against 30 Hz (supplement Table 1)",
    "## Friction generalisation", "## Topple classification per category", "## Encoder pretraining on and off",
    "## Runs and wall times", "## What differs from the paper",
)


@pytest.fixture(scope="module")
def tiny_suite(tmp_path_factory):
    """The whole suite at the tiny scale, run once in this process (about 20 s on 2 cores)."""
    root = tmp_path_factory.mktemp("reproduce")
    log: list[str] = []
    started = time.time()
    outcomes = runner.run_suite("tiny", root / "out", results=root / "results.md", command="pytest tiny suite", log=log.append)
    return root, outcomes, log, time.time() - started


@pytest.mark.slow  # minutes-scale; CI runs it after the default suite
def test_the_tiny_suite_runs_end_to_end_and_the_page_has_every_table(tiny_suite):
    root, outcomes, log, _ = tiny_suite
    assert {o.name for o in outcomes} == {r.name for r in suite.build_suite()}
    assert all(o.status == "done" for o in outcomes)
    page = (root / "results.md").read_text()
    for heading in SECTIONS:
        assert heading in page, heading
    assert "| not run" not in page
    for category in suite.CATEGORIES:  # per category, with the baselines beside the models
        for label in ("Single", "Combined", "Leave-out", "stay put (baseline)", "Coulomb sliding (baseline, true μ)"):
            assert f"| {category} | {label} |" in page
    # Table 1 with the supplement's numbers beside ours
    for published in ("8.65 %", "7.59 %", "8.10 %", "0.52 %", "4.92 %", "3.25 %", "6.13 %", "0.43 %"):
        assert published in page
    assert "| 15 Hz | ours |" in page and "| 30 Hz | ours |" in page
    for k in (0, 1, 3, 5):
        assert f"| random friction, warm start {k} |" in page
    assert "| constant friction (Speakers LSTM) |" in page
    assert "| from scratch |" in page and "| pretrained |" in page
    # scale, hardware, command and date, what differs, wall times
    assert "**Scale:** `tiny`" in page and "torch " in page and "CPUs" in page
    assert "`pytest tiny suite` on 20" in page
    assert "ShapeNet" in page and "PyBullet" in page
    assert "| `train/combined` | finished |" in page
    for plot in ("generalisation", "mlp", "rate", "friction"):
        png = root / "results" / f"{plot}.png"
        assert png.read_bytes()[:4] == b"\x89PNG" and f"](results/{plot}.png)" in page
    # each run keeps its resolved config, checkpoint, metrics and wall time
    out = root / "out"
    assert (out / "train/combined/config.yaml").is_file() and (out / "train/combined/best.ckpt").is_file()
    assert (out / "data/combined/config.yaml").is_file()
    assert json.loads((out / "eval/friction-warm3/metrics.json").read_text())["results"]["friction"]["warm_start"] == 3
    assert "window: 30" in (out / "train/speakers-30hz/config.yaml").read_text()
    assert json.loads((out / "train/combined/run.json").read_text())["wall_s"] > 0


def test_error_curves_stop_where_too_few_sequences_remain():
    curve = lambda count: {"position_m": [0.0] * len(count), "count": count}  # noqa: E731
    assert results_page.CURVE_MIN_SEQUENCES == 10
    assert results_page.plotted_steps(curve([40, 40, 25, 10, 9, 3, 1])) == 4  # the steps with at least 10 sequences
    assert results_page.plotted_steps(curve([12, 12, 12])) == 3
    assert results_page.plotted_steps(curve([3, 3, 2, 1])) == 2  # a small set: plotted while all of it moves
    assert results_page.plotted_steps(curve([])) == 0
    assert results_page.plotted_steps(curve([800, 600, 400, 200, 150])) == 4  # and at least a quarter of a large set (200)


@pytest.mark.slow  # minutes-scale; CI runs it after the default suite
def test_a_second_invocation_skips_every_finished_run(tiny_suite):
    root, _, _, first_seconds = tiny_suite
    log: list[str] = []
    started = time.time()
    outcomes = runner.run_suite("tiny", root / "out", log=log.append)
    assert all(o.status == "skipped" for o in outcomes)
    assert sum("skip " in line for line in log) == len(suite.build_suite())
    assert time.time() - started < max(5.0, first_seconds / 3)
    # the page credits the invocation that made the runs, not the one that only skipped them
    page = results_page.write_results(root / "out", root / "again.md").read_text()
    assert "`pytest tiny suite` on 20" in page and f"({len(suite.build_suite())} runs)" in page
    assert "and 1 later invocation(s) that found every selected run finished" in page


@pytest.mark.slow  # minutes-scale; CI runs it after the default suite
def test_the_opening_a_person_wrote_above_the_generated_part_survives_regeneration(tiny_suite):
    root, _, _, _ = tiny_suite
    page = root / "opened.md"
    generated = results_page.write_results(root / "out", page).read_text()
    title, rest = generated.split("\n", 1)
    page.write_text(f"{title}\n\n**The answer first.** Two lines a person wrote.\n\n{rest.lstrip()}")
    again = results_page.write_results(root / "out", page).read_text()
    assert again.startswith(f"{title}\n\n**The answer first.** Two lines a person wrote.\n\n<!-- Generated")
    assert again.count("The answer first") == 1 and "## What differs from the paper" in again
    # a page with no generated part (a person's own notes) is replaced whole, never spliced
    notes = root / "notes.md"
    notes.write_text("# My notes\n\nnothing generated here\n")
    assert "nothing generated" not in results_page.write_results(root / "out", notes).read_text()


@pytest.mark.slow  # minutes-scale; CI runs it after the default suite
def test_an_interrupted_run_is_resumed_and_only_it_is_redone(tiny_suite):
    root, _, _, _ = tiny_suite
    out = root / "out"
    # a training killed after its last checkpoint, an evaluation that never wrote its metrics, and a
    # dataset whose generation stopped half way (re-opened as incomplete)
    (out / "train/speakers-mlp/finished.json").unlink()
    shutil.rmtree(out / "eval/single-mugs")
    before = (out / "eval/speakers-lstm/metrics.json").stat().st_mtime
    log: list[str] = []
    outcomes = {o.name: o.status for o in runner.run_suite("tiny", out, log=log.append)}
    assert outcomes.pop("train/speakers-mlp") == "resumed"
    assert outcomes.pop("eval/single-mugs") == "done"
    assert set(outcomes.values()) == {"skipped"}
    assert (out / "train/speakers-mlp/finished.json").is_file() and (out / "eval/single-mugs/metrics.json").is_file()
    assert (out / "eval/speakers-lstm/metrics.json").stat().st_mtime == before


def test_an_incomplete_store_is_resumed(tmp_path):
    from physdyn.data.simulated_store import generate_dataset
    from physdyn.data.store import load_store

    scale, path = suite.load_scale("tiny")
    out = tmp_path / "out"
    store = suite.store_path(out, "speakers")
    scale.data["speakers"] = list(scale.data["speakers"]) + ["shapes_per_block=2"]  # two blocks: stop after one
    cfg = suite.data_config(scale, "speakers")
    import physdyn.data.simulated_store as G

    original = G.simulate_blocks

    def first_block_only(*args, **kwargs):
        for item in original(*args, **kwargs):
            yield item
            raise KeyboardInterrupt

    G.simulate_blocks = first_block_only
    try:
        with pytest.raises(KeyboardInterrupt):
            generate_dataset(cfg, str(store), workers=1, progress=False)
    finally:
        G.simulate_blocks = original
    assert not runner._store_complete(store)
    suite_runner = runner.SuiteRunner(scale, path, out, log=lambda _: None)
    outcomes = suite_runner.run([r for r in suite.build_suite() if r.name == "data/speakers"])
    assert outcomes[0].status == "resumed" and runner._store_complete(store)
    assert load_store(str(store)).num_shapes == 4


@pytest.mark.slow  # minutes-scale; CI runs it after the default suite
def test_cli_only_two_experiments_then_report_only(tmp_path):
    out, page = tmp_path / "out", tmp_path / "page" / "results.md"
    proc = run_cli("reproduce", "--scale", "tiny", "--out", str(out), "--only", "lstm-vs-mlp,sampling-rate",
                   "--results", str(page), check=True)
    assert "reproduce: 8 run(s) done, 0 skipped" in proc.stdout
    assert not (out / "data/combined").exists() and not (out / "train/friction").exists()
    text = page.read_text()
    assert "| LSTM |" in text and "| 30 Hz | ours |" in text and "| not run" in text  # the rest says so
    assert "--only lstm-vs-mlp,sampling-rate" in text
    page.unlink()
    proc = run_cli("reproduce", "--report-only", "--out", str(out), "--results", str(page), check=True)
    assert page.is_file() and "| MLP |" in page.read_text()


def test_cli_errors_are_one_line(tmp_path, capsys):
    """The command's own error boundary, in this process (a fresh interpreter per case cost 5 s each)."""
    from physdyn.cli import main

    def cli(*args: str) -> tuple[int, str]:
        code = main(list(args))
        return code, capsys.readouterr().err

    code, err = cli("reproduce", "--scale", "tiny", "--out", str(tmp_path / "o"), "--only", "nonsense", "--no-results")
    assert code == 2 and "unknown experiment 'nonsense'" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    (tmp_path / "o").mkdir(exist_ok=True)
    (tmp_path / "o" / suite.MANIFEST).write_text(json.dumps({"scale": "cpu", "invocations": []}))
    code, err = cli("reproduce", "--scale", "tiny", "--out", str(tmp_path / "o"), "--no-results")
    assert code == 2 and "scale 'cpu'" in err and len(err.strip().splitlines()) == 1
    code, err = cli("reproduce", "--report-only", "--out", str(tmp_path / "empty"), "--results", str(tmp_path / "r.md"))
    assert code == 2 and "reproduce.json" in err and len(err.strip().splitlines()) == 1


def test_selecting_experiments_pulls_in_what_they_need():
    runs = suite.select_runs(suite.build_suite(), ["friction"])
    names = [r.name for r in runs]
    assert names.index("data/friction") < names.index("train/friction") < names.index("eval/friction-warm5")
    assert "train/speakers-lstm" in names and "data/combined" not in names
    for scale in suite.SCALES:  # every scale's presets resolve to valid configs
        cfg, path = suite.load_scale(scale)
        for spec in suite.build_suite():
            if spec.kind == "train":
                suite.experiment_config(cfg, path, spec, "runs/x")
            elif spec.kind == "data":
                suite.data_config(cfg, spec.short)
        suite.pretrain_config(cfg, path, suite.RunSpec("pretrain/encoder", "pretrain"), "runs/x")


@pytest.mark.slow  # about a minute: every run starts a fresh interpreter; CI runs it
def test_jobs_run_independent_runs_side_by_side_and_a_failure_stops_the_suite_in_one_line(tmp_path):
    out = tmp_path / "out"
    log: list[str] = []
    outcomes = runner.run_suite("tiny", out, only=["lstm-vs-mlp"], log=log.append, jobs=2)
    assert [o.status for o in outcomes] == ["done"] * 5
    assert all((out / name / "run.json").is_file() for name in ("train/speakers-lstm", "train/speakers-mlp"))
    assert (out / "eval/speakers-mlp/metrics.json").is_file()
    # the two trainings need only the store: both start before either ends
    started = [line for line in log if " run train/" in line]
    first_end = next(i for i, line in enumerate(log) if " done train/" in line)
    assert len(started) == 2 and all(log.index(line) < first_end for line in started)
    # a run that fails stops the suite: the error in one line, nothing after it started, finished runs kept
    bad = tmp_path / "bad.yaml"
    text = (suite.SCALES_DIR / "tiny.yaml").read_text()
    bad.write_text(text.replace("  - trainer.max_steps=2\n", "  - trainer.max_steps=2\n  - trainer.precision=nonsense\n", 1))
    with pytest.raises(PhysdynError) as info:
        runner.run_suite(str(bad), tmp_path / "bad", only=["lstm-vs-mlp"], log=log.append, jobs=2)
    message = str(info.value)
    assert message.startswith("train/speakers-") and "\n" not in message and "run the same command again" in message
    assert (tmp_path / "bad/data/speakers").is_dir() and not (tmp_path / "bad/eval").exists()
