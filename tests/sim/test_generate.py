"""Dataset generation as a user runs it: deterministic, resumable, never overwriting, clear on bad input."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from physdyn.data.simulated_store import generate_dataset
from physdyn.data.store import PARTS, load_store
from physdyn.errors import ConfigError, StoreError
from physdyn.geometry.rotations import tilt_angle
from tests.conftest import REPO, TINY_OVERRIDES, run_cli, tiny_data_config

ARRAYS = ["points", "com_mesh", "mass", "inertia_diag", "category", "source", "shape_id", "start", "split",
          "toppled", "friction", "impulse", "impulse_point", "com_position", "orientation_xyzw",
          "linear_velocity", "angular_velocity", "topple_label"]


def assert_same_arrays(a, b):
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def parts_marked_done(parts: Path) -> int:
    """How many blocks a running `physdyn simulate` has finished (their metadata says done)."""
    import json

    count = 0
    for meta in parts.glob("*/zarr.json") if parts.exists() else []:
        try:
            count += bool(json.loads(meta.read_text()).get("attributes", {}).get("done"))
        except (ValueError, OSError):  # being written right now
            pass
    return count


def small_config(*extra):
    return tiny_data_config("families.primitives.shapes=3", "families.bottles.shapes=3", "families.mugs.shapes=2",
                            "families.trashcans.shapes=2", "families.speakers.shapes=2",
                            *[f"families.{n}.sims_per_shape=3" for n in ("primitives", "bottles", "mugs", "trashcans", "speakers")],
                            *extra)


def test_store_follows_the_conventions(tiny_store):
    d = load_store(tiny_store)
    assert d.category_names == ["primitives", "bottles", "mugs", "trashcans", "speakers"]
    assert d.points.shape == (d.num_shapes, 1024, 3) and d.points.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(d.orientation_xyzw, axis=1), 1.0, atol=1e-9)
    assert d.attrs["rate_hz"] == 15 and d.attrs["physics"]["linear_damping"] == 0.0
    np.testing.assert_allclose(d.friction, 0.25)
    # Labels agree with the 45-degree rule recomputed from the stored orientations.
    for m in range(d.num_sims):
        q = d.orientation_xyzw[d.frames(m)]
        tilted = np.degrees(tilt_angle(q[0], q)) > 45
        first = int(np.argmax(tilted)) if tilted.any() else -1
        assert d.topple_step[m] == first and d.toppled[m] == (first >= 0)
        np.testing.assert_array_equal(d.topple_label[d.frames(m)], np.arange(len(q)) >= first if first >= 0 else False)
    # Velocities agree with finite differences of positions (15 Hz: coarse, so a loose bound on the mean).
    errs = []
    for m in range(d.num_sims):
        p, v = d.com_position[d.frames(m)], d.linear_velocity[d.frames(m)]
        if len(p) > 2:
            fd = (p[2:] - p[:-2]) * 15 / 2
            errs.append(np.linalg.norm(fd - v[1:-1], axis=1).mean())
    assert np.median(errs) < 0.05
    # Splits are by shape: all pushes of one shape share it, and every split is used.
    for s in range(d.num_shapes):
        assert len(set(d.split[d.shape_id == s])) == 1
    assert set(np.unique(d.split)) == {0, 1, 2}
    # The points are in the body frame: centred near the centre of mass.
    assert np.abs(d.points.mean(axis=1)).max() < 0.1
    assert d.toppled.any() and not d.toppled.all()


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_same_arrays_whatever_the_worker_count(tmp_path):
    cfg = small_config()
    a = generate_dataset(cfg, str(tmp_path / "w1.zarr"), workers=1, progress=False)
    b = generate_dataset(cfg, str(tmp_path / "w2.zarr"), workers=2, progress=False)
    assert a.num_sims == b.num_sims == 36
    assert_same_arrays(load_store(tmp_path / "w1.zarr"), load_store(tmp_path / "w2.zarr"))


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_a_different_seed_gives_different_shapes(tmp_path):
    generate_dataset(small_config(), str(tmp_path / "a.zarr"), progress=False)
    generate_dataset(small_config("seed=1"), str(tmp_path / "b.zarr"), progress=False)
    assert not np.array_equal(load_store(tmp_path / "a.zarr").points, load_store(tmp_path / "b.zarr").points)


@pytest.mark.slow  # minutes-scale; CI runs it after the default suite
def test_killed_run_is_incomplete_then_resumes_to_identical_arrays(tmp_path):
    out = tmp_path / "killed.zarr"
    overrides = TINY_OVERRIDES + ["shapes_per_block=1", "families.speakers.sims_per_shape=60"]
    cmd = [sys.executable, "-m", "physdyn.cli", "simulate", "--config", "configs/data/quickstart.yaml",
           "--out", str(out), "--workers", "1", "--quiet", *overrides]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    parts = out / PARTS
    deadline = time.time() + 120
    while time.time() < deadline and parts_marked_done(parts) < 2 and proc.poll() is None:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert parts_marked_done(parts) >= 2, "the run was not killed mid-way (too fast or too slow?)"
    with pytest.raises(StoreError, match="incomplete"):
        load_store(out)
    done = run_cli("simulate", "--config", "configs/data/quickstart.yaml", "--out", str(out), "--resume",
                   "--workers", "2", "--quiet", *overrides, check=True)
    assert "resumed" in done.stdout
    ref = tmp_path / "ref.zarr"
    generate_dataset(tiny_data_config("shapes_per_block=1", "families.speakers.sims_per_shape=60"), str(ref), progress=False)
    assert_same_arrays(load_store(out), load_store(ref))


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_resume_survives_a_part_with_truncated_metadata(tmp_path):
    """SIGKILL can land while zarr writes a part's zarr.json; resume must redo that part, not crash."""
    import zarr

    out = tmp_path / "trunc.zarr"
    cfg = small_config("shapes_per_block=2")
    generate_dataset(cfg, str(out), progress=False)
    reference = load_store(out)
    # Rebuild the interrupted state: incomplete, one part fully written, one with truncated metadata.
    from physdyn.data.simulated_store import block_part
    from physdyn.data.store import StoreWriter
    from physdyn.sim.generate import config_hash, plan, run_block

    blocks, _ = plan(cfg)
    writer = StoreWriter.create(str(out), {"config_hash": config_hash(cfg), "rate_hz": cfg.rate_hz}, overwrite=True)
    for b in (0, 1):
        writer.write_block(b, *block_part(run_block(cfg, b, blocks[b])))
    meta = out / PARTS / "000001" / "zarr.json"
    meta.write_text(meta.read_text()[:25])
    assert writer.done_blocks(len(blocks)) == {0}
    generate_dataset(cfg, str(out), resume=True, progress=False)
    assert_same_arrays(load_store(out), reference)
    assert zarr.open_group(str(out), mode="r").attrs["complete"] is True


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_existing_store_is_never_overwritten_without_flag(tmp_path, tiny_store):
    out = tmp_path / "mine.zarr"
    cfg = small_config()
    generate_dataset(cfg, str(out), progress=False)
    before = load_store(out).com_position.copy()
    proc = run_cli("simulate", "--config", "configs/data/quickstart.yaml", "--out", str(out), "seed=5", "--quiet")
    assert proc.returncode == 2
    assert "already exists" in proc.stderr and "--overwrite" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    np.testing.assert_array_equal(load_store(out).com_position, before)
    with pytest.raises(StoreError, match="already complete"):
        generate_dataset(cfg, str(out), resume=True, progress=False)
    generate_dataset(small_config("seed=5"), str(out), overwrite=True, progress=False)
    assert not np.array_equal(load_store(out).points, load_store(tiny_store).points[: len(load_store(out).points)])


