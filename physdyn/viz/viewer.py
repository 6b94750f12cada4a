"""An interactive page of predicted vs simulated motion: one self-contained HTML file, no server, no network.

plotly.js draws (WebGL 3D with orbit and zoom, a time plot below); it is embedded in the page, so a double
click opens it anywhere. A small script of ours (``viewer.js`` beside this module) poses the mesh at the
step under the time slider: the page carries each mesh once and each trajectory as in the prediction
file, not one mesh copy per frame, which keeps a 15-scene report page to a few MB beyond plotly.js.

The embedded data (``<script type="application/json" id="physdyn-data">``) holds, per scene, the mesh in
mesh coordinates and ``com_mesh``, and the trajectories with the prediction file's keys
(``com_position``, ``orientation_xyzw``, ``topple_probability``, ``toppled``): a mesh vertex x is drawn at
R (x - com_mesh) + com_position, as the conventions say. A scene of a distribution (``predict_distribution``)
also holds ``fan``: ``com_position`` (N, T, 3) and ``orientation_xyzw`` (N, T, 4) of its N samples, drawn as
their paths and their final poses (translucent), beside its central sample; its ``predicted`` topple
probability is the distribution's. ``read_viewer_data`` reads it back.
"""

from __future__ import annotations

import html
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from plotly.offline import get_plotlyjs

from physdyn.errors import PhysdynError
from physdyn.files import atomic_output
from physdyn.predict.prediction_files import check_output_path
from physdyn.viz.meshes import decimate, mesh_to_draw

VIEWER_EXTENSIONS = (".html",)
MAX_FACES = 800  # per mesh: orbiting stays smooth in software WebGL, shapes stay recognisable
_SCRIPT = Path(__file__).with_name("viewer.js")
_DATA_ID = "physdyn-data"


class ViewerError(PhysdynError):
    """A viewer page that cannot be built (no scenes, unreadable page, mismatched trajectories)."""


@dataclass
class Trajectory:
    """One motion of the object: (T, 3) centre-of-mass positions and (T, 4) orientations (x, y, z, w)."""

    label: str
    com_position: np.ndarray
    orientation_xyzw: np.ndarray
    topple_probability: np.ndarray | None = None
    toppled: bool | None = None

    def as_json(self) -> dict[str, Any]:
        prob = self.topple_probability
        return {
            "label": self.label,
            "com_position": _rounded(self.com_position),
            "orientation_xyzw": _rounded(self.orientation_xyzw),
            "topple_probability": None if prob is None else _rounded(prob),
            "toppled": None if self.toppled is None else bool(self.toppled),
        }


