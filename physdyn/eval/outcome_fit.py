"""Fitting ``physdyn fit-outcome``'s correction: the model rolled out on a store's pushes (eval's roll-out),
then ``physdyn.models.outcome_correction.train_outcome_network`` per seed (with the clouds, ``--pointnet``)."""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from physdyn.data.windows import store_spin_inertia, store_world_inertia
from physdyn.errors import PhysdynError
from physdyn.eval.rollout import RolloutOptions, as_pipeline, rollout
from physdyn.geometry.rotations import quat_to_matrix, wrap_angle
from physdyn.models.outcome_correction import (EXTRA_STEPS, REST_SPEED, REST_SPIN, OutcomeCorrection, outcome_inputs,
                                               resting_state, train_outcome_network)
from physdyn.models.topple_pointnet import POINT_WIDTHS
from physdyn.pipeline.engine import Pipeline


def store_outcomes(model: Any, stores: list[Any], chunk: int = 2048,
                   progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
    """Every non-toppling push of ``stores`` rolled out by ``model`` (without any correction it holds) to
    ``EXTRA_STEPS`` past its truth's end: raw inputs (P, INPUTS), targets (P, 3) truth minus roll-out at rest,
    split (P,), shape (P,) (numbered across stores), rests (P,) whether the roll-out came to rest, frame (P, 3, 3)
    body -> the push's travel frame at step 0; and clouds (S, N, 3), the stores' body-frame clouds."""
    # The network alone: neither a correction being replaced nor a topple classifier (its probabilities move nothing)
    model = as_pipeline(model.network if isinstance(model, Pipeline) else model)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("inputs", "targets", "split", "shape", "rests", "frame")}
    if not any((s.topple_step < 0).any() for s in stores):
        raise PhysdynError("every push of the --data stores topples; the correction learns where pushes that do not "
                           "topple come to rest: fit on stores that have some")
    offset, done = 0, 0
    total = sum(int((s.topple_step < 0).sum()) for s in stores)
    for store in stores:
        sims = np.flatnonzero(store.topple_step < 0)
        lengths = store.lengths()
        for part in np.array_split(sims, max(1, -(-len(sims) // chunk))):
            if not len(part):
                continue
            first, last = store.start[part], store.start[part] + lengths[part] - 1
            q0, p0 = store.orientation_xyzw[first], store.com_position[first]
            v0, w0 = store.linear_velocity[first], store.angular_velocity[first]
            spin = store_spin_inertia(store, part, q0)
            out = rollout(model, store.points[store.shape_id[part]], q0, p0, v0, w0,
                          int(lengths[part].max()) - 1 + EXTRA_STEPS,
                          RolloutOptions(spin_inertia=spin, body_inertia=store_world_inertia(store, part, q0)))
            p, q = out.com_position[:, -1], out.orientation_xyzw[:, -1]
            v, w = out.linear_velocity[:, -1], out.angular_velocity[:, -1]
            inputs, turn = outcome_inputs(v0, w0, spin, p0, q0, p, q, v, w)
            truth = resting_state(turn, p0, q0, store.com_position[last], store.orientation_xyzw[last],
                                  store.linear_velocity[last], store.angular_velocity[last])
            target = truth[:, 3:] - inputs[:, 9:12]
            target[:, 2] = wrap_angle(target[:, 2])
            parts["inputs"].append(inputs)
            parts["targets"].append(target)
            parts["split"].append(np.asarray(store.split[part], dtype=np.int64))
            parts["shape"].append(store.shape_id[part].astype(np.int64) + offset)
            parts["frame"].append(turn @ quat_to_matrix(q0))
            parts["rests"].append((np.linalg.norm(v, axis=1) < REST_SPEED) & (np.linalg.norm(w, axis=1) < REST_SPIN))
            done += len(part)
            if progress is not None:
                progress(done, total)
        offset += store.num_shapes
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["clouds"] = np.concatenate([np.asarray(s.points, dtype=np.float32) for s in stores])
    return out


def outcome_training_data(model: Any, stores: list[Any], num_points: int | None = None,
                          progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """``store_outcomes`` with the training and validation pushes (those whose roll-out rests) picked out,
    and its clouds thinned to ``num_points`` (``thin_hull_surface``) where that is below their size
    (``thinned_from``: their size then, else 0)."""
    say = progress or (lambda _: None)
    data = store_outcomes(model, stores, progress=lambda done, total: say(f"rolled out {done}/{total} pushes"))
    usable = data["rests"]
    data["train"] = np.flatnonzero(usable & (data["split"] == 0))
    data["val"] = np.flatnonzero(usable & (data["split"] == 1))
    if not len(data["train"]) or not len(data["val"]):
        raise PhysdynError(f"{len(data['train'])} training and {len(data['val'])} validation pushes of the --data "
                           "stores come to rest without toppling in the model's roll-out; fit-outcome needs some of "
                           "both (more or longer pushes, or stores with both splits)")
    stored = int(data["clouds"].shape[1])
    data["thinned_from"] = stored if num_points is not None and num_points < stored else 0
    if data["thinned_from"]:
        from physdyn.geometry.sampling import thin_hull_surface

        data["clouds"] = np.stack([thin_hull_surface(cloud, int(num_points)) for cloud in data["clouds"]])
    return data


def fit_outcome_correction(model: Any, stores: list[Any], seeds: tuple[int, ...] = (0,), steps: int = 6000,
                           batch: int = 1024, width: int = 256, progress: Callable[[str], None] | None = None,
                           pointnet: bool = False, num_points: int | None = None, device: str = "cpu",
                           point_widths: tuple[int, ...] = POINT_WIDTHS) -> tuple[OutcomeCorrection, dict[str, Any]]:
    """One network per seed on the stores' non-toppling training pushes whose roll-out by ``model`` comes to
    rest, each chosen on the validation split's; the ensemble and a report: the median error of the resting
    position and turn on each split, the model's own and corrected. ``pointnet``: networks that also read
    each push's step-0 cloud (thinned to ``num_points``, where given), trained on ``device``."""
    say = progress or (lambda _: None)
    data = outcome_training_data(model, stores, num_points if pointnet else None, say)

    def report_to(s: int) -> Callable[[int, float], None]:
        return lambda step, error: say(f"network {s}: step {step}/{steps}, validation error {error:.3f}")

    clouds = {"clouds": data["clouds"], "shape": data["shape"], "frame": data["frame"]} if pointnet else {}
    runs = [train_outcome_network(data["inputs"], data["targets"], data["train"], data["val"], steps, batch, width, seed,
                                  report_to(seed), device=device, point_widths=point_widths, **clouds) for seed in seeds]
    correction = correction_from_runs(runs, data, width, pointnet, point_widths)
    return correction, outcome_report(correction, data)


def correction_from_runs(runs: list[dict[str, Any]], data: dict[str, Any], width: int, pointnet: bool,
                         point_widths: tuple[int, ...] = POINT_WIDTHS) -> OutcomeCorrection:
    """The ensemble of ``runs`` (one standardisation: every run's is the training split's, the same numbers)."""
    first = runs[0]
    return OutcomeCorrection([r["state_dict"] for r in runs], first["inputs_mean"], first["inputs_std"],
                             first["targets_mean"], first["targets_std"], width,
                             int(data["clouds"].shape[1]) if pointnet else 0, int(data["thinned_from"]) if pointnet else 0,
                             tuple(point_widths))


def outcome_report(correction: OutcomeCorrection, data: dict[str, Any]) -> dict[str, Any]:
    """The median error of the resting position and turn on each split, the model's own and corrected."""
    usable = data["rests"]
    report: dict[str, Any] = {"train_pushes": int(len(data["train"])), "val_pushes": int(len(data["val"])),
                              "not_at_rest": int((~usable).sum()), "splits": {}}
    for name, split in (("train", 0), ("validation", 1), ("test", 2)):
        idx = np.flatnonzero(usable & (data["split"] == split))
        if not len(idx):
            continue
        y = data["targets"][idx]
        fix = np.concatenate([correction.correction(data["inputs"][part], None if not correction.num_points else
                                                    np.einsum("bij,bnj->bni", data["frame"][part],
                                                              data["clouds"][data["shape"][part]]))
                              for part in np.array_split(idx, max(1, -(-len(idx) // 8192)))])
        rest = y - fix
        report["splits"][name] = {"pushes": int(len(idx)),
                                  "position_cm": [100 * float(np.median(np.hypot(a[:, 0], a[:, 1]))) for a in (y, rest)],
                                  "yaw_deg": [float(np.degrees(np.median(np.abs(wrap_angle(a[:, 2]))))) for a in (y, rest)]}
    return report
