"""Predicting how a user's mesh moves after a push, and writing the prediction file.

``load_predictor()`` gives a ``Predictor`` around a trained ``DynamicsModel`` (the bundled one by default);
``Predictor.predict(mesh, lin_vel, ang_vel, seconds)`` places the object at rest on the ground as the
conventions say (docs/conventions.md, "Initial condition"), rolls the model out and returns a dict with
the keys of a prediction file ("Prediction output"). ``compare_sim=True`` adds the same keys from PyBullet,
started from the same state, under ``simulated``. ``write_prediction`` writes JSON, .npz or .csv (layout:
docs/predict.md); ``read_prediction`` reads any of the three back.

Arrays in a result are float64 numpy arrays: T = round(seconds * rate_hz) + 1 steps, step 0 included.
"""

from __future__ import annotations

import json
import math
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from physdyn.errors import PhysdynError
from physdyn.files import atomic_output, check_writable, jsonable

BUNDLED_CHECKPOINT = Path(__file__).resolve().parents[1] / "assets" / "bundled.ckpt"
OUTPUT_EXTENSIONS = (".json", ".npz", ".csv")
STEP_KEYS = ("time", "com_position", "orientation_xyzw", "linear_velocity", "angular_velocity", "topple_probability")
SCALAR_KEYS = ("rate_hz", "toppled", "com_mesh", "mesh", "mesh_scale", "checkpoint")
# CSV column suffixes of the per-step vectors.
_COMPONENTS = {"com_position": "xyz", "orientation_xyzw": "xyzw", "linear_velocity": "xyz", "angular_velocity": "xyz"}
_CSV_COLUMN_BASE = {"orientation_xyzw": "orientation"}
DEFAULT_NUM_POINTS = 1024
POINTS_SEED = 0  # fixed: the same mesh always gets the same cloud, so predictions are reproducible
SIMULATOR_NAME = "pybullet"
IN_MEMORY = "<in-memory>"
MAX_LINEAR_SPEED = 50.0  # m/s; training pushes are 0.5-2 m/s
MAX_ANGULAR_SPEED = 500.0  # rad/s
MAX_SECONDS = 600.0  # a pushed object rests within seconds; far longer only allocates
_CSV_SCALAR = re.compile(r"^# ([A-Za-z_]+): (.*)$")  # "# rate_hz: 15.0": a scalar key and its JSON value


class PredictionError(PhysdynError):
    """Bad input to a prediction: a vector, a duration, an output path."""


class PredictionWarning(UserWarning):
    """Something the user should know about a prediction that still runs (e.g. an open mesh)."""


# --------------------------------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------------------------------
def as_vector(value: Any, name: str, length: int = 3) -> np.ndarray:
    """``value`` as a finite float64 vector of ``length``; a one-line ``PredictionError`` naming ``name``."""
    try:
        vec = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise PredictionError(f"{name} must be {length} numbers, got {value!r}") from None
    if np.ndim(value) > 1 or vec.size != length:
        raise PredictionError(f"{name} must be {length} numbers, got {vec.size} ({_short(value)})")
    if not np.isfinite(vec).all():
        raise PredictionError(f"{name} must be finite, got {_short(value)}; pass {length} real numbers")
    return vec


def check_seconds(seconds: Any) -> float:
    try:
        s = float(seconds)
    except (TypeError, ValueError):
        raise PredictionError(f"seconds must be a number, got {seconds!r}") from None
    if not math.isfinite(s) or s <= 0:
        raise PredictionError(f"seconds must be a positive number, got {seconds!r}; e.g. --seconds 3")
    if s > MAX_SECONDS:
        raise PredictionError(f"seconds must be at most {MAX_SECONDS:g} (objects come to rest within a few), got {seconds!r}")
    return s


def check_orientation(orientation_xyzw: Any) -> np.ndarray:
    """Unit quaternion (x, y, z, w) from ``orientation_xyzw``; identity (the mesh frame as is) for None."""
    if orientation_xyzw is None:
        return np.array([0.0, 0.0, 0.0, 1.0])
    q = as_vector(orientation_xyzw, "orientation (x, y, z, w)", 4)
    norm = float(np.linalg.norm(q))
    if norm < 1e-9:
        raise PredictionError("orientation (x, y, z, w) is the zero quaternion; pass a rotation, e.g. 0 0 0 1")
    return q / norm


