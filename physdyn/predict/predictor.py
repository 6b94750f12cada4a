"""Predicting how a user's mesh moves after a push.

``load_predictor()`` gives a ``Predictor`` around a trained ``DynamicsNetwork`` (the shipped ``fast`` one by default:
nothing simulated, the accuracy-cost frontier's point, docs/performance.md);
``Predictor.predict(mesh, lin_vel, ang_vel, seconds)`` places the object at rest on the ground as the
conventions say (docs/conventions.md, "Initial condition"), rolls the model out and returns a dict with
the keys of a prediction file ("Prediction output"); ``predict_many`` does R requests as batches.
``compare_sim=True`` adds the same keys from PyBullet, started from the same state, under ``simulated``
(``simulator.py``). Mesh to rigid body: ``body.py``; the files: ``prediction_files.py``.

Arrays in a result are float64 numpy arrays: T = round(seconds * rate_hz) + 1 steps, step 0 included.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from typing import Any, Sequence

import numpy as np

from physdyn.config.uncertainty import resolve_uncertainty
from physdyn.errors import PhysdynError, PredictionError, PredictionWarning
from physdyn.eval.rollout import RolloutOptions, as_pipeline, prepared_batch
from physdyn.geometry.mass import vertical_inertia, world_inertia_per_mass
from physdyn.geometry.rotations import quat_conjugate, quat_multiply, quat_to_rotvec
from physdyn.models.checkpoint_file import SHIPPED
from physdyn.pipeline.distribution import check_samples, sample_requests, summarise, topple_by_step
from physdyn.pipeline.engine import Pipeline, run_stages
from physdyn.pipeline.presets import build_pipeline, load_pipeline, preset_file, read_preset
from physdyn.pipeline.spread import SampledPushes
from physdyn.pipeline.stages import BodyCache
from physdyn.predict.body import PreparedBody, preparation_key, prepare_body
from physdyn.predict.device import resolve_device
from physdyn.predict.request_checks import (MAX_ANGULAR_SPEED, MAX_LINEAR_SPEED, MAX_SECONDS, _boolean, _orientations,  # noqa: F401
                                            _per_request, _per_request_values, as_vector, check_orientation, check_seconds)
from physdyn.predict.simulator import SIMULATOR_NAME, simulate_from_state
from physdyn.sim.trajectory import resting_com_positions

BUNDLED_CHECKPOINT = SHIPPED["bundled"]
# The default: the shipped model no PyBullet step beats on both accuracy and cost, on new meshes
# (docs/performance.md); "bundled", which simulates inside each prediction, is dominated by PyBullet at 1/240 s.
DEFAULT_MODEL = "fast"
DEFAULT_CHECKPOINT = SHIPPED[DEFAULT_MODEL]
PREPARED_CACHE_SIZE = 256  # meshes whose preparation a Predictor keeps (a 10k-face one holds about 0.5 MB)


def _posed(bodies: list[PreparedBody], q0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each request's body in its step-0 orientation q0 (R, 4): the resting centre of mass (R, 3), the mesh's
    own I_zz / m about the vertical (R,), for a contact prior that takes it (``model.contact_inertia=body``)
    and an outcome correction, and I / m in world axes (R, 3, 3), for a topple classifier that simulates.
    A batch often pushes one object hundreds of times: each body's requests are posed at once (the same
    numbers as one at a time, to the bit; tests/predict)."""
    p0, spin, inertia = np.zeros((len(bodies), 3)), np.zeros(len(bodies)), np.zeros((len(bodies), 3, 3))
    rows: dict[int, list[int]] = {}
    for r, body in enumerate(bodies):
        rows.setdefault(id(body), []).append(r)
    for group in rows.values():
        spec, q = bodies[group[0]].spec, q0[group]
        mass = (spec.inertia_diag, spec.principal_axes, spec.mass, q)
        p0[group], spin[group], inertia[group] = resting_com_positions(spec, q), vertical_inertia(*mass), world_inertia_per_mass(*mass)
    return p0, spin, inertia


