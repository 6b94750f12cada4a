"""One writer per store and run folder (physdyn.write_lock), and outputs that are whole or absent
(physdyn.files.atomic_output) when the disk fills or fails mid-write. docs/reliability.md describes both."""

from __future__ import annotations

import errno
import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from physdyn.errors import OutputWriteError, PhysdynError, WriterBusyError
from physdyn.files import atomic_output, write_text_atomic
from physdyn.write_lock import lock_path, write_lock
from tests.conftest import REPO, tiny_data_config

FAMILIES = ("primitives", "bottles", "mugs", "trashcans", "speakers")


def five_shape_config():
    """Five shapes (one per family), two pushes each, one shape per block: five blocks in a few seconds."""
    return tiny_data_config(*[f"families.{n}.shapes=1" for n in FAMILIES],
                            *[f"families.{n}.sims_per_shape=2" for n in FAMILIES], "shapes_per_block=1")


def five_shape_overrides() -> list[str]:
    from tests.conftest import TINY_OVERRIDES

    return TINY_OVERRIDES + [f"families.{n}.shapes=1" for n in FAMILIES] + \
        [f"families.{n}.sims_per_shape=2" for n in FAMILIES] + ["shapes_per_block=1"]


def start_holder(target: Path, then_fork: bool = False) -> subprocess.Popen:
    """Another process holding the writer's lock on ``target`` until killed (``then_fork``: after forking a
    child that sleeps, as a --workers pool does). Returns once the lock is held."""
    script = textwrap.dedent(f"""
        import os, sys, time
        from physdyn.write_lock import write_lock
        with write_lock({str(target)!r}, command="physdyn simulate (test holder)"):
            if {then_fork!r} and os.fork() == 0:
                time.sleep(60)
                os._exit(0)
            print("held", flush=True)
            time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=REPO, stdout=subprocess.PIPE, text=True,
                            start_new_session=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)


# --- the lock ---------------------------------------------------------------------------------------------

def test_a_second_writer_is_refused_in_one_line_naming_the_holder(tmp_path):
    store = tmp_path / "s.zarr"
    holder = start_holder(store)
    try:
        with pytest.raises(WriterBusyError) as err:
            with write_lock(store):
                pass
        message = str(err.value)
        assert "\n" not in message
        assert message.startswith(f"{store} is being written by pid {holder.pid} on host {socket.gethostname()} since ")
        assert "physdyn simulate (test holder)" in message and message.endswith("; wait for it or stop it")
    finally:
        stop(holder)


def test_a_lock_left_by_a_killed_writer_is_taken_over(tmp_path):
    store = tmp_path / "s.zarr"
    holder = start_holder(store)
    os.kill(holder.pid, signal.SIGKILL)  # no clean-up: the lock file and its record stay behind
    holder.wait(timeout=30)
    stale = json.loads(lock_path(store).read_text())
    assert stale["pid"] == holder.pid
    with write_lock(store) as lock:
        assert json.loads(lock.read_text())["pid"] == os.getpid()  # the record is ours now
    assert not lock_path(store).exists()  # released: the file goes too


def test_a_worker_outliving_its_killed_parent_does_not_keep_the_lock(tmp_path):
    """Pool workers are forked with the lock's file open; they drop it at fork, so killing the writer frees
    the store even while a worker lingers."""
    store = tmp_path / "s.zarr"
    holder = start_holder(store, then_fork=True)
    os.kill(holder.pid, signal.SIGKILL)  # the parent only; its sleeping child lives on
    holder.wait(timeout=30)
    try:
        with write_lock(store):
            pass
    finally:
        os.killpg(holder.pid, signal.SIGKILL)  # the orphaned child (same process group)


def test_one_process_cannot_take_its_own_lock_twice(tmp_path):
    with write_lock(tmp_path / "run"):
        with pytest.raises(WriterBusyError, match=f"pid {os.getpid()}"):
            with write_lock(tmp_path / "run"):
                pass


def test_remote_urls_are_not_locked(tmp_path):
    with write_lock("s3://bucket/store.zarr") as lock:
        assert lock is None
    with write_lock(f"file://{tmp_path}/s.zarr") as lock:
        assert lock == lock_path(tmp_path / "s.zarr")


def test_simulate_resume_is_refused_while_another_process_writes_the_store(tmp_path, monkeypatch):
    """The issue's bug: a second --resume on a store being written failed with KeyError '_parts/...'."""
    from physdyn.data.simulated_store import generate_dataset
    from physdyn.data.store import PARTS

    out = tmp_path / "s.zarr"
    partial_store(out, 2, monkeypatch)
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    holder = start_holder(out)
    try:
        with pytest.raises(WriterBusyError, match=f"is being written by pid {holder.pid} on host"):
            generate_dataset(five_shape_config(), str(out), resume=True, progress=False, workers=1)
    finally:
        stop(holder)
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before  # the refused writer touched nothing
    assert len(list((out / PARTS).glob("0*"))) == 2


def partial_store(out: Path, blocks: int, monkeypatch) -> None:
    """A store whose run stopped (as on Ctrl-C) after its first ``blocks`` blocks: what --resume continues."""
    import physdyn.data.simulated_store as simulated_store
    from physdyn.data.simulated_store import generate_dataset

    real = simulated_store.simulate_blocks

    def stopping(*args, **kwargs):
        for i, block in enumerate(real(*args, **kwargs)):
            if i == blocks:
                raise KeyboardInterrupt
            yield block

    with monkeypatch.context() as patch:
        patch.setattr(simulated_store, "simulate_blocks", stopping)
        with pytest.raises(KeyboardInterrupt):
            generate_dataset(five_shape_config(), str(out), progress=False, workers=1)


def test_fit_is_refused_while_another_process_writes_the_run_folder(tiny_store, tmp_path):
    from physdyn.models.training import fit, load_experiment_config
    from tests.models.conftest import QUICKSTART, shrunk_overrides

    cfg = load_experiment_config(QUICKSTART, shrunk_overrides(tiny_store, tmp_path / "run"))
    holder = start_holder(tmp_path / "run")
    try:
        with pytest.raises(WriterBusyError, match=f"run is being written by pid {holder.pid} on host"):
            fit(cfg)
    finally:
        stop(holder)
    assert not (tmp_path / "run").exists()  # refused before the folder was made


# --- atomic writes --------------------------------------------------------------------------------------

def _no_temporaries(folder: Path, keep: set[str]) -> None:
    assert {p.name for p in folder.iterdir()} == keep


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EIO])
def test_a_disk_fault_mid_write_keeps_the_old_file_and_names_the_users_path(tmp_path, code):
    target = tmp_path / "last.ckpt"
    target.write_bytes(b"good")

    class FailingFile:  # what a full disk looks like to a writer: the write itself fails
        def __init__(self, path):
            self.fh = open(path, "wb")

        def write(self, data):
            self.fh.write(data[: len(data) // 2])
            raise OSError(code, os.strerror(code))

    with pytest.raises(OutputWriteError) as err:
        with atomic_output(target) as tmp:
            FailingFile(tmp).write(b"new checkpoint bytes")
    assert str(err.value) == f"cannot write {target}: {os.strerror(code)}; the previous file is unchanged"
    assert isinstance(err.value, OSError) and isinstance(err.value, PhysdynError) and err.value.errno == code
    assert target.read_bytes() == b"good"
    _no_temporaries(tmp_path, {"last.ckpt"})


@pytest.mark.parametrize("step", ["os.fsync", "os.replace"])
def test_a_fault_at_sync_or_rename_keeps_the_old_file(tmp_path, monkeypatch, step):
    target = tmp_path / "metrics.json"
    write_text_atomic(target, "old")
    module, name = step.split(".")

    def failing(*args, **kwargs):
        raise OSError(errno.EIO, os.strerror(errno.EIO))

    monkeypatch.setattr(os, name, failing)
    with pytest.raises(OutputWriteError, match=f"cannot write {target}: Input/output error"):
        write_text_atomic(target, "new")
    monkeypatch.undo()
    assert target.read_text() == "old"
    _no_temporaries(tmp_path, {"metrics.json"})


def test_a_failed_first_write_says_nothing_was_written(tmp_path, monkeypatch):
    monkeypatch.setattr(os, "replace", lambda *a: (_ for _ in ()).throw(OSError(errno.ENOSPC, "No space left on device")))
    with pytest.raises(OutputWriteError, match="nothing was written"):
        write_text_atomic(tmp_path / "report.md", "x")
    monkeypatch.undo()
    _no_temporaries(tmp_path, set())


def test_the_cli_prints_a_disk_fault_as_one_line_naming_the_output(tmp_path, capsys, monkeypatch):
    """`physdyn ...` catches PhysdynError first: one line naming the user's file, exit status 2."""
    from physdyn import cli

    target = tmp_path / "out.json"

    def fake_command(args):
        with atomic_output(target) as tmp:
            tmp.write_text("half")
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp))

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    args = parser.parse_args(["components"])
    monkeypatch.setattr(parser, "parse_args", lambda argv=None: args)
    monkeypatch.setattr(args, "func", fake_command)
    assert cli.main(["components"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"physdyn components: error: cannot write {target}: No space left on device; nothing was written"


def test_lightning_checkpoints_are_written_beside_their_name_then_renamed(tmp_path, monkeypatch):
    """Lightning's own save staged checkpoints in /tmp and copied them over last.ckpt: a full disk left a
    truncated checkpoint. physdyn's CheckpointIO keeps the old one."""
    import torch

    from physdyn.models.trainer_setup import SafeCheckpointIO

    io = SafeCheckpointIO()
    target = tmp_path / "last.ckpt"
    io.save_checkpoint({"global_step": 1, "state_dict": {"w": torch.ones(3)}}, target)
    assert io.load_checkpoint(target)["global_step"] == 1

    def full_disk(self, data):  # half the bytes reach the disk, then it is full
        with open(self, "wb") as fh:
            fh.write(bytes(data)[: len(data) // 2])
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_bytes", full_disk)
    with pytest.raises(OutputWriteError, match=f"cannot write {target}: No space left on device; the previous"):
        io.save_checkpoint({"global_step": 2, "state_dict": {}}, target)
    monkeypatch.undo()
    assert io.load_checkpoint(target)["global_step"] == 1
    _no_temporaries(tmp_path, {"last.ckpt"})


@pytest.mark.slow  # two small simulations: ~10 s
def test_a_run_killed_while_removing_its_parts_is_completed_by_resume(tmp_path, monkeypatch):
    """A kill inside finalize, after the final arrays are written, while the parts are being deleted, must not
    leave parts marked done without their arrays (--resume would fail with KeyError 'frames/com_position'):
    resume keeps the written arrays and only marks the store complete."""
    from physdyn.data.simulated_store import generate_dataset
    from physdyn.data.store import StoreWriter, load_store
    from tests.sim.test_generate import assert_same_arrays

    out = tmp_path / "s.zarr"
    real_delete = StoreWriter._delete

    def killed_mid_delete(self, name):
        if name == "_parts":
            real_delete(self, "_parts/000001/frames")  # some of the parts' arrays are gone...
            raise KeyboardInterrupt  # ...when the process dies
        real_delete(self, name)

    with monkeypatch.context() as patch:
        patch.setattr(StoreWriter, "_delete", killed_mid_delete)
        with pytest.raises(KeyboardInterrupt):
            generate_dataset(five_shape_config(), str(out), progress=False, workers=1)
    report = generate_dataset(five_shape_config(), str(out), resume=True, progress=False, workers=1)
    assert report.num_shapes == 5 and report.blocks_resumed == 5
    ref = tmp_path / "ref.zarr"
    generate_dataset(five_shape_config(), str(ref), progress=False, workers=1)
    assert_same_arrays(load_store(out), load_store(ref))


# --- end to end, two real commands (slow) ------------------------------------------------------------------

PAUSED_SIMULATE = """
import sys, time
from pathlib import Path
import physdyn.data.simulated_store as s
real = s.simulate_blocks
go = Path(sys.argv[1])

def paused(*args, **kwargs):  # hold the store, lock taken, after the first resumed block, until told to go
    for i, block in enumerate(real(*args, **kwargs)):
        if i == 1:
            print("paused", flush=True)
            while not go.exists():
                time.sleep(0.05)
        yield block

s.simulate_blocks = paused
from physdyn.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow  # three simulations and two CLI start-ups: ~15 s on a busy 2-core machine
def test_two_concurrent_simulate_resume_one_refused_store_equals_an_uninterrupted_run(tmp_path, monkeypatch):
    from physdyn.data.simulated_store import generate_dataset
    from physdyn.data.store import load_store
    from tests.conftest import run_cli
    from tests.sim.test_generate import assert_same_arrays

    out, go = tmp_path / "s.zarr", tmp_path / "go"
    partial_store(out, 2, monkeypatch)
    args = ["simulate", "--config", "configs/data/quickstart.yaml", "--out", str(out), "--resume", "--quiet",
            "--workers", "1", *five_shape_overrides()]
    first = subprocess.Popen([sys.executable, "-c", PAUSED_SIMULATE, str(go), *args], cwd=REPO,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert first.stdout.readline().strip() == "paused"
        second = run_cli(*args, timeout=120)
        assert second.returncode == 2
        lines = second.stderr.strip().splitlines()
        assert len(lines) == 1 and "bug" not in lines[0] and "KeyError" not in lines[0]
        assert lines[0].startswith(f"physdyn simulate: error: {out} is being written by pid {first.pid} "
                                   f"on host {socket.gethostname()} since ")
        go.touch()
        stdout, stderr = first.communicate(timeout=300)
        assert first.returncode == 0, stderr[-2000:]
        assert "resumed: 2 blocks were already done" in stdout
    finally:
        stop(first)
    ref = tmp_path / "ref.zarr"
    generate_dataset(five_shape_config(), str(ref), progress=False, workers=1)
    assert_same_arrays(load_store(out), load_store(ref))
    assert not lock_path(out).exists()


PAUSED_FIT = """
import sys, time
from pathlib import Path
import physdyn.models.training as t
real = t._train
go = Path(sys.argv[1])

def paused(*args, **kwargs):  # the run folder's lock is held here, before training starts
    print("paused", flush=True)
    while not go.exists():
        time.sleep(0.05)
    return real(*args, **kwargs)

t._train = paused
from physdyn.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow  # two fit start-ups (torch, Lightning) and a short training: ~20 s
def test_two_fits_on_one_run_folder_one_refused_the_other_finishes(tiny_store, tmp_path):
    from physdyn.models.checkpoint_file import read_checkpoint
    from tests.conftest import run_cli
    from tests.models.conftest import QUICKSTART, shrunk_overrides

    out, go = tmp_path / "run", tmp_path / "go"
    args = ["fit", "--config", str(QUICKSTART), *shrunk_overrides(tiny_store, out, "trainer.max_steps=5")]
    first = subprocess.Popen([sys.executable, "-c", PAUSED_FIT, str(go), *args], cwd=REPO,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert first.stdout.readline().strip() == "paused"
        for extra in ([], ["--resume"], ["--overwrite"]):
            second = run_cli(*args, *extra, timeout=300)
            assert second.returncode == 2, second.stderr
            lines = second.stderr.strip().splitlines()
            assert len(lines) == 1 and f"{out} is being written by pid {first.pid} on host" in lines[0], lines
        go.touch()
        _, stderr = first.communicate(timeout=300)
        assert first.returncode == 0, stderr[-2000:]
    finally:
        stop(first)
    assert json.loads((out / "finished.json").read_text())["global_step"] == 5
    assert read_checkpoint(out / "last.ckpt")["global_step"] == 5
    assert not lock_path(out).exists() and not list(out.glob(".*"))  # no lock, no temporaries left