def check_output_path(path: str | Path, overwrite: bool = False, extensions: Sequence[str] = OUTPUT_EXTENSIONS,
                      what: str = "output") -> Path:
    """Refuse an unsupported extension, or an existing file unless ``overwrite``, before any work is done."""
    path = Path(path).expanduser()
    ext = path.suffix.lower()
    if ext not in extensions:
        raise PredictionError(f"{what} {path}: unsupported extension '{ext or '(none)'}'; use one of {', '.join(extensions)}")
    if path.is_dir():
        raise PredictionError(f"{what} {path} is a folder; pass a file name such as {path / ('prediction' + extensions[0])}")
    if path.exists() and not overwrite:
        raise PredictionError(f"{what} {path} already exists; pass --overwrite (overwrite=True) to replace it")
    check_writable(path, what)
    return path


def _per_request(value: Any, count: int, name: str, length: int = 3) -> np.ndarray:
    """(count, length) finite float64 from one vector for every request or one row per request."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise PredictionError(f"{name}: expected {length} numbers or {count} rows of {length}, got {_short(value)}") from None
    if arr.shape == (length,):
        return np.tile(as_vector(arr, name, length), (count, 1))
    if arr.shape != (count, length):
        raise PredictionError(f"{name}: expected {length} numbers or {count} rows of {length}, got shape {arr.shape}")
    for i, row in enumerate(arr):
        as_vector(row, f"{name} of request {i + 1}", length)
    return arr


def _per_request_values(value: Any, count: int, name: str) -> list:
    """One scalar for all requests, or a sequence of ``count``."""
    if isinstance(value, (str, bytes)) or np.ndim(value) == 0:
        return [value] * count
    values = list(value)
    if len(values) != count:
        raise PredictionError(f"{name}: expected one value or {count}, got {len(values)}")
    return values


def _boolean(value: Any, name: str) -> bool:
    """A real boolean: the strings "no" or "false" are not read as true."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise PredictionError(f"{name} must be true or false, got {value!r}")


def _short(value: Any) -> str:
    text = " ".join(str(v) for v in np.ravel(value)) if np.ndim(value) else str(value)
    return text if len(text) <= 60 else text[:57] + "..."


# --------------------------------------------------------------------------------------------------
# The object
# --------------------------------------------------------------------------------------------------
@dataclass
class PreparedBody:
    """A mesh made into a rigid body: cleaned mesh (mesh frame, metres), its ``RigidBodySpec`` and where it
    came from. ``notes``: one-line warnings (e.g. the convex hull was used for the mass properties)."""

    mesh: Any
    spec: Any
    name: str
    notes: list[str] = field(default_factory=list)
    scale: float = 1.0  # applied to the file's coordinates to get metres
    _points: dict[int, np.ndarray] = field(default_factory=dict, repr=False)

    def points_body(self, num_points: int) -> np.ndarray:
        """(num_points, 3) float32 surface points in the body frame (mesh axes, origin at the com)."""
        if num_points not in self._points:
            from physdyn.config import DataConfig
            from physdyn.geometry.sampling import sample_surface_points

            pts = sample_surface_points(self.mesh, num_points, DataConfig().oversample, seed=POINTS_SEED)
            self._points[num_points] = (pts - self.spec.com_mesh).astype(np.float32)
        return self._points[num_points]