def test_overwrite_never_deletes_a_folder_that_is_not_a_store(tmp_path):
    precious = tmp_path / "thesis"
    precious.mkdir()
    (precious / "chapter1.tex").write_text("months of work")
    with pytest.raises(StoreError, match="not a physdyn store"):
        generate_dataset(small_config(), str(precious), overwrite=True, progress=False)
    assert (precious / "chapter1.tex").read_text() == "months of work"


@pytest.mark.slow  # seconds of real simulation or installs: CI's slow pass runs it
def test_ctrl_c_leaves_a_resumable_store_and_says_so(tmp_path):
    out = tmp_path / "int.zarr"
    cmd = [sys.executable, "-m", "physdyn.cli", "simulate", "--config", "configs/data/quickstart.yaml",
           "--out", str(out), "--workers", "2", "--quiet", *TINY_OVERRIDES, "shapes_per_block=1",
           "families.speakers.sims_per_shape=60"]
    # The child gets Ctrl-C's default disposition, as a shell gives it: a process that ignores SIGINT passes that
    # on to its children. In the whole slow pass something before this test leaves the test process ignoring it
    # (Lightning's trainer sets SIG_IGN when a fit is interrupted, and does not put it back), and the child would
    # run to the end (which test does it is not known: each half of the pass alone does not).
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 120
    while time.time() < deadline and (not (out / PARTS).exists() or len(list((out / PARTS).iterdir())) < 2):
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C sends to the terminal's process group
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert "--resume" in err.strip().splitlines()[-1]
    with pytest.raises(StoreError, match="incomplete"):
        load_store(out)


