"""The dynamics model: its registered components (encoder, predictor, head) and the analytic prior it corrects."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Optional


@dataclass
class ComponentConfig:
    """One registered component: its registry ``name`` and its ``params`` (checked against its ``Config``)."""

    name: str = ""
    params: Dict[str, Any] = field(default_factory=dict)


@dataclass
class ModelConfig:
    encoder: ComponentConfig = field(default_factory=lambda: ComponentConfig("pointnet"))
    predictor: ComponentConfig = field(default_factory=lambda: ComponentConfig("lstm"))
    head: ComponentConfig = field(default_factory=lambda: ComponentConfig("topple"))
    encoder_init: Optional[str] = None  # encoder weights from `physdyn pretrain` (encoder.pt)
    # An analytic prior the network corrects (it predicts the residual): "none" (the paper), "kinematic"
    # (dp = v dt, dtheta = w dt, constant velocities) or "coulomb" (kinematic, with the horizontal velocity
    # slowed by Coulomb friction mu g, mu the training data's median friction), "planar" (coulomb, spin
    # stopping with the slide, tilt damped) or "contact" (slide and spin integrated under friction over the
    # footprint read from the point cloud; needs orientation_input). See physdyn/models/priors.py and
    # docs/research/contact-prior.md.
    prior: str = "none"
    # With a prior: below both of these speeds (horizontal m/s, rad/s) the network's residual is switched off
    # and the prior alone predicts the step (0: never). Chosen on validation, docs/research/training-recipe.md.
    residual_gate_linear: float = 0.0
    residual_gate_angular: float = 0.0
    # Feed the object's current orientation relative to step 0 (6D rotation representation) at every step;
    # the paper feeds velocities only, so the predictor is never told how the object has turned.
    orientation_input: bool = False
    # The contact prior's spin inertia (I_zz / m): "points" estimates it from the cloud (0.8 x the points'
    # mean squared radius); "body" takes the body's mass properties where the caller knows them (a store's
    # shapes, a mesh given to `physdyn predict`) and the estimate elsewhere. docs/research/contact-prior.md.
    contact_inertia: str = "points"
    # How the contact prior picks its 4 footprint points among the cloud's lowest: "spread" (farthest-point
    # sampling, the presets') or "area" (the 4 spanning the largest area, as the simulator's contact manifold
    # keeps them: finds a box face's corners; better on the procedural shapes, worse on irregular blobs;
    # docs/research/contact-prior.md). Acts at inference too: `export --set` may change it.
    contact_footprint: str = "spread"
    # The contact prior's sub-steps per recorded step (16: 1/240 s at 15 Hz); fewer cost less and integrate
    # more coarsely (docs/research/fast-cost.md). Acts at inference too (`export --set`).
    contact_substeps: int = 16
    # With a prior: the channels the network's residual corrects. "all" (velocity, spin, position, rotation),
    # "linear" (velocity and position; spin and rotation are the prior's) or "angular" (spin and rotation).
    # A "linear" network gave the best positions measured; `python -m physdyn.models.export --linear-from`
    # combines one with a model whose spin and rotation are better (docs/research/network-residual.md).
    residual_channels: str = "all"
    # Seconds at the start of a roll-out taken from PyBullet run on the point cloud's convex hull (the
    # body's inertia where the caller knows it, the conventions' physics step), rounded to recorded steps
    # (at least one), before the networks continue from the simulated state, their recurrent state warmed
    # up on the simulated velocities and orientations. 0: the networks from step 0 (the paper). Acts at
    # inference only (`export --set`): the impact phase is where the networks missed most
    # (docs/research/simulated-start.md).
    sim_seconds: float = 0.0