def prepare_body(mesh: Any, scale: float = 1.0, density: float | None = None) -> PreparedBody:
    """A mesh file path or ``trimesh.Trimesh`` -> ``PreparedBody``. Exact mass properties of the solid, or
    of its convex hull (with a note) when the mesh is not a closed volume. Raises ``ShapeError``."""
    import trimesh

    from physdyn.config import MassConfig
    from physdyn.errors import ShapeError
    from physdyn.geometry.mass import solid_mass_properties
    from physdyn.geometry.mesh_io import check_mesh, load_mesh, prepare_mesh
    from physdyn.sim.body import RigidBodySpec

    if isinstance(mesh, PreparedBody):
        return mesh
    if isinstance(mesh, trimesh.Trimesh):
        if not np.isfinite(scale) or scale <= 0:
            raise ShapeError(f"mesh {IN_MEMORY}: scale must be a positive number, got {scale}")
        name = IN_MEMORY
        raw = mesh.copy()
        if scale != 1.0:
            raw.apply_scale(scale)
        check_mesh(raw, name)
    elif isinstance(mesh, (str, os.PathLike)):
        name = str(mesh)
        raw = load_mesh(mesh, scale)
    else:
        raise PredictionError(f"mesh must be a file path or a trimesh.Trimesh, got {type(mesh).__name__}")
    prepared = prepare_mesh(raw, name)
    density = MassConfig().density if density is None else float(density)
    props = solid_mass_properties(prepared.mesh, prepared.watertight, density, f"mesh {name}")
    spec = RigidBodySpec.from_mesh(prepared.mesh, props)
    return PreparedBody(mesh=prepared.mesh, spec=spec, name=name, notes=list(prepared.warnings), scale=float(scale))


def initial_pose(spec: Any, orientation_xyzw: np.ndarray) -> np.ndarray:
    """The centre of mass (3,) of the object at rest in this orientation: lowest point on z = 0, x = y = 0."""
    from physdyn.sim.trajectory import resting_com_position

    return resting_com_position(spec, orientation_xyzw)


# --------------------------------------------------------------------------------------------------
# Simulation from a given state
# --------------------------------------------------------------------------------------------------
def simulate_from_state(spec: Any, orientation_xyzw: np.ndarray, lin_vel: np.ndarray, ang_vel: np.ndarray,
                        rate_hz: float, num_steps: int, physics: Any = None) -> dict[str, np.ndarray]:
    """PyBullet from the state right after a push: the body at rest in ``orientation_xyzw`` (mesh frame),
    given the velocities directly (no impulse), recorded at ``rate_hz`` for ``num_steps`` steps.

    Once the body has been at rest for ``physics.rest_duration`` the rest is padded with the resting pose
    and zero velocities. Returns ``com_position`` (T, 3), ``orientation_xyzw`` (T, 4) of the mesh frame,
    ``linear_velocity`` (T, 3), ``angular_velocity`` (T, 3), ``topple_label`` (T,) bool (the 45° rule).
    """
    from physdyn.config import PhysicsConfig
    from physdyn.sim.bullet import pb
    from physdyn.sim.trajectory import place_at_rest, record, topple_labels
    from physdyn.sim.world import PhysicsWorld

    phys = physics or PhysicsConfig()
    with PhysicsWorld(phys) as world:
        body = world.add_body(spec)
        place_at_rest(world, body, spec, orientation_xyzw)
        pb.resetBaseVelocity(body, list(map(float, lin_vel)), list(map(float, ang_vel)), physicsClientId=world.client)
        traj = record(world, body, spec, rate_hz, max_frames=num_steps)
    out = {
        "com_position": traj.com_position,
        "orientation_xyzw": traj.orientation_xyzw,
        "linear_velocity": traj.linear_velocity,
        "angular_velocity": traj.angular_velocity,
    }
    recorded = len(traj)
    if recorded < num_steps:
        pad = num_steps - recorded
        for key in ("com_position", "orientation_xyzw"):
            out[key] = np.concatenate([out[key], np.repeat(out[key][-1:], pad, axis=0)])
        for key in ("linear_velocity", "angular_velocity"):
            out[key] = np.concatenate([out[key], np.zeros((pad, 3))])
    out["topple_label"] = topple_labels(out["orientation_xyzw"])[0]
    return out


