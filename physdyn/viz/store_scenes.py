"""Viewer scenes of a store's sequences: the model's roll-out beside the recorded simulation.

A store keeps point clouds, not meshes, so each shape's mesh is made again from the generation config the
store records (the same family, index and seed give the same mesh; its source string and centre of mass
must match the store's, or it is not used). Where that fails (a mesh folder that moved, a store written by
another tool) the page draws the convex hull of the stored point cloud and says so.

``physdyn test`` shows, per category, the sequences with the best, median and worst final position error
(``pick_sequences``).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import trimesh

from physdyn.config import DataConfig, config_from_dict
from physdyn.data.store import StoreData
from physdyn.eval.evaluate import gather_truth, predict_rollouts
from physdyn.eval.metrics import TOPPLE_THRESHOLD
from physdyn.sim.body import rigid_body
from physdyn.sim.generate import build_family, plan, task_streams
from physdyn.viz.viewer import Trajectory, ViewerScene

COM_TOLERANCE = 1e-4  # m: a rebuilt mesh whose centre of mass moved more is not the stored shape


def _rebuild_mesh(store: StoreData, shape_id: int, cache: dict) -> Any | None:
    """The shape's mesh (mesh frame, metres) from the store's generation config, or None."""

    if "tasks" not in cache:
        try:
            cfg = config_from_dict(DataConfig, dict(store.attrs["config"]))
            blocks, _ = plan(cfg)
            cache.update(cfg=cfg, tasks=[t for block in blocks for t in block], families={})
        except Exception:  # noqa: BLE001 - any config this version cannot rebuild falls back to the hull
            cache.update(tasks=None)
    if cache["tasks"] is None:
        return None
    cfg, tasks = cache["cfg"], cache["tasks"]
    source = str(store.source[shape_id])
    skipped = len(store.attrs.get("skipped") or [])
    # Shapes are stored in task order; skipped tasks shift the ids down by at most their number.
    for index in range(shape_id, min(shape_id + skipped + 1, len(tasks))):
        task = tasks[index]
        try:
            family = cache["families"].get(task.family) or build_family(cfg, task.family)
            cache["families"][task.family] = family
            instance = family.make(task.index, np.random.default_rng(task_streams(cfg, task)[0]))
            if instance.source != source:
                continue
            # the same factory as generation, so the centre of mass matches the stored one
            body = rigid_body(instance.mesh, source, cfg.mass.density, cfg.mass.method, cfg.mass.voxel_pitch)
            mesh, props = body.mesh, body.props
        except Exception:  # noqa: BLE001 - a shape that cannot be made again is drawn as its hull
            continue
        if np.linalg.norm(np.asarray(props.com) - store.com_mesh[shape_id]) <= COM_TOLERANCE:
            return mesh
    return None


def shape_mesh(store: StoreData, shape_id: int, cache: dict | None = None) -> tuple[np.ndarray, np.ndarray, str | None]:
    """(vertices (V, 3) in mesh coordinates, faces (F, 3), a note or None) for a store's shape."""

    mesh = _rebuild_mesh(store, int(shape_id), {} if cache is None else cache)
    if mesh is not None:
        return np.asarray(mesh.vertices), np.asarray(mesh.faces), None
    points = store.points[shape_id].astype(np.float64) + store.com_mesh[shape_id]  # body frame -> mesh frame
    hull = trimesh.convex.convex_hull(points)
    return np.asarray(hull.vertices), np.asarray(hull.faces), ("The shape could not be made again from the store's "
                                                             "config; it is drawn as the convex hull of its point cloud.")


def pick_sequences(per_sequence: dict[str, list], key: str = "final.position_m") -> list[tuple[int, str]]:
    """(position in the evaluation, label) of the best, median and worst sequence of each category by
    ``key`` (an ``evaluate`` per-sequence metric; NaNs skipped)."""
    error = np.asarray(per_sequence[key], dtype=np.float64)
    category = np.asarray(per_sequence["category"])
    picked: list[tuple[int, str]] = []
    for name in dict.fromkeys(category.tolist()):  # categories in order of appearance
        idx = np.flatnonzero((category == name) & np.isfinite(error))
        if not len(idx):
            continue
        order = idx[np.argsort(error[idx], kind="stable")]
        choices = {"best": order[0], "median": order[(len(order) - 1) // 2], "worst": order[-1]}
        seen: set[int] = set()
        for label, i in choices.items():
            if int(i) not in seen:
                seen.add(int(i))
                picked.append((int(i), f"{name}: {label}"))
    return picked


def store_scenes(store: StoreData, sims: Sequence[int], predicted: Any, truth: dict[str, np.ndarray],
                 positions: Sequence[int], labels: Sequence[str], prediction_label: str = "prediction") -> list[ViewerScene]:
    """Scenes for ``positions`` (indices into ``sims``, the evaluated simulations) from a roll-out
    (``RolloutResult``) and the truth it was scored on (``gather_truth``), each cut to its real length."""
    cache: dict = {}
    scenes = []
    for pos, label in zip(positions, labels):
        sim = int(sims[pos])
        last = int(truth["last"][pos])
        shape = int(store.shape_id[sim])
        vertices, faces, note = shape_mesh(store, shape, cache)
        prob = None if predicted.topple_probability is None else predicted.topple_probability[pos, : last + 1]
        toppled_pred = None if prob is None else bool(np.any(prob >= TOPPLE_THRESHOLD))
        p = predicted.com_position[pos, : last + 1]
        q = predicted.orientation_xyzw[pos, : last + 1]
        err = float(np.linalg.norm(p[-1] - truth["com_position"][pos, last]))
        title = f"{label} (sim {sim}, final position error {100 * err:.2f} cm)"
        scenes.append(ViewerScene(
            title=title, rate_hz=store.rate_hz, vertices=vertices, faces=faces, com_mesh=store.com_mesh[shape],
            predicted=Trajectory(prediction_label, p, q, prob, toppled_pred),
            reference=Trajectory("simulation", truth["com_position"][pos, : last + 1],
                                 truth["orientation_xyzw"][pos, : last + 1], None, bool(truth["toppled"][pos])),
            notes=[note] if note else [],
        ))
    return scenes


def rollout_scenes(model: Any, store: StoreData, sims: Sequence[int], seed: int = 0) -> list[ViewerScene]:
    """Roll ``model`` out on the given simulations (as ``physdyn test`` does, these alone) and make their scenes."""

    sims = np.asarray(sims, dtype=np.int64)
    truth = gather_truth(store, sims)
    predicted = predict_rollouts(model, store, sims, truth, seed=seed)
    category = store.sim_category()[sims]
    labels = [store.category_names[c] if c < len(store.category_names) else str(c) for c in category]
    return store_scenes(store, sims, predicted, truth, range(len(sims)), labels)
