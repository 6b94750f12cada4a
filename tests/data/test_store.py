"""Corrupt, missing or foreign stores are refused with the fix in the message."""

import shutil

import numpy as np
import pytest
import zarr

from physdyn.data.store import load_store
from physdyn.errors import StoreError
from tests.conftest import run_cli


def test_missing_store(tmp_path):
    with pytest.raises(StoreError, match="no dataset store"):
        load_store(tmp_path / "nothing.zarr")
    proc = run_cli("data", "info", str(tmp_path / "nothing.zarr"))
    assert proc.returncode == 2 and "physdyn simulate" in proc.stderr


def test_foreign_zarr_group_is_not_a_store(tmp_path):
    zarr.open_group(str(tmp_path / "other.zarr"), mode="w").create_array("x", data=np.arange(3))
    with pytest.raises(StoreError, match="not a physdyn dataset store"):
        load_store(tmp_path / "other.zarr")


def test_missing_array_is_corrupt(tmp_path, tiny_store):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(tiny_store, copy)
    shutil.rmtree(copy / "frames" / "linear_velocity")  # the consolidated metadata still lists it
    with pytest.raises(StoreError, match="corrupt.*linear_velocity"):
        load_store(copy)


def test_lost_chunk_is_corrupt(tmp_path, tiny_store):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(tiny_store, copy)
    chunk = next(p for p in (copy / "frames" / "com_position" / "c").rglob("*") if p.is_file())
    chunk.unlink()  # zarr would read fill values here without complaint
    with pytest.raises(StoreError, match="com_position does not match its checksum"):
        load_store(copy)


def test_inconsistent_offsets_are_corrupt(tmp_path, tiny_store):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(tiny_store, copy)
    g = zarr.open_group(str(copy), mode="r+", use_consolidated=False)
    start = g["sims/start"][...]
    start[-1] += 5
    g["sims/start"][...] = start
    with pytest.raises(StoreError, match="sims/start"):
        load_store(copy)


def test_data_info_summarises(tiny_store):
    out = run_cli("data", "info", tiny_store, check=True).stdout
    for word in ("primitives", "bottles", "mugs", "trashcans", "speakers", "topple", "v0", "physics"):
        assert word in out
    js = run_cli("data", "info", tiny_store, "--json", check=True).stdout
    import json

    summary = json.loads(js)
    assert summary["sims"] == 150 and summary["shapes"] == 25


@pytest.mark.slow  # seconds of real simulation or installs: CI's slow pass runs it
def test_contact_noise_statistic_tells_a_coarse_physics_step_from_the_conventions_one(tiny_store, tmp_path):
    # The same pushes simulated at PyBullet's usual 1/240 s chatter: the statistic must see it, and
    # `data info` must call that store noisy and the conventions' 1/960 s one faithful.
    from physdyn.data.info import FAITHFUL_CHATTER, tilt_chatter
    from physdyn.data.simulated_store import generate_dataset
    from tests.conftest import tiny_data_config

    coarse = tmp_path / "coarse.zarr"
    generate_dataset(tiny_data_config("physics.time_step=0.004166666666666667"), str(coarse), progress=False)
    fine_store, coarse_store = load_store(tiny_store), load_store(str(coarse))
    assert fine_store.attrs["physics"]["time_step"] == pytest.approx(1 / 960)
    fine, noisy = tilt_chatter(fine_store), tilt_chatter(coarse_store)
    assert fine < FAITHFUL_CHATTER < noisy and noisy > 3 * fine, (fine, noisy)
    assert "faithful" in run_cli("data", "info", tiny_store, check=True).stdout
    assert "NOISY" in run_cli("data", "info", str(coarse), check=True).stdout