# --------------------------------------------------------------------------------------------------
# The predictor
# --------------------------------------------------------------------------------------------------
class Predictor:
    """A trained ``DynamicsModel`` ready to predict users' meshes.

    model: a ``DynamicsModel``; name: what the ``checkpoint`` key of a result says (a path or a name);
    physics: the ``PhysicsConfig`` of ``compare_sim`` runs (default: the conventions' defaults).
    """

    def __init__(self, model: Any, name: str = "model", physics: Any = None, device: str = "cpu"):
        self.model = model.to(resolve_device(device)) if hasattr(model, "to") else model
        self.name = str(name)
        self.physics = physics

    @property
    def rate_hz(self) -> float:
        return float(self.model.data_info.get("rate_hz") or 15.0)

    @property
    def num_points(self) -> int:
        return int(getattr(self.model, "num_points", None) or self.model.data_info.get("num_points") or DEFAULT_NUM_POINTS)

    def num_steps(self, seconds: float) -> int:
        """T = round(seconds * rate_hz) + 1 (step 0 included)."""
        return int(round(check_seconds(seconds) * self.rate_hz)) + 1

    def predict(self, mesh: Any, lin_vel: Any, ang_vel: Any, seconds: float = 3.0, orientation_xyzw: Any = None,
                scale: float = 1.0, compare_sim: bool = False) -> dict[str, Any]:
        """Predict the motion of ``mesh`` (a file path, a ``trimesh.Trimesh`` or a ``PreparedBody``) resting
        on the ground in ``orientation_xyzw`` (default: the mesh frame as is) with the post-push velocities
        ``lin_vel`` (m/s) and ``ang_vel`` (rad/s, world axes) at step 0.

        Returns the keys of a prediction file (docs/predict.md): ``rate_hz``, ``time`` (T,),
        ``com_position`` (T, 3), ``orientation_xyzw`` (T, 4), ``linear_velocity`` (T, 3),
        ``angular_velocity`` (T, 3), ``topple_probability`` (T,) or None, ``toppled``, ``com_mesh`` (3,),
        ``mesh``, ``checkpoint``; with ``compare_sim`` also ``simulated`` with the same keys from PyBullet.
        A note about the mesh (e.g. an open surface) is issued as a ``PredictionWarning``.
        """
        v0 = as_vector(lin_vel, "linear velocity (lin_vel)")
        w0 = as_vector(ang_vel, "angular velocity (ang_vel)")
        return self.predict_many([mesh], v0[None], w0[None], seconds, None if orientation_xyzw is None else [orientation_xyzw],
                                 scale, compare_sim)[0]

    def predict_many(self, meshes: Sequence[Any], lin_vel: Any, ang_vel: Any, seconds: Any = 3.0,
                     orientation_xyzw: Any = None, scale: Any = 1.0, compare_sim: Any = False,
                     chunk_size: int = 1024) -> list[dict[str, Any]]:
        """``predict`` for R requests at once, rolled out as batches: one result per request, in order.

        meshes: R file paths, ``trimesh.Trimesh`` or ``PreparedBody`` (a mesh named twice is prepared once);
        lin_vel, ang_vel: (R, 3), or (3,) for every request; seconds, scale, compare_sim: one value or R;
        orientation_xyzw: None (each mesh as it is), (4,) or (R, 4). Requests are grouped by length and
        rolled out ``chunk_size`` at a time, which bounds memory. Results equal per-request ``predict`` up
        to float32 round-off of batched arithmetic.
        """
        from physdyn.eval.metrics import TOPPLE_THRESHOLD
        from physdyn.eval.rollout import rollout
        from physdyn.sim.trajectory import topple_labels

        meshes = list(meshes)
        R = len(meshes)
        if R == 0:
            return []
        if int(chunk_size) < 1:
            raise PredictionError(f"chunk_size must be at least 1, got {chunk_size}")
        v0 = _per_request(lin_vel, R, "linear velocity (lin_vel)")
        w0 = _per_request(ang_vel, R, "angular velocity (ang_vel)")
        for values, name, limit, unit in ((v0, "linear velocity (lin_vel)", MAX_LINEAR_SPEED, "m/s"),
                                          (w0, "angular velocity (ang_vel)", MAX_ANGULAR_SPEED, "rad/s")):
            fastest = float(np.linalg.norm(values, axis=1).max())
            if fastest > limit:
                raise PredictionError(f"{name}: {fastest:g} {unit} is beyond any push a tabletop object survives "
                                      f"(at most {limit:g} {unit}); check the units")
        steps = [self.num_steps(s) for s in _per_request_values(seconds, R, "seconds")]
        scales = _per_request_values(scale, R, "scale")
        compare = [_boolean(c, "compare_sim") for c in _per_request_values(compare_sim, R, "compare_sim")]
        if orientation_xyzw is None:
            q0 = np.tile(check_orientation(None), (R, 1))
        else:
            q0 = np.stack([check_orientation(q) for q in _per_request(orientation_xyzw, R, "orientation (x, y, z, w)", 4)])
        bodies = self._bodies(meshes, scales)
        p0 = np.stack([initial_pose(body.spec, q) for body, q in zip(bodies, q0)])
        points = np.stack([body.points_body(self.num_points) for body in bodies])
        classifier = getattr(self.model, "topple_classifier", None)
        topple_points = None if classifier is None else np.stack(
            [body.points_body(classifier.num_points or DEFAULT_NUM_POINTS) for body in bodies])
        results: list[dict[str, Any] | None] = [None] * R
        for T in sorted(set(steps)):
            same = np.flatnonzero(np.asarray(steps) == T)
            for lo in range(0, len(same), int(chunk_size)):
                idx = same[lo : lo + int(chunk_size)]
                rolled = rollout(self.model, points[idx], q0[idx], p0[idx], v0[idx], w0[idx], T - 1,
                                 topple_points_body=None if topple_points is None else topple_points[idx])
                for b, r in enumerate(idx):
                    out = rolled.sequence(b)
                    probability = out["topple_probability"]
                    if probability is not None:
                        toppled = bool(np.any(probability >= TOPPLE_THRESHOLD))
                    else:  # no topple head: the 45 degree rule on the predicted orientations
                        toppled = bool(topple_labels(out["orientation_xyzw"])[1] >= 0)
                    results[r] = self._result(out, probability, toppled, bodies[r], self.name)
        for r in np.flatnonzero(compare):
            sim = simulate_from_state(bodies[r].spec, q0[r], v0[r], w0[r], self.rate_hz, steps[r], self.physics)
            results[r]["simulated"] = self._result(sim, sim["topple_label"].astype(np.float64),
                                                   bool(sim["topple_label"].any()), bodies[r], SIMULATOR_NAME)
        return results  # type: ignore[return-value]

    def _bodies(self, meshes: list, scales: list) -> list[PreparedBody]:
        """Each request's ``PreparedBody``, preparing a mesh named several times (same path or object, same
        scale) once; its notes are issued once as ``PredictionWarning``."""
        cache: dict[Any, PreparedBody] = {}
        bodies = []
        for mesh, scale in zip(meshes, scales):
            key = (str(Path(mesh).expanduser().resolve()) if isinstance(mesh, (str, os.PathLike)) else id(mesh), float(scale))
            if key not in cache:
                cache[key] = prepare_body(mesh, float(scale))
                for note in cache[key].notes:
                    warnings.warn(note, PredictionWarning, stacklevel=3)
            bodies.append(cache[key])
        return bodies

    def _result(self, states: dict, probability: Any, toppled: bool, body: PreparedBody, source: str) -> dict[str, Any]:
        T = len(states["com_position"])
        return {
            "rate_hz": self.rate_hz,
            "time": np.arange(T, dtype=np.float64) / self.rate_hz,
            "com_position": np.asarray(states["com_position"], dtype=np.float64),
            "orientation_xyzw": np.asarray(states["orientation_xyzw"], dtype=np.float64),
            "linear_velocity": np.asarray(states["linear_velocity"], dtype=np.float64),
            "angular_velocity": np.asarray(states["angular_velocity"], dtype=np.float64),
            "topple_probability": None if probability is None else np.asarray(probability, dtype=np.float64),
            "toppled": bool(toppled),
            "com_mesh": np.asarray(body.spec.com_mesh, dtype=np.float64),
            "mesh": body.name,
            "mesh_scale": body.scale,  # the mesh file's units to metres, so a viewer can draw it again
            "checkpoint": source,
        }