@pytest.mark.slow  # seconds of real simulation or installs: CI's slow pass runs it
def test_resume_with_a_different_config_is_refused(tmp_path):
    out = tmp_path / "x.zarr"
    generate_dataset(small_config(), str(out), progress=False)
    import zarr

    zarr.open_group(str(out), mode="r+").attrs["complete"] = False
    with pytest.raises(StoreError, match="different config"):
        generate_dataset(small_config("seed=9"), str(out), resume=True, progress=False)


# A real process each (~1.5 s); tests/test_bad_inputs.py checks unknown keys, steps and rates in-process, so
# the default run keeps the one case it lacks and CI's slow pass runs the others.
@pytest.mark.parametrize(
    "override, key",
    [pytest.param("physics.frobnicate=1", "physics.frobnicate", marks=pytest.mark.slow),
     pytest.param("physics.time_step=fast", "physics.time_step", marks=pytest.mark.slow),
     ("families.bottles.params.no_such=1", "families.bottles.params.no_such"),
     pytest.param("rate_hz=7", "rate_hz", marks=pytest.mark.slow)],
)
def test_bad_config_is_a_one_line_error_naming_the_key(tmp_path, override, key):
    out = tmp_path / "never.zarr"
    proc = run_cli("simulate", "--config", "configs/data/quickstart.yaml", "--out", str(out), override)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and key in lines[0], proc.stderr
    assert not out.exists()  # nothing half-written


def test_missing_config_file_and_unknown_family(tmp_path):
    proc = run_cli("simulate", "--config", "configs/data/nope.yaml", "--out", str(tmp_path / "x.zarr"))
    assert proc.returncode == 2 and "config file not found" in proc.stderr
    with pytest.raises(ConfigError, match="unknown shape family 'teapots'"):
        generate_dataset(tiny_data_config("families.teapots.shapes=1"), str(tmp_path / "y.zarr"), progress=False)


