"""Reference distributions: each push re-simulated K times, perturbed as its uncertainty says.

A member starts from the push's recorded step-0 state (its orientation and post-push velocities), the
velocities and friction perturbed by ``perturb_pushes``, and is simulated exactly as
``physdyn.predict.simulator.simulate_from_state`` simulates a predicted start: at rest with its centre of mass
above the origin, at the conventions' physics step, recorded at the store's rate for a fixed number of steps
(padded with the resting pose once at rest). Members run in the push's own world and body, after all the
shape's pushes, so the pushes are those of the same store without an ensemble.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from physdyn.config import DataConfig, UncertaintyConfig
from physdyn.sim.body import RigidBodySpec
from physdyn.sim.perturb import perturb_pushes
from physdyn.sim.trajectory import Trajectory, record_from_state
from physdyn.sim.world import PhysicsWorld


@dataclass
class PushMembers:
    """One push's K members, each T recorded steps (step 0 the perturbed post-push state).

    linear_velocity0 (K, 3), angular_velocity0 (K, 3), friction (K,): the perturbed start, world frame.
    com_position (K, T, 3), orientation_xyzw (K, T, 4) of the mesh frame; topple_label (K, T) bool (the 45
    degree rule); topple_step (K,) int, -1 where a member does not topple.
    """

    linear_velocity0: np.ndarray
    angular_velocity0: np.ndarray
    friction: np.ndarray
    com_position: np.ndarray
    orientation_xyzw: np.ndarray
    topple_label: np.ndarray
    topple_step: np.ndarray


@dataclass(frozen=True)
class EnsemblePlan:
    """Each push's ensemble: ``members`` (K) runs of ``steps`` (T) recorded steps at ``rate_hz``, perturbed
    by ``uncertainty``."""

    members: int
    steps: int
    rate_hz: float
    uncertainty: UncertaintyConfig

    @classmethod
    def from_config(cls, cfg: DataConfig) -> "EnsemblePlan | None":
        """The data config's ensemble; None without one (``ensemble.members`` 0). A member is recorded for
        ``ensemble.seconds`` (default the push's time cap, ``physics.max_duration``), step 0 included."""
        if not cfg.ensemble.members:
            return None
        seconds = cfg.physics.max_duration if cfg.ensemble.seconds is None else cfg.ensemble.seconds
        return cls(cfg.ensemble.members, int(np.floor(seconds * cfg.rate_hz + 1e-9)) + 1, cfg.rate_hz,
                   cfg.ensemble.uncertainty_config())

    def describe(self) -> dict:
        """The store's ``ensemble`` attribute: members, steps, seconds and the uncertainty resolved."""
        return {"members": self.members, "steps": self.steps, "seconds": (self.steps - 1) / self.rate_hz,
                "uncertainty": asdict(self.uncertainty)}


def simulate_members(world: PhysicsWorld, body: int, spec: RigidBodySpec, push: Trajectory, friction: float,
                     plan: EnsemblePlan, rng: np.random.Generator) -> PushMembers:
    """One push's members, in the push's world and body (its ``physics``). ``push``: the push's recorded
    trajectory, whose step 0 is perturbed; ``friction``: its effective Coulomb coefficient; ``rng``: the
    push's own stream (the same draws whatever the worker)."""
    K, T = plan.members, plan.steps
    lin, ang, mu = perturb_pushes(push.linear_velocity[:1], push.angular_velocity[:1], np.array([friction]),
                                  plan.uncertainty, rng, K)
    runs = []
    for k in range(K):
        world.set_object_friction(body, mu[0, k] / world.physics.lateral_friction_ground)
        runs.append(record_from_state(world, body, spec, push.orientation_xyzw[0], lin[0, k], ang[0, k],
                                      plan.rate_hz, T))
    labels = np.stack([r["topple_label"] for r in runs]).reshape(K, T)
    return PushMembers(
        linear_velocity0=lin[0], angular_velocity0=ang[0], friction=mu[0],
        com_position=np.stack([r["com_position"] for r in runs]).reshape(K, T, 3),
        orientation_xyzw=np.stack([r["orientation_xyzw"] for r in runs]).reshape(K, T, 4),
        topple_label=labels, topple_step=np.where(labels.any(axis=1), labels.argmax(axis=1), -1),
    )


def members_arrays(pushes: list[PushMembers], plan: EnsemblePlan) -> dict[str, np.ndarray]:
    """The members of P pushes as the store's ``ensemble/`` arrays (docs/dataset-format.md), (P, K, ...);
    the plan gives a block without pushes its arrays' trailing shapes."""
    K, T = plan.members, plan.steps
    trailing = {"linear_velocity0": ((K, 3), np.float64), "angular_velocity0": ((K, 3), np.float64),
                "friction": ((K,), np.float64), "com_position": ((K, T, 3), np.float64),
                "orientation_xyzw": ((K, T, 4), np.float64), "topple_label": ((K, T), bool),
                "topple_step": ((K,), np.int32)}
    return {f"ensemble/{name}": np.asarray([getattr(p, name) for p in pushes], dtype=dtype).reshape((len(pushes),) + dims)
            for name, (dims, dtype) in trailing.items()}