def resolve_device(device: str) -> str:
    """"cpu", "cuda" (or "cuda:N"), or "auto" (the GPU when torch sees one) -> a torch device name."""
    import torch

    name = str(device).lower()
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name.startswith("cuda"):
        if not torch.cuda.is_available():
            raise PhysdynError(f"device '{device}': torch sees no CUDA GPU here; use --device cpu (or auto)")
        return name
    if name != "cpu":
        raise PhysdynError(f"device '{device}': use cpu, cuda or auto")
    return name


def load_predictor(checkpoint: Any = None, physics: Any = None, device: str = "cpu") -> Predictor:
    """A ``Predictor`` from a `physdyn fit` checkpoint path, a loaded ``DynamicsModel``, or (None) the
    model bundled with physdyn, on ``device`` (cpu, cuda or auto). Raises a one-line ``PhysdynError`` for
    anything else."""
    from physdyn.eval.baselines import load_checkpoint

    if checkpoint is None:
        if not BUNDLED_CHECKPOINT.is_file():
            raise PhysdynError(f"no bundled model in this installation ({BUNDLED_CHECKPOINT} is missing); "
                               "pass a checkpoint of `physdyn fit` with --checkpoint CKPT (load_predictor(path))")
        return Predictor(load_checkpoint(BUNDLED_CHECKPOINT), name="bundled", physics=physics, device=device)
    if hasattr(checkpoint, "encode_points") and hasattr(checkpoint, "step"):
        return Predictor(checkpoint, name="model", physics=physics, device=device)
    if not isinstance(checkpoint, (str, os.PathLike)):
        raise PhysdynError(f"checkpoint must be a path or a DynamicsModel, got {type(checkpoint).__name__}")
    return Predictor(load_checkpoint(checkpoint), name=str(checkpoint), physics=physics, device=device)


