"""The simulated world and the push: PyBullet's settings, the impulse, friction and mass.

Shared by dataset generation (`physdyn simulate`, inside ``DataConfig``) and by prediction and planning,
which simulate beside the model with the same settings.
"""

from __future__ import annotations

from dataclasses import dataclass

from physdyn.config.rules import FRACTION, NON_NEGATIVE, POSITIVE, VALUE_RULES, within


@dataclass
class PhysicsConfig:
    """PyBullet settings. Defaults are the paper's where it says, see docs/conventions.md."""

    # 1/960 s (the conventions): at 1/240 s the contact chatters and non-toppling objects pick up a
    # spurious tilt spin while sliding (median 0.59 rad/s) that a model would have to learn as noise.
    time_step: float = 1.0 / 960.0
    gravity: float = -9.81
    lateral_friction_object: float = 0.5
    lateral_friction_ground: float = 0.5  # Bullet multiplies: effective Coulomb mu = 0.25
    rolling_friction_object: float = 0.01  # without it round shapes roll until the time cap
    rolling_friction_ground: float = 0.0
    spinning_friction: float = 0.0
    linear_damping: float = 0.0  # PyBullet's default 0.04 would slow free motion
    angular_damping: float = 0.0
    restitution: float = 0.0
    rest_linear_speed: float = 0.01  # m/s
    rest_angular_speed: float = 0.1  # rad/s
    rest_duration: float = 0.5  # s at rest before the simulation stops
    max_duration: float = 7.0  # s


@dataclass
class ImpulseConfig:
    """The push: a horizontal force over one physics step with impulse = mass x speed."""

    speed_min: float = 0.5  # m/s
    speed_max: float = 2.0  # m/s
    # The push point's height is drawn within +/- this fraction of the object's height around the
    # centre-of-mass height; its sideways offset within +/- this fraction of the half-width (spin).
    height_fraction: float = 0.25
    lateral_fraction: float = 0.5


@dataclass
class FrictionConfig:
    """Per-simulation random friction for the friction-generalisation experiment."""

    random: bool = False
    # Range of the *effective* Coulomb coefficient (object x ground lateral friction).
    min: float = 0.1
    max: float = 0.5


@dataclass
class MassConfig:
    method: str = "exact"  # exact | voxel (the paper's estimate)
    density: float = 10.0  # kg/m^3; the paper's public data use 10
    voxel_pitch: float = 0.025  # m; reduced to smallest extent / 40 for small objects


VALUE_RULES[PhysicsConfig] = {
    "time_step": (within(1e-5, 0.1), "seconds per physics step, 1e-5 to 0.1 (the conventions: 1/960)"),
    "gravity": (within(-100, -0.1), "negative m/s^2 (z is up), e.g. -9.81"),
    "lateral_friction_object": NON_NEGATIVE, "lateral_friction_ground": NON_NEGATIVE,
    "rolling_friction_object": NON_NEGATIVE, "rolling_friction_ground": NON_NEGATIVE,
    "spinning_friction": NON_NEGATIVE, "linear_damping": NON_NEGATIVE, "angular_damping": NON_NEGATIVE,
    "restitution": FRACTION, "rest_linear_speed": POSITIVE, "rest_angular_speed": POSITIVE,
    "rest_duration": NON_NEGATIVE, "max_duration": (within(0, 600, low_open=True), "seconds, above 0 and at most 600"),
}
VALUE_RULES[ImpulseConfig] = {
    "speed_min": (within(0, 20, low_open=True), "m/s, above 0 and at most 20 (a hard push is a few m/s)"),
    "speed_max": (within(0, 20, low_open=True), "m/s, above 0 and at most 20 (a hard push is a few m/s)"),
    "height_fraction": FRACTION, "lateral_fraction": FRACTION,
}
VALUE_RULES[FrictionConfig] = {"min": POSITIVE, "max": POSITIVE}
VALUE_RULES[MassConfig] = {"density": POSITIVE, "voxel_pitch": POSITIVE}
