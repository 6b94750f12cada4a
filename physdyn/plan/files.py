"""A plan's files: the JSON of ``plan_push`` (keys in docs/plan.md), written whole or not at all; its
one-line summary; and its viewer page, the planned push beside its PyBullet check."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from physdyn.errors import PredictionError
from physdyn.files import atomic_output, jsonable
from physdyn.predict.prediction_files import check_output_path
from physdyn.viz.viewer import Trajectory, ViewerScene, check_viewer_path, write_viewer

PLAN_EXTENSIONS = (".json",)  # a plan nests its trajectories; npz and CSV cannot


def check_plan_path(path: str | Path, overwrite: bool = False) -> Path:
    """Refuse an extension other than .json, or an existing file unless ``overwrite``, before any work."""
    return check_output_path(path, overwrite, PLAN_EXTENSIONS, what="plan")


def write_plan(result: dict[str, Any], path: str | Path, overwrite: bool = False) -> Path:
    """Write a plan as JSON, to a temporary file renamed into place (a reader never sees half a file)."""
    path = check_plan_path(path, overwrite)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(jsonable(result), indent=1))
    return path


def read_plan(path: str | Path) -> dict[str, Any]:
    return json.loads(Path(path).read_text())


def plan_summary(result: dict[str, Any]) -> str:
    """One line: the push, the predicted miss, and the check's when there is one."""
    d, goal = np.asarray(result["push_direction"]), result["goal"]
    heading = float(np.degrees(np.arctan2(d[1], d[0])))
    point = np.asarray(result["push_point"])

    def miss(outcome: dict) -> str:
        yaw = "" if outcome["miss_yaw_deg"] is None else f", {outcome['miss_yaw_deg']:.1f} deg"
        topple = ", toppled" if outcome["toppled"] else ""
        return f"{100 * outcome['miss_m']:.1f} cm{yaw}{topple} ({'met' if outcome['met'] else 'not met'})"

    line = (f"push {result['push_speed']:.2f} m/s toward {heading:.0f} deg at ({point[0]:.3f}, {point[1]:.3f}, "
            f"{point[2]:.3f}) m: predicted miss {miss(result['predicted'])}")
    if "verified" in result:
        line += f"; PyBullet check {miss(result['verified'])}"
    searched = f"{result['candidates']} candidates"
    if result.get("screened"):
        searched = f"{result.get('screened')} screened ({result.get('screen')}), {searched} by {result['model']}"
    else:
        searched += f" by {result['model']}"
    if result.get("checked"):
        searched += f", the best {result['checked']} checked by {result.get('answered_by')}"
    return line + f"; goal ({goal['xy'][0]:.3f}, {goal['xy'][1]:.3f}) m; {searched} in {result['elapsed_s']:.2f} s of {result['budget_s']:g} s"


def write_plan_viewer(result: dict[str, Any], mesh: Any, path: str | Path, overwrite: bool = False) -> Path:
    """The viewer page (docs/viewer.md): the answering model's roll-out of the planned push, beside PyBullet's check
    (with verify) as the ghost; the goal and the misses in the scene's notes. ``mesh``: the prepared body."""
    check_viewer_path(path, overwrite)
    predicted, verified = result["predicted"], result.get("verified")
    if "com_position" not in predicted:  # a plan searched with PyBullet as its model keeps no trajectory
        predicted = verified
    if predicted is None or "com_position" not in predicted:
        raise PredictionError("this plan holds no trajectory to draw; plan with its final check (the default) or pass --verify")
    p, q = np.asarray(predicted["com_position"]), np.asarray(predicted["orientation_xyzw"])
    reference = None
    if verified is not None and verified is not predicted:
        vp, vq = np.asarray(verified["com_position"]), np.asarray(verified["orientation_xyzw"])
        # the viewer plays both for as long as the longer: the shorter rests at its last pose
        T = max(len(p), len(vp))
        p, q = _hold(p, T), _hold(q, T)
        reference = Trajectory("PyBullet check", _hold(vp, T), _hold(vq, T), None, verified["toppled"])
    goal = result["goal"]
    notes = [f"goal: ({goal['xy'][0]:.3f}, {goal['xy'][1]:.3f}) m" + ("" if goal["yaw_deg"] is None else f", {goal['yaw_deg']:.1f} deg")
             + (", upright" if goal["upright"] else ""), plan_summary(result)]
    scene = ViewerScene(title=f"plan: {Path(str(result['mesh'])).name}", rate_hz=float(result["rate_hz"]),
                        vertices=np.asarray(mesh.mesh.vertices), faces=np.asarray(mesh.mesh.faces),
                        com_mesh=np.asarray(result["com_mesh"], np.float64),
                        predicted=Trajectory(f"plan ({result.get('answered_by') or result['model']})", p, q, None,
                                             predicted["toppled"]), reference=reference, notes=notes)
    return write_viewer([scene], path, title=f"physdyn plan: {Path(path).stem}", overwrite=overwrite)


def _hold(x: np.ndarray, T: int) -> np.ndarray:
    return np.concatenate([x, np.repeat(x[-1:], T - len(x), axis=0)]) if len(x) < T else x