# --------------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------------
def _flat(result: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``simulated`` nested keys -> ``simulated_<key>`` (npz and CSV cannot nest)."""
    out: dict[str, Any] = {}
    for key, value in result.items():
        if key == "simulated" and isinstance(value, dict):
            out.update(_flat(value, prefix + "simulated_"))
        else:
            out[prefix + key] = value
    return out


def _nest(flat: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    sim: dict[str, Any] = {}
    for key, value in flat.items():
        if key.startswith("simulated_"):
            sim[key[len("simulated_"):]] = value
        else:
            out[key] = value
    if sim:
        out["simulated"] = sim
    return out


def write_prediction(result: dict[str, Any], path: str | Path, overwrite: bool = False) -> Path:
    """Write ``result`` to ``path``: JSON, or .npz / .csv by the extension (docs/predict.md).

    Written to a temporary file in the same folder and renamed into place, so a reader never sees half a
    file. Refuses an existing ``path`` unless ``overwrite``.
    """
    path = check_output_path(path, overwrite)
    path.parent.mkdir(parents=True, exist_ok=True)
    ext = path.suffix.lower()
    with atomic_output(path) as tmp, open(tmp, "wb") as fh:
        if ext == ".json":
            fh.write(json.dumps(jsonable(result), indent=1).encode())
        elif ext == ".npz":
            np.savez(fh, **_npz_arrays(result))
        else:
            fh.write(_csv_text(result).encode())
        if not overwrite and path.exists():
            raise PredictionError(f"output {path} appeared while writing; pass --overwrite to replace it")
    return path


def _npz_arrays(result: dict[str, Any]) -> dict[str, np.ndarray]:
    arrays = {}
    for key, value in _flat(result).items():
        if value is None:  # a model without a topple head: NaN at every step (see docs/predict.md)
            value = np.full(len(result["time"]), np.nan)
        arrays[key] = np.asarray(value)
    return arrays


def _csv_columns(key: str) -> list[str]:
    """CSV columns of a per-step key: vectors get one column per component (``com_position_x``...,
    ``orientation_x``...``orientation_w``), scalars one column; a ``simulated_`` prefix is kept."""
    for name, comps in _COMPONENTS.items():
        if key == name or key.endswith("_" + name):
            stem = key[: -len(name)] + _CSV_COLUMN_BASE.get(name, name)
            return [f"{stem}_{c}" for c in comps]
    return [key]


def _csv_text(result: dict[str, Any]) -> str:
    flat = _flat(result)
    T = len(result["time"])
    lines = ["# physdyn prediction: one row per step; scalars in these comment lines as JSON values"]
    header: list[str] = []
    columns: list[np.ndarray] = []
    for key, value in flat.items():
        is_step = key.split("simulated_", 1)[-1] in STEP_KEYS
        if not is_step:
            lines.append(f"# {key}: {json.dumps(jsonable({key: value})[key])}")
            continue
        arr = (np.full(T, np.nan) if value is None else np.asarray(value, dtype=np.float64)).reshape(T, -1)
        header += _csv_columns(key)
        columns.append(arr)
    table = np.concatenate(columns, axis=1)
    lines.append(",".join(header))
    for row in table:
        lines.append(",".join("" if np.isnan(x) else repr(float(x)) for x in row))
    return "\n".join(lines) + "\n"


def read_prediction(path: str | Path) -> dict[str, Any]:
    """A prediction file (.json, .npz or .csv) -> the dict ``Predictor.predict`` returns (arrays as
    float64 numpy arrays, ``topple_probability`` None where the model has no topple head)."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".json":
        raw = json.loads(path.read_text())
        flat = _flat(raw)
    elif ext == ".npz":
        with np.load(path) as data:
            flat = {k: data[k] for k in data.files}
        for key, value in list(flat.items()):
            if value.ndim == 0:
                flat[key] = value.item()
    elif ext == ".csv":
        flat = _read_csv(path)
    else:
        raise PredictionError(f"{path}: unsupported extension '{ext}'; use one of {', '.join(OUTPUT_EXTENSIONS)}")
    out = {}
    for key, value in flat.items():
        base = key.split("simulated_", 1)[-1]
        if base == "topple_probability":
            arr = None if value is None else np.asarray(value, dtype=np.float64)
            out[key] = None if arr is None or np.isnan(arr).all() else arr
        elif base in STEP_KEYS or base == "com_mesh":
            out[key] = np.asarray(value, dtype=np.float64)
        elif base == "toppled":
            out[key] = bool(value)
        elif base in ("rate_hz", "mesh_scale"):
            out[key] = float(value)
        else:
            out[key] = str(value)
    return _nest(out)


def _read_csv(path: Path) -> dict[str, Any]:
    flat: dict[str, Any] = {}
    rows: list[list[str]] = []
    header: list[str] | None = None
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            match = _CSV_SCALAR.match(line)
            if match:
                flat[match.group(1)] = json.loads(match.group(2))
        elif header is None:
            header = line.split(",")
        elif line:
            rows.append(line.split(","))
    assert header is not None
    table = np.array([[float(x) if x else np.nan for x in row] for row in rows], dtype=np.float64).reshape(len(rows), len(header))
    index = {name: i for i, name in enumerate(header)}
    for prefix in ("", "simulated_"):
        for key in STEP_KEYS:
            cols = _csv_columns(prefix + key)
            if all(c in index for c in cols):
                arr = table[:, [index[c] for c in cols]]
                flat[prefix + key] = arr[:, 0] if len(cols) == 1 else arr
    return flat


def summary(result: dict[str, Any]) -> str:
    """A few human lines: where the object ends, how far it turned, whether it toppled."""
    from physdyn.geometry.rotations import quat_conjugate, quat_multiply, quat_to_rotvec

    lines = []
    for label, res in (("prediction", result), ("simulation", result.get("simulated"))):
        if res is None:
            continue
        p0, p1 = res["com_position"][0], res["com_position"][-1]
        turn = quat_to_rotvec(quat_multiply(res["orientation_xyzw"][-1], quat_conjugate(res["orientation_xyzw"][0])))
        lines.append(
            f"{label} ({res['checkpoint']}), t = {res['time'][-1]:.2f} s: centre of mass at "
            f"({p1[0]:.3f}, {p1[1]:.3f}, {p1[2]:.3f}) m, moved {np.linalg.norm(p1[:2] - p0[:2]):.3f} m, "
            f"turned {np.degrees(np.linalg.norm(turn)):.1f} deg, toppled: {'yes' if res['toppled'] else 'no'}"
        )
    return "\n".join(lines)
