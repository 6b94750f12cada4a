"""PyBullet on a body made from a point cloud alone: its mass properties, and short roll-outs' tilt."""

import numpy as np
import pytest
import trimesh

from physdyn.config import PhysicsConfig
from physdyn.geometry.sampling import sample_surface_points
from physdyn.predict.simulator import simulate_from_state
from physdyn.sim.body import rigid_body
from physdyn.sim.cloud_body import CloudSimulator, cloud_body_spec
from physdyn.sim.trajectory import topple_labels


def _box_cloud(extents, n=1024, seed=0):
    return sample_surface_points(trimesh.creation.box(extents), n, 3, seed=seed)


def test_a_box_cloud_makes_the_box_solid():
    a, b, c = 0.1, 0.2, 0.4
    spec = cloud_body_spec(_box_cloud((a, b, c)))
    # a solid box: I / m = (sum of the other two sides squared) / 12, about its own centre
    per_mass = np.sort(spec.inertia_diag / spec.mass)
    np.testing.assert_allclose(per_mass, np.sort([(b * b + c * c) / 12, (a * a + c * c) / 12, (a * a + b * b) / 12]), rtol=0.03)
    assert spec.mass == pytest.approx(1000 * a * b * c, rel=0.03)
    body = spec.body_vertices()
    np.testing.assert_allclose(body.max(axis=0) - body.min(axis=0), [a, b, c], rtol=0.03)
    # the inertia is taken about the cloud's origin (the known centre of mass), not the hull's centroid
    shifted = cloud_body_spec(_box_cloud((a, b, c)) + [0.0, 0.0, 0.05])
    assert shifted.inertia_diag.max() / shifted.mass > per_mass.max() + 0.05 ** 2 * 0.9
    with pytest.raises(ValueError, match="no 3D convex hull"):
        cloud_body_spec(np.c_[np.random.default_rng(0).normal(size=(64, 2)), np.zeros(64)])  # flat


def test_short_rollouts_tilt_a_tall_box_over_and_leave_a_squat_one_standing():
    tall, squat = _box_cloud((0.06, 0.06, 0.3)), _box_cloud((0.2, 0.2, 0.08), seed=1)
    points = np.stack([tall, squat, tall, squat])
    v = np.array([[0.5, 0.0, 0.0], [1.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.3, 0.0, 0.0]])
    w = np.array([[0.0, 12.0, 0.0], [0.0, 0.0, 3.0], [0.0, 2.0, 0.0], [0.0, 0.0, 0.0]])
    with CloudSimulator() as sim:
        tilt = sim.max_tilt(points, v, w, friction=0.25)
        again = np.concatenate([sim.max_tilt(points[i : i + 1], v[i : i + 1], w[i : i + 1], 0.25) for i in range(4)])
    assert tilt.shape == (4, 3) and (np.diff(tilt, axis=1) >= 0).all()  # the largest so far, per horizon
    np.testing.assert_allclose(tilt, again, atol=1e-9)  # a body per cloud, reused: the same roll-outs
    assert tilt[0, -1] > 80  # a hard tilt spin topples the tall box
    assert tilt[1, -1] < 2 and tilt[3, -1] < 2  # sliding and spinning flat leaves a squat box upright
    assert 1 < tilt[2, -1] < 45, tilt[2]  # a milder push rocks it and it falls back

    # the same verdicts as the conventions' simulation of the real box mesh (1/960 s)
    box = rigid_body(trimesh.creation.box((0.06, 0.06, 0.3)), "tall", 500.0)
    for i in (0, 2):
        real = simulate_from_state(box.spec, np.array([0, 0, 0, 1.0]), v[i], w[i], 15.0, 16, PhysicsConfig())
        assert (topple_labels(real["orientation_xyzw"])[1] >= 0) == (tilt[i, -1] > 45)