def test_mesh_folder_with_bad_files_skips_and_reports_them(tmp_path):
    import trimesh

    folder = tmp_path / "meshes"
    folder.mkdir()
    trimesh.creation.box((10.0, 8.0, 4.0)).export(folder / "box_cm.stl")
    trimesh.creation.cylinder(radius=3.0, height=12.0, sections=24).export(folder / "can_cm.obj")
    (folder / "broken.obj").write_text("v 0 0 0\nthis is not a mesh\n")
    (folder / "empty.ply").write_bytes(b"")
    out = tmp_path / "mine.zarr"
    proc = run_cli("simulate", "--config", "configs/data/meshes.yaml", "--out", str(out), "--quiet",
                   f"meshes.dir={folder}", "meshes.scale=0.01", "families.meshes.sims_per_shape=4", check=True)
    assert "skipped 2 unusable shape(s)" in proc.stdout
    assert "broken.obj" in proc.stdout and "empty.ply" in proc.stdout
    d = load_store(out)
    assert d.num_shapes == 2 and d.num_sims == 8 and d.category_names == ["meshes"]
    assert any("box_cm.stl" in s for s in d.source)
    assert 0.05 < d.points.max() - d.points.min() < 0.2  # scaled from centimetres to metres


@pytest.mark.slow  # seconds of real simulation or installs: CI's slow pass runs it
def test_a_failed_overwrite_leaves_the_old_store_exactly_as_it_was(tmp_path):
    import hashlib

    def digest(folder: Path) -> str:
        h = hashlib.sha256()
        for f in sorted(folder.rglob("*")):
            h.update(str(f.relative_to(folder)).encode())
            if f.is_file():
                h.update(f.read_bytes())
        return h.hexdigest()

    out = tmp_path / "good.zarr"
    generate_dataset(small_config(), str(out), progress=False)
    before = digest(out)
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "broken.obj").write_text("v 0 0 0\nthis is not a mesh\n")
    proc = run_cli("simulate", "--config", "configs/data/meshes.yaml", "--out", str(out), "--overwrite", "--quiet",
                   f"meshes.dir={junk}")
    assert proc.returncode == 2
    last = proc.stderr.strip().splitlines()[-1]
    assert "every shape was unusable" in last and "broken.obj" in last, proc.stderr
    assert digest(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.zarr", "junk"]  # no staged leftovers


def test_mesh_folder_not_set_is_a_clear_error(tmp_path):
    proc = run_cli("simulate", "--config", "configs/data/meshes.yaml", "--out", str(tmp_path / "m.zarr"))
    assert proc.returncode == 2 and "meshes.dir" in proc.stderr


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_voxel_mass_is_reported_against_exact(tmp_path):
    out = tmp_path / "vox.zarr"
    generate_dataset(small_config("mass.method=voxel"), str(out), progress=False)
    info = run_cli("data", "info", str(out), check=True).stdout
    assert "voxel vs exact mass error" in info
    from physdyn.data.info import summarize

    assert summarize(load_store(out))["voxel_vs_exact_mass_error"]["median"] < 0.05


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_store_at_an_fsspec_url(tmp_path):
    url = f"file://{tmp_path}/remote.zarr"
    generate_dataset(small_config(), url, progress=False)
    assert load_store(url).num_sims == 36


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_random_friction_is_recorded_and_used(tmp_path):
    out = tmp_path / "fr.zarr"
    generate_dataset(small_config("friction.random=true", "friction.min=0.1", "friction.max=0.6"), str(out), progress=False)
    d = load_store(out)
    assert d.friction.min() >= 0.1 and d.friction.max() <= 0.6 and d.friction.std() > 0.05


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_30hz_recording(tmp_path):
    out = tmp_path / "30.zarr"
    generate_dataset(small_config("rate_hz=30"), str(out), progress=False)
    d = load_store(out)
    assert d.rate_hz == 30
    ref = load_store(tmp_path / "30.zarr")
    assert np.mean(d.lengths()) > 20 and ref.num_sims == 36


@pytest.mark.ray
@pytest.mark.slow  # minutes-scale; CI runs it after the default suite
def test_ray_executor_gives_the_same_arrays(tmp_path):
    pytest.importorskip("ray")
    cfg = small_config()
    generate_dataset(cfg, str(tmp_path / "p.zarr"), progress=False)
    generate_dataset(cfg, str(tmp_path / "r.zarr"), workers=2, executor="ray", progress=False)
    assert_same_arrays(load_store(tmp_path / "p.zarr"), load_store(tmp_path / "r.zarr"))