def _velocities(lin_vel: Any, ang_vel: Any, count: int) -> tuple[np.ndarray, np.ndarray]:
    """(count, 3) post-push velocities, each checked finite and within what a tabletop object survives."""
    v0 = _per_request(lin_vel, count, "linear velocity (lin_vel)")
    w0 = _per_request(ang_vel, count, "angular velocity (ang_vel)")
    for values, name, limit, unit in ((v0, "linear velocity (lin_vel)", MAX_LINEAR_SPEED, "m/s"),
                                      (w0, "angular velocity (ang_vel)", MAX_ANGULAR_SPEED, "rad/s")):
        fastest = float(np.linalg.norm(values, axis=1).max())
        if fastest > limit:
            raise PredictionError(f"{name}: {fastest:g} {unit} is beyond any push a tabletop object survives "
                                  f"(at most {limit:g} {unit}); check the units")
    return v0, w0


# --------------------------------------------------------------------------------------------------
# The predictor
# --------------------------------------------------------------------------------------------------
class Predictor:
    """A pipeline of stages (``physdyn.pipeline``) ready to predict users' meshes.

    model: a ``Pipeline`` (``load_pipeline``), or a bare ``DynamicsNetwork`` (rolled out as ``as_pipeline``
    makes it); name: what the ``checkpoint`` key of a result says (a preset, a path or a name); physics: the
    ``PhysicsConfig`` of ``compare_sim`` runs (default: the conventions' defaults).
    """

    def __init__(self, model: Any, name: str = "model", physics: Any = None, device: str = "cpu"):
        self.model: Pipeline = as_pipeline(model).to(resolve_device(device))
        self.name = str(name)
        self.physics = physics
        # The bodies this predictor has seen: prepared meshes (by preparation_key, least recently used first:
        # a new mesh costs milliseconds to prepare, a mesh seen before only a digest of its arrays) and the
        # thinned clouds its PointNets read.
        self._prepared = BodyCache()

    @property
    def rate_hz(self) -> float:
        """The rate of the predicted trajectory (Hz): the rate of the store the model was trained on."""
        return self.model.rate_hz

    @property
    def num_points(self) -> int:
        """How many surface points the model reads from a mesh's cloud."""
        return self.model.num_points

    @property
    def points_method(self) -> str:
        """The point representation the model was trained on (its store's ``points_method``)."""
        return self.model.points_method

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
        A note about the mesh (e.g. an open surface) is issued as a ``PredictionWarning``. The ground's
        friction is the body's (``prepare_body(mesh).with_friction(mu)``), else the model's own.
        """
        v0 = as_vector(lin_vel, "linear velocity (lin_vel)")
        w0 = as_vector(ang_vel, "angular velocity (ang_vel)")
        return self.predict_many([mesh], v0[None], w0[None], seconds, None if orientation_xyzw is None else [orientation_xyzw],
                                 scale, compare_sim)[0]

    def predict_many(self, meshes: Sequence[Any], lin_vel: Any, ang_vel: Any, seconds: Any = 3.0,
                     orientation_xyzw: Any = None, scale: Any = 1.0, compare_sim: Any = False,
                     chunk_size: int = 1024) -> list[dict[str, Any]]:
        """``predict`` for R requests at once, rolled out as batches: one result per request, in order.

        meshes: R file paths, ``trimesh.Trimesh`` or ``PreparedBody`` (a mesh this predictor prepared
        before, as the same file or the same content, is not prepared again: ``_bodies``);
        lin_vel, ang_vel: (R, 3), or (3,) for every request; seconds, scale, compare_sim: one value or R;
        orientation_xyzw: None (each mesh as it is), (4,) or (R, 4). Requests of different lengths share a
        roll-out, padded to the longest and cut to their own length; ``chunk_size`` requests at a time bound
        memory. Results equal per-request ``predict`` up to float32 round-off of batched arithmetic.
        """

        meshes = list(meshes)
        R = len(meshes)
        if R == 0:
            return []
        if int(chunk_size) < 1:
            raise PredictionError(f"chunk_size must be at least 1, got {chunk_size}")
        v0, w0 = _velocities(lin_vel, ang_vel, R)
        steps = [self.num_steps(s) for s in _per_request_values(seconds, R, "seconds")]
        scales = _per_request_values(scale, R, "scale")
        compare = [_boolean(c, "compare_sim") for c in _per_request_values(compare_sim, R, "compare_sim")]
        q0 = _orientations(orientation_xyzw, R)
        bodies = self._bodies(meshes, scales)
        results: list[dict[str, Any] | None] = [None] * R
        for idx, rolled in self._rollouts(bodies, (q0, v0, w0), steps, chunk_size):
            for b, r in enumerate(idx):
                T = steps[r]
                out = {k: None if v is None else v[:T] for k, v in rolled.sequence(b).items()}
                # the roll-out's verdict at the request's own end: its probabilities, or with no topple output
                # the 45 degree rule on its poses
                results[r] = self._result(out, out["topple_probability"], bool(rolled.toppled[b]), bodies[r], self.name)
        for r in np.flatnonzero(compare):
            sim = simulate_from_state(bodies[r].spec, q0[r], v0[r], w0[r], self.rate_hz, steps[r], self.physics,
                                      bodies[r].friction)
            results[r]["simulated"] = self._result(sim, sim["topple_label"].astype(np.float64),
                                                   bool(sim["topple_label"].any()), bodies[r], SIMULATOR_NAME)
        return results  # type: ignore[return-value]

    def predict_distribution(self, mesh: Any, lin_vel: Any, ang_vel: Any, seconds: float = 3.0, uncertainty: Any = "default",
                             samples: int = 32, seed: int = 0, orientation_xyzw: Any = None) -> dict[str, Any]:
        """The outcomes of a push known only roughly: ``samples`` outcomes of the push (``lin_vel``, ``ang_vel``)
        under ``uncertainty`` (a preset name: none, low, default; a mapping of ``UncertaintyConfig``'s keys; or
        an ``UncertaintyConfig``) with seed ``seed``, of ``mesh`` (prepared once; pass a ``PreparedBody`` for a
        scale other than 1) resting in ``orientation_xyzw``. The pipeline's distribution stage makes them
        (``physdyn.pipeline.spread``): ``calibrated`` (``fast``) draws them around one roll-out with a fitted
        spread that covers the push's uncertainty and the model's own error; ``sampled_pushes`` rolls out that
        many pushes drawn from the uncertainty as one batch.

        Returns ``com_position`` (N, T, 3), ``orientation_xyzw`` (N, T, 4), ``toppled`` (N,) each sample's
        verdict, ``topple_probability`` (T,) the probability of having toppled by each step, the summary
        figures of ``physdyn.pipeline.distribution.summarise``, ``distribution`` (the stage's name), and
        ``samples``, ``seed``, ``uncertainty`` (the resolved values), ``lin_vel``, ``ang_vel``, ``rate_hz``,
        ``time`` (T,), ``com_mesh``, ``mesh``, ``mesh_scale``, ``checkpoint``, ``kind`` ("distribution");
        with ``sampled_pushes`` also ``sample_lin_vel`` and ``sample_ang_vel`` (N, 3), the pushes rolled out.
        With zero uncertainty every sample is ``predict``'s trajectory.
        """
        config = resolve_uncertainty(uncertainty)
        count = check_samples(samples)
        v0 = as_vector(lin_vel, "linear velocity (lin_vel)")
        w0 = as_vector(ang_vel, "angular velocity (ang_vel)")
        T = self.num_steps(seconds)
        q0 = np.tile(check_orientation(orientation_xyzw), (count, 1))
        body = self._bodies([mesh], [1.0])[0]
        stage = getattr(self.model, "distribution", None) or SampledPushes()
        out: dict[str, Any] = {"kind": "distribution", "rate_hz": self.rate_hz,
                               "time": np.arange(T, dtype=np.float64) / self.rate_hz}
        if stage.rolls_out_samples:
            # friction too, where the motion takes it
            mu = self.frictions([body])
            if mu is None and self.model.motion.takes_friction and self.own_friction is not None:
                mu = np.array([self.own_friction])
            lin, ang, mus = sample_requests(v0, w0, mu, config, count, seed)
            v, w = _velocities(lin[0], ang[0], count)
            p, q = np.empty((count, T, 3)), np.empty((count, T, 4))
            toppled, by_step = np.zeros(count, dtype=bool), np.zeros((count, T))
            # one body, one length: the batches are the samples themselves, in order
            for idx, rolled in self._rollouts([body] * count, (q0, v, w), [T] * count, 1024,
                                              None if mus is None else mus[0]):
                p[idx], q[idx], toppled[idx] = rolled.com_position, rolled.orientation_xyzw, rolled.toppled
                by_step[idx] = topple_by_step(rolled, q0[idx])
            out.update(sample_lin_vel=v, sample_ang_vel=w)
            if mus is not None:
                out["sample_friction"] = mus[0]
        else:
            # the push as given, rolled out alone (``predict``'s roll-out), and the samples drawn around it
            _, rolled = next(self._rollouts([body], (q0[:1], v0[None], w0[None]), [T], 1))
            nominal = {"com_position": rolled.com_position, "orientation_xyzw": rolled.orientation_xyzw,
                       "topple_by_step": topple_by_step(rolled, q0[:1])}
            drawn = stage.spread(nominal, v0[None], w0[None], config, count, np.random.default_rng(int(seed)))
            p, q, toppled = drawn["com_position"][0], drawn["orientation_xyzw"][0], drawn["toppled"][0]
            by_step = np.repeat(nominal["topple_by_step"], count, axis=0)
        out.update(com_position=p, orientation_xyzw=q, toppled=toppled)
        out.update(summarise(p, q, by_step))
        out.update(samples=count, seed=int(seed), uncertainty=dataclasses.asdict(config), lin_vel=v0, ang_vel=w0,
                   com_mesh=np.array(body.spec.com_mesh, dtype=np.float64), mesh=body.name, mesh_scale=body.scale,
                   checkpoint=self.name, distribution=stage.registered_name)
        return out

    def _rollouts(self, bodies: list[PreparedBody], start: tuple, steps: list[int], chunk_size: int,
                  friction: np.ndarray | None = None):
        """The roll-outs of R requests as batches: yields (idx, ``RolloutResult``) per chunk of at most
        ``chunk_size`` requests, idx (B,) the requests of its rows. start: q0 (R, 4), v0, w0 (R, 3); steps: each
        request's T; friction (R,): each request's, where not its body's (``own_friction``).
        ``predict_many`` and ``predict_distribution`` both roll out through here."""
        q0, v0, w0 = start
        friction = self.frictions(bodies) if friction is None else friction
        p0, spin_inertia, body_inertia = _posed(bodies, q0)
        points = np.stack([body.points_body(self.num_points, self.points_method) for body in bodies])
        # a hull_surface cloud's first points are its mesh's hull vertices: thinning it needs no qhull
        hulls = None
        if self.points_method == "hull_surface":
            hulls = np.array([body.hull_count(self.num_points) for body in bodies])
        # None where no stage reads another cloud, or where it is the motion's own (`fast`: one cloud for all)
        spec = self.model.stage_cloud()
        topple_points = None if spec is None else np.stack([body.points_body(spec.count, spec.method) for body in bodies])
        # Longest first, then one roll-out per chunk at the chunk's longest length: a roll-out is causal (each
        # step reads only earlier ones), so a shorter request's steps are exactly its own roll-out's and the
        # steps past its end are cut off. One roll-out per length cost 18 roll-outs for 60 requests.
        order = np.argsort(-np.asarray(steps), kind="stable")
        for lo in range(0, len(bodies), int(chunk_size)):
            idx = order[lo : lo + int(chunk_size)]
            longest = max(steps[r] for r in idx)
            options = RolloutOptions(topple_points_body=None if topple_points is None else topple_points[idx],
                                     spin_inertia=spin_inertia[idx], body_inertia=body_inertia[idx],
                                     lengths=np.array([steps[r] for r in idx]), with_changes=False,
                                     hull_counts=None if hulls is None else hulls[idx],
                                     friction=None if friction is None else friction[idx])
            batch = prepared_batch(points[idx], (q0[idx], p0[idx], v0[idx], w0[idx]), longest - 1, options, self._prepared)
            yield idx, run_stages(self.model, batch)

    @property
    def own_friction(self) -> float | None:
        """The effective Coulomb coefficient the model predicts at when a body gives none (its prior's; None
        where it has no prior that reads one)."""
        return getattr(self.model.network, "prior_friction", None)

    def frictions(self, bodies: list[PreparedBody]) -> np.ndarray | None:
        """(R,) each body's ground friction (``PreparedBody.with_friction``), the model's own where a body gives
        none; None where none gives one (the model's own throughout)."""
        given = [body.friction for body in bodies]
        if all(mu is None for mu in given):
            return None
        own = self.own_friction
        return np.array([own if mu is None else mu for mu in given], dtype=np.float64)

    def forget_meshes(self) -> None:
        """Forget every mesh prepared so far (this predictor's body cache: preparations, thinned clouds, the
        simulator's hull shapes), so the next request pays for its preparation as a new mesh does
        (benchmarks/frontier.py)."""
        self._prepared.forget()

    def _bodies(self, meshes: list, scales: list) -> list[PreparedBody]:
        """Each request's ``PreparedBody``. A mesh this predictor prepared before, in this call or an
        earlier one, is not prepared again: the same file (path, size, modification time) or a mesh of the
        same content (an equal ``trimesh.Trimesh``, whatever the object), at the same scale. The last
        ``PREPARED_CACHE_SIZE`` preparations are kept. Each body's notes are issued once per call as
        ``PredictionWarning``."""
        bodies: list[PreparedBody] = []
        noted: set[int] = set()
        keys: dict[tuple[int, Any], tuple | None] = {}  # per object: one digest for many pushes of one mesh
        for mesh, scale in zip(meshes, scales):
            if (id(mesh), scale) not in keys:
                keys[id(mesh), scale] = None if isinstance(mesh, PreparedBody) else preparation_key(mesh, scale)
            key = keys[id(mesh), scale]
            prepared = self._prepared.meshes
            body = prepared.get(key) if key is not None else None
            if body is None:
                body = prepare_body(mesh, float(scale))
                if key is not None:
                    prepared[key] = body
                    if len(prepared) > PREPARED_CACHE_SIZE:
                        prepared.popitem(last=False)  # the least recently used
            else:
                prepared.move_to_end(key)
            if id(body) not in noted:
                noted.add(id(body))
                for note in body.notes:
                    warnings.warn(note, PredictionWarning, stacklevel=3)
            bodies.append(body)
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
            "com_mesh": np.array(body.spec.com_mesh, dtype=np.float64),  # a copy: the body may be cached
            "mesh": body.name,
            "mesh_scale": body.scale,  # the mesh file's units to metres, so a viewer can draw it again
            "checkpoint": source,
        }


def contact_prior_predictor(physics: Any = None, rate_hz: float = 15.0, num_points: int = 256) -> Predictor:
    """The ``contact_prior`` preset as a ``Predictor`` (configs/predictor/contact_prior.yaml: no network, nothing
    learned, never topples): Coulomb friction integrated over the footprint of the mesh's ``hull_surface``
    cloud of ``num_points`` with the body's own spin inertia, at ``rate_hz`` and the friction of ``physics``
    (default: the conventions'). About 0.1 ms a trajectory in a batch of one mesh's pushes; the planner
    screens candidates with it."""
    preset = read_preset(preset_file("contact_prior"))
    preset.motion.params.update(rate_hz=float(rate_hz), num_points=int(num_points))
    return Predictor(build_pipeline(preset, physics), name="contact prior", physics=physics)


def load_predictor(checkpoint: Any = None, physics: Any = None, device: str = "cpu") -> Predictor:
    """A ``Predictor`` from a shipped preset's name ("fast": nothing simulated, docs/model-card.md; "bundled":
    a simulated start and a topple roll-out in PyBullet; "contact_prior"), a preset file (.yaml), a checkpoint
    of `physdyn fit` (a path, with what `fit-topple` and `fit-outcome` added), a ``Pipeline`` or a loaded
    ``DynamicsNetwork``, or (None) the default, the shipped ``fast`` model, on ``device`` (cpu, cuda or auto).
    All but the last two through one factory (``physdyn.pipeline.presets.load_pipeline``). Raises a one-line
    ``PhysdynError`` for anything else."""

    if checkpoint is None:
        # the shipped file itself: a file named "fast" where the caller runs is theirs to name, not the default
        if not DEFAULT_CHECKPOINT.is_file():
            raise PhysdynError(f"no shipped model in this installation ({DEFAULT_CHECKPOINT} is missing); "
                               "pass a checkpoint of `physdyn fit` with --checkpoint CKPT (load_predictor(path))")
        return Predictor(load_pipeline(preset_file(DEFAULT_MODEL), physics), name=DEFAULT_MODEL, physics=physics,
                         device=device)
    if isinstance(checkpoint, Pipeline) or (hasattr(checkpoint, "encode_points") and hasattr(checkpoint, "step")):
        return Predictor(checkpoint, name=getattr(checkpoint, "name", "model"), physics=physics, device=device)
    if not isinstance(checkpoint, (str, os.PathLike)):
        raise PhysdynError(f"checkpoint must be a path, a preset's name or a DynamicsNetwork, got {type(checkpoint).__name__}")
    return Predictor(load_pipeline(checkpoint, physics), name=str(checkpoint), physics=physics, device=device)


def summary(result: dict[str, Any]) -> str:
    """A few human lines: where the object ends, how far it turned, whether it toppled."""

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
