"""A model trained on hull_surface clouds is fed hull_surface clouds of a user's mesh at prediction time."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from physdyn.errors import ConfigError
from physdyn.models.training import fit, load_experiment_config
from physdyn.predict.body import prepare_body
from physdyn.predict.predictor import load_predictor
from tests.models.conftest import QUICKSTART, shrunk_overrides


@pytest.fixture(scope="module")
def hull_store(tiny_hull_store) -> str:
    return tiny_hull_store  # 150 pushes of hull_surface clouds, shared with the topple classifier's tests


def test_the_store_holds_hull_vertices_and_the_model_predicts_with_them(hull_store, tmp_path):
    from physdyn.data.store import load_store

    store = load_store(hull_store)
    assert store.attrs["config"]["points_method"] == "hull_surface" and store.points.shape[1] == 64
    torch.set_num_threads(1)
    run = fit(load_experiment_config(QUICKSTART, shrunk_overrides(hull_store, tmp_path / "run", "data.num_points=null",
                                                                  "trainer.max_steps=3")))
    predictor = load_predictor(str(run.last_checkpoint))
    assert predictor.points_method == "hull_surface" and predictor.num_points == 64
    box = trimesh.creation.box((0.08, 0.12, 0.2))
    result = predictor.predict(box, [1.0, 0.0, 0.0], [0.0, 0.0, 2.0], seconds=1.0)
    assert np.isfinite(result["com_position"]).all()
    corners = prepare_body(box).spec.body_vertices()  # the box's 8 corners, body frame
    cloud = prepare_body(box).points_body(64, "hull_surface")
    assert {tuple(r) for r in np.round(corners, 5)} <= {tuple(r) for r in np.round(cloud.astype(np.float64), 5)}


def test_subsampling_a_hull_surface_store_at_random_is_refused(hull_store, tmp_path):
    with pytest.raises(ConfigError, match="data.num_points.*lose hull vertices"):
        fit(load_experiment_config(QUICKSTART, shrunk_overrides(hull_store, tmp_path / "run", "data.num_points=32")))
