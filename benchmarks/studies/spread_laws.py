"""Which inputs and which shape should the ``calibrated`` distribution stage's spread take?
(docs/research/spread-laws.md)

    python -m benchmarks.studies.spread_laws --calibrate data/ensemble_calibrate.zarr --test data/ensemble_eval.zarr

1. Inputs: the power laws fitted on the calibration store's first two thirds of shapes and scored on the rest
   (the store lists its pushes shape by shape), with each set of inputs: travel, turn and speed of the
   roll-out, and fewer.
2. Shape: the fitted laws' standard deviations with Gaussian, Laplace and Student-t draws (each scaled to that
   standard deviation, and at 0.7 of it), scored on the test split of the evaluation store.
3. Toppled poses: the shipped forecast's samples drawn as toppled, left in the roll-out's upright pose or tipped
   by 90 degrees about the axis across the travel (the top falling forward, or back), scored by the energy
   score of the final orientation on the same test split (``physdyn test``'s forecast).

Scores per component (along and across the travel, cm; the turn, degrees), over the upright members (the
laws compared are theirs; a toppled draw has a law of its own): the mean fair CRPS of the component's draws
against the members (1-D energy score), and how many members the central 90 % holds.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
from scipy.stats import norm

from physdyn.data.store import load_store
from physdyn.eval.distribution_eval import evaluate_distribution
from physdyn.eval.evaluate import select_sequences
from physdyn.eval.scores import score_pushes
from physdyn.geometry.rotations import quat_multiply
from physdyn.pipeline.spread import COMPONENTS, outcome_frame
from physdyn.pipeline.spread_fit import fit_spread, outcome_residuals
from physdyn.predict.predictor import load_predictor

UNITS = np.array([100.0, 100.0, np.degrees(1.0)])  # m, m, rad -> cm, cm, degrees
INPUTS = {"travel, turn, speed": [0, 1, 2, 3], "travel, turn (shipped)": [0, 1, 2], "turn, speed": [0, 2, 3],
          "travel": [0, 1], "speed": [0, 3], "constant": [0]}
DRAWS = 400


def with_speed(data: dict, lin_vel: np.ndarray) -> dict:
    """``outcome_residuals`` with a fourth input: log(push speed + 0.1 m/s)."""
    speed = np.linalg.norm(lin_vel[:, :2], axis=1)
    return {**data, "features": np.concatenate([data["features"], np.log(speed + 0.1)[:, None]], axis=1)}


def subset(data: dict, rows: np.ndarray, cols: list[int]) -> dict:
    return {"features": data["features"][rows][:, cols], "residual": data["residual"][rows],
            "upright": data["upright"][rows], "scale": data["scale"]}


def sigmas(config, data: dict) -> np.ndarray:
    """(P, 3) an upright outcome's standard deviations under the fitted laws (any number of inputs)."""
    push, model = np.asarray(config.push), np.asarray(config.model)
    return np.sqrt((np.exp(data["features"] @ push.T) * data["scale"]) ** 2 + np.exp(data["features"] @ model.T) ** 2)


