"""What rolls a plan's candidates out: post-push velocities (B, 3), (B, 3) -> final poses (``Outcome``).
``LearnedRollout``: a predictor (the plan's, or a screen from ``screens.py``), every candidate of a round in
one batch; ``BulletRollout``: PyBullet at a given step on the mesh's hull."""

from __future__ import annotations

import math
import time
import warnings
import weakref
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from physdyn.config import PhysicsConfig
from physdyn.errors import PredictionWarning
from physdyn.geometry.rotations import quat_conjugate, quat_multiply, tilt_angle
from physdyn.predict.body import PreparedBody
from physdyn.sim.bullet import pb
from physdyn.sim.trajectory import TOPPLE_ANGLE, place_at_rest
from physdyn.sim.world import PhysicsWorld

# The predictors that have rolled out in this process (their one-off set-up paid): kept beside them, not on
# them, and forgotten with them.
_warm: weakref.WeakSet = weakref.WeakSet()


@dataclass
class Outcome:
    """Where each candidate ends: ``com_position`` (B, 3), ``orientation_xyzw`` (B, 4), ``toppled`` (B,);
    ``trajectories``: the per-candidate results of ``Predictor.predict`` when the roll-out has them."""

    com_position: np.ndarray
    orientation_xyzw: np.ndarray
    toppled: np.ndarray
    trajectories: list | None = None


class LearnedRollout:
    """The predictor's model, all candidates of a round in one ``predict_many`` call."""

    def __init__(self, predictor: Any, body: PreparedBody, orientation_xyzw: np.ndarray, seconds: float):
        self.predictor, self.body, self.orientation, self.seconds = predictor, body, orientation_xyzw, seconds
        self.name = predictor.name

    def warm_up(self) -> float:
        """A predictor's first roll-out in a process sets things up once (torch, the simulated start's world):
        1-2 s on a loaded core. One candidate of the first plan pays it before the budget's clock starts.
        Returns the seconds it took (0 when this predictor was warm)."""
        if self.predictor in _warm:
            return 0.0
        t0 = time.perf_counter()
        self(np.array([[0.5, 0.0, 0.0]]), np.zeros((1, 3)))
        _warm.add(self.predictor)
        return time.perf_counter() - t0

    def __call__(self, lin_vel: np.ndarray, ang_vel: np.ndarray) -> Outcome:
        # One thread: a round of a few dozen candidates is too small to split, and on a shared 2-core machine
        # two threads made a round of 16 four times slower (1.0 s against 0.22 s, measured).
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", PredictionWarning)  # the mesh's notes were issued when it was prepared
                results = self.predictor.predict_many([self.body] * len(lin_vel), lin_vel, ang_vel, self.seconds,
                                                      self.orientation)
        finally:
            torch.set_num_threads(threads)
        return Outcome(np.stack([r["com_position"][-1] for r in results]),
                       np.stack([r["orientation_xyzw"][-1] for r in results]),
                       np.array([r["toppled"] for r in results]), results)

    def close(self) -> None:
        pass