@dataclass
class ViewerScene:
    """A mesh (mesh coordinates, ``com_mesh`` its centre of mass there) moving along ``predicted``, beside
    ``reference`` (the simulation or the recorded truth, drawn as a ghost) when there is one."""

    title: str
    rate_hz: float
    vertices: np.ndarray
    faces: np.ndarray
    com_mesh: np.ndarray
    predicted: Trajectory
    reference: Trajectory | None = None
    notes: list[str] = field(default_factory=list)
    fan: dict[str, np.ndarray] | None = None  # a distribution's samples: com_position (N, T, 3), orientation_xyzw (N, T, 4)

    def as_json(self) -> dict[str, Any]:
        vertices, faces = decimate(np.asarray(self.vertices, np.float64), np.asarray(self.faces, np.int64), MAX_FACES)
        used = np.unique(faces)  # a decimated face subset leaves vertices no face uses
        remap = np.full(len(vertices), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        vertices, faces = vertices[used], remap[faces]
        trajectories = [self.predicted] + ([self.reference] if self.reference is not None else [])
        for traj in trajectories:
            _check_trajectory(traj, self.title)
        return {
            "title": self.title,
            "rate_hz": float(self.rate_hz),
            "mesh": {"vertices": _rounded(vertices), "faces": np.asarray(faces, int).tolist()},
            "com_mesh": _rounded(self.com_mesh),
            "bounds": _bounds(vertices, np.asarray(self.com_mesh, np.float64), trajectories + self._fan_points()),
            "predicted": self.predicted.as_json(),
            "reference": None if self.reference is None else self.reference.as_json(),
            "notes": list(self.notes),
            "fan": None if self.fan is None else {k: _rounded(v) for k, v in self.fan.items()},
        }

    def _fan_points(self) -> list[Trajectory]:
        """Every state of the samples as one trajectory, so the page's bounds hold their paths."""
        if self.fan is None:
            return []
        return [Trajectory("samples", self.fan["com_position"].reshape(-1, 3), self.fan["orientation_xyzw"].reshape(-1, 4))]


def _rounded(x: Any, digits: int = 6) -> Any:
    """Micrometre / micro-radian precision: the page stays small and matches the file to 1e-6."""
    return np.round(np.asarray(x, np.float64), digits).tolist()


def _check_trajectory(traj: Trajectory, title: str) -> None:
    p, q = np.asarray(traj.com_position), np.asarray(traj.orientation_xyzw)
    if p.ndim != 2 or p.shape[1] != 3 or q.shape != (len(p), 4) or len(p) == 0:
        raise ViewerError(f"scene '{title}': the {traj.label} trajectory needs com_position (T, 3) and "
                          f"orientation_xyzw (T, 4), got {p.shape} and {q.shape}")
    if not (np.isfinite(p).all() and np.isfinite(q).all()):
        raise ViewerError(f"scene '{title}': the {traj.label} trajectory holds NaN or infinite values")


def _bounds(vertices: np.ndarray, com_mesh: np.ndarray, trajectories: Sequence[Trajectory]) -> dict[str, list[float]]:
    """One cube holding every pose (ground at z = 0 included), so the camera never has to move."""
    radius = float(np.linalg.norm(vertices - com_mesh, axis=1).max())
    coms = np.concatenate([np.asarray(t.com_position, np.float64) for t in trajectories])
    lo = np.minimum(coms.min(axis=0) - radius, [np.inf, np.inf, 0.0])
    hi = coms.max(axis=0) + radius
    centre, half = (lo + hi) / 2, float((hi - lo).max()) / 2 * 1.1
    lo, hi = centre - half, centre + half
    lo[2], hi[2] = 0.0, 2 * half
    return {"lo": _rounded(lo), "hi": _rounded(hi)}


def scene_from_prediction(result: dict[str, Any], mesh: Any, title: str | None = None) -> ViewerScene:
    """A scene from a prediction (``Predictor.predict``'s dict or ``read_prediction``'s) and its mesh (a
    path, a ``trimesh.Trimesh`` or a ``PreparedBody``, at the scale it was predicted at)."""

    m = mesh_to_draw(mesh, 1.0)
    if result.get("kind") == "distribution":
        return _distribution_scene(result, m, title)
    sim = result.get("simulated")
    name = title or Path(str(result.get("mesh", "prediction"))).name
    return ViewerScene(
        title=name,
        rate_hz=float(result["rate_hz"]),
        vertices=np.asarray(m.vertices), faces=np.asarray(m.faces),
        com_mesh=np.asarray(result["com_mesh"], np.float64),
        predicted=Trajectory("prediction", result["com_position"], result["orientation_xyzw"],
                             result.get("topple_probability"), result.get("toppled")),
        reference=None if not sim else Trajectory("simulation", sim["com_position"], sim["orientation_xyzw"],
                                                  None, sim.get("toppled")),
    )


def _distribution_scene(result: dict[str, Any], m: Any, title: str | None) -> ViewerScene:
    """A distribution's scene: its central sample (the one ending nearest the mean final position) moves under
    the slider, with the distribution's topple probability, and the fan of all samples."""
    p, q = np.asarray(result["com_position"], np.float64), np.asarray(result["orientation_xyzw"], np.float64)
    central = int(np.argmin(np.linalg.norm(p[:, -1] - p[:, -1].mean(axis=0), axis=1)))
    probability = np.asarray(result["topple_probability"], np.float64)
    return ViewerScene(
        title=title or Path(str(result.get("mesh", "distribution"))).name,
        rate_hz=float(result["rate_hz"]),
        vertices=np.asarray(m.vertices), faces=np.asarray(m.faces),
        com_mesh=np.asarray(result["com_mesh"], np.float64),
        predicted=Trajectory("central sample", p[central], q[central], probability, None),
        notes=[f"{len(p)} sampled pushes ({result.get('checkpoint', 'model')}): their paths and final poses are "
               f"drawn translucent; topple probability {probability[-1]:.2f} by the end."],
        fan={"com_position": p, "orientation_xyzw": q},
    )


def check_viewer_path(path: str | Path, overwrite: bool = False) -> Path:
    return check_output_path(path, overwrite, VIEWER_EXTENSIONS, what="viewer page")


def viewer_html(scenes: Sequence[ViewerScene], title: str = "physdyn viewer") -> str:
    """The page's text: plotly.js, our script and the scenes' data, all inline."""
    if not scenes:
        raise ViewerError("a viewer page needs at least one scene")
    data = json.dumps({"title": title, "scenes": [s.as_json() for s in scenes]}, separators=(",", ":"))
    data = data.replace("</", "<\\/")  # a mesh path holding "</script>" must not end the data block
    return _PAGE.format(title=html.escape(title), plotly=get_plotlyjs(), script=_SCRIPT.read_text(),
                        data=data, data_id=_DATA_ID)


def write_viewer(scenes: Sequence[ViewerScene], path: str | Path, title: str = "physdyn viewer",
                 overwrite: bool = False) -> Path:
    """Write the page for ``scenes`` to ``path`` (.html) in one rename: no half-written page is left."""

    path = check_viewer_path(path, overwrite)
    text = viewer_html(scenes, title)
    with atomic_output(path, suffix=".html") as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def read_viewer_data(path: str | Path) -> dict[str, Any]:
    """The data embedded in a viewer page: {"title", "scenes": [scene dicts as described above]}."""
    text = Path(path).read_text(encoding="utf-8")
    match = re.search(rf'<script type="application/json" id="{_DATA_ID}">(.*?)</script>', text, re.S)
    if not match:
        raise ViewerError(f"{path} is not a physdyn viewer page (no embedded data); write one with `physdyn view`")
    return json.loads(match.group(1).replace("<\\/", "</"))


_PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>
  body {{ font-family: system-ui, sans-serif; margin: 0; color: #222; background: #fafafa; }}
  header {{ padding: 8px 14px; display: flex; gap: 14px; align-items: center; flex-wrap: wrap; border-bottom: 1px solid #ddd; background: #fff; }}
  header h1 {{ font-size: 16px; margin: 0; }}
  #controls {{ display: flex; gap: 10px; align-items: center; padding: 6px 14px; flex-wrap: wrap; }}
  #slider {{ flex: 1 1 300px; }}
  #readout {{ font-variant-numeric: tabular-nums; font-size: 13px; min-width: 28em; }}
  #notes {{ font-size: 12px; color: #666; padding: 0 14px; }}
  button {{ font-size: 14px; min-width: 5em; }}
  .legend {{ font-size: 12px; }}
  .swatch {{ display: inline-block; width: 10px; height: 10px; margin: 0 4px 0 10px; border-radius: 2px; }}
</style>
</head>
<body>
<header>
  <h1 id="title">{title}</h1>
  <label>scene <select id="scene"></select></label>
  <span class="legend" id="legend"></span>
</header>
<div id="controls">
  <button id="play" type="button">Play</button>
  <input id="slider" type="range" min="0" max="0" value="0" step="1" aria-label="time step">
  <span id="readout"></span>
</div>
<div id="notes"></div>
<div id="view3d"></div>
<div id="plot2d"></div>
<script>{plotly}</script>
<script type="application/json" id="{data_id}">{data}</script>
<script>{script}</script>
</body>
</html>
"""
