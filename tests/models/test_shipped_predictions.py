"""The shipped models' predictions, pinned: `fast`, `bundled` and the contact prior on a fixed set of meshes
and pushes, one at a time and batched (a batch sums in another order, and a push near a threshold may end
elsewhere: each is pinned on its own), against values stored in tests/fixtures/shipped_predictions.npz. A
change to how a predictor is built or rolled out must leave them equal to float32 round-off.

The stored values were written by this module run as a script (``python -m tests.models.test_shipped_predictions``);
rewrite them only when a prediction is meant to change, and say so in CHANGELOG.md."""

from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from physdyn.predict.predictor import contact_prior_predictor, load_predictor

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "shipped_predictions.npz"
REPO = Path(__file__).resolve().parents[2]
SECONDS = 3.0
MODELS = ("fast", "bundled", "contact_prior")
# Positions in metres and unit quaternions: a float32 roll-out summed in another order differs by ~1e-6.
ATOL = 2e-5


def meshes() -> dict[str, trimesh.Trimesh]:
    bracket = trimesh.load(REPO / "examples" / "meshes" / "bracket_mm.obj", force="mesh")
    bracket.apply_scale(0.001)
    return {
        "box": trimesh.creation.box((0.1, 0.16, 0.12)),
        "tall_box": trimesh.creation.box((0.05, 0.06, 0.2)),
        "cylinder": trimesh.creation.cylinder(radius=0.04, height=0.15, sections=24),
        "bracket": bracket,
    }


def pushes() -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) post-push linear and angular velocities: a straight slide, a spinning slide, a hard push that
    tips a tall object, and a sideways push with a tilting spin."""
    lin = np.array([[1.0, 0.0, 0.0], [0.8, 0.5, 0.0], [2.5, 0.0, 0.0], [0.0, -1.2, 0.05]])
    ang = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 6.0], [0.0, 9.0, 1.0], [-4.0, 0.5, -3.0]])
    return lin, ang


def predictors() -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {"fast": load_predictor("fast"), "bundled": load_predictor("bundled"),
                "contact_prior": contact_prior_predictor()}


def predictions(predictor, batched: bool) -> dict[str, np.ndarray]:
    """Every mesh under every push: ``com_position`` (M*P, T, 3), ``orientation_xyzw`` (M*P, T, 4),
    ``toppled`` (M*P,)."""
    lin, ang = pushes()
    requests = [(mesh, v, w) for mesh in meshes().values() for v, w in zip(lin, ang)]
    if batched:
        results = predictor.predict_many([m for m, _, _ in requests], lin_vel=np.array([v for _, v, _ in requests]),
                                         ang_vel=np.array([w for _, _, w in requests]), seconds=SECONDS)
    else:
        results = [predictor.predict(m, v, w, seconds=SECONDS) for m, v, w in requests]
    return {"com_position": np.stack([r["com_position"] for r in results]),
            "orientation_xyzw": np.stack([r["orientation_xyzw"] for r in results]),
            "toppled": np.array([bool(r["toppled"]) for r in results])}


@pytest.fixture(scope="module")
def shipped():
    return predictors()


@pytest.fixture(scope="module")
def stored():
    with np.load(FIXTURE) as data:
        return {key: data[key] for key in data.files}


@pytest.mark.parametrize("batched", [False, True], ids=["one-at-a-time", "batched"])
@pytest.mark.parametrize("model", MODELS)
def test_shipped_predictions_equal_the_stored_ones(shipped, stored, model, batched):
    got = predictions(shipped[model], batched)
    for key in ("com_position", "orientation_xyzw"):
        want = stored[f"{model}/{'batched' if batched else 'single'}/{key}"]
        assert got[key].shape == want.shape, key
        np.testing.assert_allclose(got[key], want, atol=ATOL, rtol=0, err_msg=f"{model} {key}")
    np.testing.assert_array_equal(got["toppled"], stored[f"{model}/{'batched' if batched else 'single'}/toppled"])


def test_the_pinned_set_is_not_trivial(stored):
    # the pushes must move, turn and topple something, or a broken model could match by standing still
    moved = np.linalg.norm(stored["fast/single/com_position"][:, -1, :2] - stored["fast/single/com_position"][:, 0, :2], axis=1)
    assert moved.min() > 0.05
    assert stored["fast/single/toppled"].any() and not stored["fast/single/toppled"].all()
    assert not np.allclose(stored["fast/single/com_position"], stored["bundled/single/com_position"], atol=1e-3)
    q0, q1 = stored["fast/single/orientation_xyzw"][:, 0], stored["fast/single/orientation_xyzw"][:, -1]
    assert np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(q0 * q1, axis=1)), 0, 1))).max() > 30


if __name__ == "__main__":  # write the stored values
    out = {}
    for name, predictor in predictors().items():
        for batched in (False, True):
            for key, value in predictions(predictor, batched).items():
                out[f"{name}/{'batched' if batched else 'single'}/{key}"] = value
    np.savez_compressed(FIXTURE, **out)
    print(f"wrote {FIXTURE}", file=sys.stderr)