def scores(draws: np.ndarray, data: dict) -> tuple[np.ndarray, np.ndarray]:
    """draws (P, D, 3) of each component -> (3,) mean fair CRPS and (3,) the central 90 %'s coverage."""
    crps, held = np.zeros(3), np.zeros(3)
    for c in range(len(COMPONENTS)):
        x, y = draws[..., c], data["residual"][..., c]
        counted = data["upright"]  # the laws compared are the upright members'
        near = np.abs(x[:, :, None] - y[:, None, :]).mean(axis=1)
        spread = np.abs(x[:, :, None] - x[:, None, :]).sum(axis=(1, 2)) / (x.shape[1] * (x.shape[1] - 1))
        crps[c] = (near - 0.5 * spread[:, None])[counted].mean()
        lo, hi = np.quantile(x, [0.05, 0.95], axis=1)
        held[c] = ((y >= lo[:, None]) & (y <= hi[:, None]))[counted].mean()
    return crps * UNITS, held


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--calibrate", default="data/ensemble_calibrate.zarr")
    ap.add_argument("--test", default="data/ensemble_eval.zarr")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    predictor = load_predictor("fast")
    rng = np.random.default_rng(0)

    cal = load_store(args.calibrate)
    sims = np.arange(cal.num_sims)
    data = with_speed(outcome_residuals(predictor.model, cal, sims), cal.linear_velocity[cal.start[sims]])
    shapes = cal.shape_id[sims]
    fit_rows = shapes < np.quantile(np.unique(shapes), 2 / 3)
    print(f"1. inputs: fitted on {fit_rows.sum()} pushes, scored on {(~fit_rows).sum()} pushes of other shapes "
          f"({args.calibrate})\n")
    print("| inputs | CRPS along (cm) | across (cm) | turn (deg) | 90 % holds: along | across | turn |\n|---|---|---|---|---|---|---|")
    for name, cols in INPUTS.items():
        config = fit_spread([subset(data, fit_rows, cols)])
        held_out = subset(data, ~fit_rows, cols)
        draws = rng.standard_normal((len(held_out["features"]), DRAWS, 3)) * sigmas(config, held_out)[:, None]
        crps, held = scores(draws, held_out)
        print(f"| {name} | " + " | ".join(f"{v:.2f}" for v in crps) + " | " + " | ".join(f"{v:.2f}" for v in held) + " |")

    test = load_store(args.test)
    sims = select_sequences(test, "test")
    data = outcome_residuals(predictor.model, test, sims)
    stage = predictor.model.distribution
    sigma = stage.sigmas(data["features"], data["scale"])[:, None]
    P = len(sims)
    shapes = {"Gaussian": lambda: rng.standard_normal((P, DRAWS, 3)),
              "Laplace": lambda: rng.laplace(size=(P, DRAWS, 3)) / np.sqrt(2.0),
              "Student-t, 5 dof": lambda: rng.standard_t(5, size=(P, DRAWS, 3)) / np.sqrt(5 / 3),
              "Student-t, 3 dof": lambda: rng.standard_t(3, size=(P, DRAWS, 3)) / np.sqrt(3.0)}
    print(f"\n2. shape: the shipped laws on {P} pushes of the test split ({args.test})\n")
    print("| draws | scale | CRPS along (cm) | across (cm) | turn (deg) | 90 % holds: along | across | turn |\n"
          "|---|---|---|---|---|---|---|---|")
    for name, draw in shapes.items():
        unit = draw()
        for scale in (1.0, 0.7):
            crps, held = scores(unit * sigma * scale, data)
            print(f"| {name} | {scale:g} | " + " | ".join(f"{v:.2f}" for v in crps) + " | "
                  + " | ".join(f"{v:.2f}" for v in held) + " |")
    print(f"\n(a Gaussian's central 90 %: +-{norm.ppf(0.95):.3f} standard deviations)")
    toppled_poses(predictor.model, test)


def toppled_poses(pipeline, store) -> None:
    """Part 3: the forecast's toppled samples upright, or tipped forward or back by 90 degrees."""
    result = evaluate_distribution(pipeline, store, samples=32, keep_samples=True)
    kept = result["trajectories"]
    forecast, members, first = kept["forecast"], kept["members"], store.start[kept["sims"]]
    p, q = forecast["com_position"], forecast["orientation_xyzw"][:, :, -1]
    nominal = kept["deterministic"]
    along = outcome_frame(nominal["com_position"][:, 0], nominal["orientation_xyzw"][:, 0], store.linear_velocity[first])["along"]
    across = np.stack([-along[:, 1], along[:, 0], np.zeros(len(along))], axis=1)
    print(f"\n3. toppled poses: {forecast['toppled'].mean():.2f} of the samples drawn as toppled, {members['toppled'].mean():.2f} "
          "of the members toppled\n")
    print("| toppled samples | ES final orientation (deg) |\n|---|---|")
    for name, angle in (("upright (shipped)", 0.0), ("tipped forward", np.pi / 2), ("tipped back", -np.pi / 2)):
        tip = np.concatenate([across * np.sin(angle / 2), np.full((len(along), 1), np.cos(angle / 2))], axis=1)
        posed = np.where(forecast["toppled"][..., None], quat_multiply(np.repeat(tip[:, None], q.shape[1], axis=1), q), q)
        scores = score_pushes(p[:, :, -1, :2] - p[:, :, 0, :2], members["displacement_xy"], posed,
                              members["orientation_xyzw"], forecast["topple_probability"], members["toppled"]).mean
        print(f"| {name} | {scores['orientation_es_deg']:.1f} |")


if __name__ == "__main__":
    main()