class BulletRollout:
    """PyBullet at ``time_step`` as the planner's model: one world and one body reused for every candidate,
    each simulated from the resting pose until at rest (the conventions' rest rule) or ``seconds``. A
    candidate has toppled when its tilt passed 45 degrees at any frame of ``rate_hz`` (the conventions'
    rule, as a store's labels and ``verify_push`` apply it), not only at its last pose: a body that rolls
    over and lands upright has toppled."""

    REST_CHECK_S = 1.0 / 60.0

    def __init__(self, spec: Any, orientation_xyzw: np.ndarray, time_step: float, seconds: float,
                 physics: PhysicsConfig | None = None, rate_hz: float = 15.0, record: bool = False):
        self.physics = replace(physics or PhysicsConfig(), time_step=float(time_step))
        self.spec, self.orientation, self.seconds = spec, np.asarray(orientation_xyzw, dtype=np.float64), seconds
        self.rate_hz = float(rate_hz)
        self.record = record  # keep each candidate's trajectory at rate_hz (the final check's answer has one)
        self.world = PhysicsWorld(self.physics)
        self.body = self.world.add_body(spec)
        self.name = f"pybullet@1/{round(1.0 / time_step)}s"

    def warm_up(self) -> float:
        return 0.0

    def __call__(self, lin_vel: np.ndarray, ang_vel: np.ndarray) -> Outcome:
        cid, phys = self.world.client, self.physics
        chunk = max(1, int(round(self.REST_CHECK_S / phys.time_step)))
        total = int(math.ceil(self.seconds / phys.time_step))
        rest_needed = int(math.ceil(phys.rest_duration / phys.time_step))
        frame = max(1, int(round(1.0 / (self.rate_hz * phys.time_step))))
        chunk = math.gcd(chunk, frame)  # the frames fall on chunk boundaries
        principal = quat_conjugate(self.spec.principal_quat_xyzw)
        positions, quats = np.empty((len(lin_vel), 3)), np.empty((len(lin_vel), 4))
        toppled = np.zeros(len(lin_vel), dtype=bool)
        trajectories = [] if self.record else None
        for i, (v, w) in enumerate(zip(lin_vel, ang_vel)):
            place_at_rest(self.world, self.body, self.spec, self.orientation)
            pb.resetBaseVelocity(self.body, list(map(float, v)), list(map(float, w)), physicsClientId=cid)
            steps = rest = 0
            track: list[tuple] = []
            recorded_last = False  # whether the final pose is the last recorded frame
            while True:
                recorded_last = steps % frame == 0
                if recorded_last:
                    pos, orn = pb.getBasePositionAndOrientation(self.body, physicsClientId=cid)
                    if not toppled[i]:  # R_mesh = R_base A^T
                        toppled[i] = tilt_angle(self.orientation, quat_multiply(np.asarray(orn), principal)) > TOPPLE_ANGLE
                    if self.record:
                        track.append((pos, orn, *pb.getBaseVelocity(self.body, physicsClientId=cid)))
                if steps >= total or rest >= rest_needed:
                    break
                self.world.step(chunk)
                steps += chunk
                lv, av = pb.getBaseVelocity(self.body, physicsClientId=cid)
                still = np.dot(lv, lv) < phys.rest_linear_speed**2 and np.dot(av, av) < phys.rest_angular_speed**2
                rest = rest + chunk if still else 0
            pos, orn = pb.getBasePositionAndOrientation(self.body, physicsClientId=cid)
            positions[i], quats[i] = pos, orn
            if not recorded_last:  # stopped between two frames: its final pose is checked here
                toppled[i] |= tilt_angle(self.orientation, quat_multiply(np.asarray(orn), principal)) > TOPPLE_ANGLE
            if self.record:
                trajectories.append(self._trajectory(track if not recorded_last else track[:-1], pos, orn))
        # PyBullet's base frame is the principal frame: back to the mesh frame, R_mesh = R_base A^T
        quats = quat_multiply(quats, principal)
        return Outcome(positions, quats, toppled, trajectories)

    def _trajectory(self, track: list[tuple], pos: Any, orn: Any) -> dict[str, Any]:
        """The recorded frames before the final state, then the final state (where the roll-out stopped, on a
        frame or between two), as the trajectory keys of a prediction, in the mesh frame; topple "probability"
        0 or 1 by the 45 degree rule, from the first frame past it on."""
        p = np.array([t[0] for t in track] + [pos], dtype=np.float64)
        q = quat_multiply(np.array([t[1] for t in track] + [orn], dtype=np.float64),
                          quat_conjugate(self.spec.principal_quat_xyzw))
        last_v, last_w = pb.getBaseVelocity(self.body, physicsClientId=self.world.client)
        v = np.array([t[2] for t in track] + [last_v], dtype=np.float64)
        w = np.array([t[3] for t in track] + [last_w], dtype=np.float64)
        over = np.maximum.accumulate(tilt_angle(self.orientation, q) > TOPPLE_ANGLE)
        return {"rate_hz": self.rate_hz, "time": np.arange(len(p)) / self.rate_hz, "com_position": p,
                "orientation_xyzw": q, "linear_velocity": v, "angular_velocity": w,
                "topple_probability": over.astype(np.float64), "checkpoint": self.name}

    def close(self) -> None:
        self.world.close()
