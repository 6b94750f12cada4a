"""The distribution scores against hand computations, their floors and estimators, and their statistics on toys
whose answer is known."""

import math
import subprocess
import sys

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from physdyn.eval import scores as S

# three 2-D samples and two members, in metres
SAMPLES = np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0]])
MEMBERS = np.array([[0.0, 0.0], [3.0, 4.0]])


def test_position_energy_score_by_hand():
    # distances to member (0, 0): 0, 3, 4 -> mean 7/3; to member (3, 4): 5, 4, 3 -> mean 4; over members 19/6
    first = (7 / 3 + 4) / 2
    # sample pairs: 3, 4, 5, each twice over the ordered pairs: 24
    fair = first - 0.5 * 24 / (3 * 2)  # 19/6 - 2 = 7/6
    plain = first - 0.5 * 24 / 3**2  # 19/6 - 4/3 = 11/6
    assert S.energy_score(SAMPLES, MEMBERS) == pytest.approx(7 / 6)
    assert fair == pytest.approx(7 / 6)
    assert S.energy_score(SAMPLES, MEMBERS, fair=False) == pytest.approx(plain)
    assert S.position_energy_score_cm(SAMPLES, MEMBERS) == pytest.approx(100 * 7 / 6)
    # floor: one member pair at distance 5, twice over the K (K-1) = 2 ordered pairs, halved
    assert S.position_energy_floor_cm(MEMBERS) == pytest.approx(100 * 0.5 * (5 + 5) / 2)


def test_one_sample_scores_as_a_point_mass():
    # no spread term: the mean distance to the members
    assert S.energy_score(SAMPLES[1:2], MEMBERS) == pytest.approx((3 + 4) / 2)
    assert S.energy_score(SAMPLES[1:2], MEMBERS, fair=False) == pytest.approx(3.5)


def test_fair_estimator_differs_from_the_plain_one_as_it_should():
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(7, 3)), rng.normal(size=(5, 3))
    n = len(x)
    pair_sum = np.linalg.norm(x[:, None] - x[None], axis=-1).sum()
    # plain - fair = 1/2 sum (1/(N (N-1)) - 1/N^2) = sum / (2 N^2 (N-1))
    gap = S.energy_score(x, y, fair=False) - S.energy_score(x, y)
    assert gap == pytest.approx(pair_sum / (2 * n**2 * (n - 1)))


def test_a_perfect_forecast_scores_the_floor_and_the_fair_estimator_is_unbiased_for_few_samples():
    rng = np.random.default_rng(1)
    cov = np.array([[4.0, 1.2, 0.0], [1.2, 1.0, 0.3], [0.0, 0.3, 0.5]]) * 1e-4
    draw = lambda *shape: rng.multivariate_normal([0.2, -0.1, 0.05], cov, size=shape)  # noqa: E731
    x, y = draw(20, 300), draw(20, 300)  # 20 pushes, N = K = 300
    floor = S.position_energy_floor_cm(y).mean()
    assert S.position_energy_score_cm(x, y).mean() == pytest.approx(floor, rel=0.02)
    assert S.position_energy_score_cm(x + [0.02, 0.0, 0.0], y).mean() > 1.2 * floor  # 2 cm off: clearly worse (1.33)
    # four samples a push: the fair estimator stays on the floor, the plain one is above it by E||X-X'|| / (2N)
    x, y = draw(3000, 4), draw(3000, 8)
    fair, plain = S.energy_score(x, y).mean(), S.energy_score(x, y, fair=False).mean()
    floor = S.energy_score_floor(y).mean()
    assert fair == pytest.approx(floor, rel=0.03)
    assert plain == pytest.approx(floor * (1 + 1 / 4), rel=0.03)


def test_energy_score_equals_the_librarys_public_score_of_each_member():
    import scoringrules

    rng = np.random.default_rng(11)
    x, y = rng.normal(size=(6, 3)), rng.normal(size=(4, 3))
    for fair, estimator in ((True, "fair"), (False, "nrg")):
        public = [scoringrules.es_ensemble(member, x, estimator=estimator, backend="numpy") for member in y]
        assert S.energy_score(x, y, fair=fair) == pytest.approx(np.mean(public))


def test_batched_scores_equal_the_scores_of_each_push():
    rng = np.random.default_rng(2)
    x, y = rng.normal(size=(2, 3, 5, 2)), rng.normal(size=(2, 3, 6, 2))
    batched = S.energy_score(x, y)
    assert batched.shape == (2, 3)
    for i in range(2):
        for j in range(3):
            assert batched[i, j] == pytest.approx(float(S.energy_score(x[i, j], y[i, j])))


def test_chordal_distance_equals_the_rotation_matrices_frobenius_distance_over_sqrt2():
    a, b = Rotation.random(50, random_state=3), Rotation.random(50, random_state=4)
    frobenius = np.linalg.norm(a.as_matrix() - b.as_matrix(), axis=(-2, -1))
    expected = np.degrees(frobenius / math.sqrt(2))
    np.testing.assert_allclose(S.chordal_distance_deg(a.as_quat(), b.as_quat()), expected, atol=1e-9)
    theta = (a.inv() * b).magnitude()  # (360/pi) sin(theta/2)
    np.testing.assert_allclose(expected, 360 / math.pi * np.sin(theta / 2), atol=1e-9)
    assert S.chordal_distance_deg([0, 0, 0, 1], Rotation.from_euler("z", 90, degrees=True).as_quat()) == \
        pytest.approx(360 / math.pi * math.sqrt(0.5))


def test_orientation_energy_score_by_hand():
    s = 360 / math.pi  # the chordal distance in degrees of a half turn; of a quarter turn it is s sqrt(2)/2
    identity, quarter_z = [0, 0, 0, 1], Rotation.from_euler("z", 90, degrees=True).as_quat()
    half_x = Rotation.from_euler("x", 180, degrees=True).as_quat()  # a half turn from both others
    samples, members = np.array([identity, quarter_z, half_x]), np.array([identity, quarter_z])
    # to member identity: 0, s sqrt2/2, s; to member quarter_z: s sqrt2/2, 0, s; each mean s (1 + sqrt2/2)/3
    first = s * (1 + math.sqrt(2) / 2) / 3
    # sample pairs: s sqrt2/2, s, s, twice over the 6 ordered pairs
    spread = 2 * s * (math.sqrt(2) / 2 + 2) / 6
    assert S.orientation_energy_score_deg(samples, members) == pytest.approx(first - spread / 2)
    assert S.orientation_energy_floor_deg(members) == pytest.approx(s * math.sqrt(2) / 2 / 2)


def test_orientation_score_is_invariant_to_the_quaternion_sign():
    rng = np.random.default_rng(5)
    x = Rotation.random(12, random_state=6).as_quat().reshape(2, 6, 4)
    y = Rotation.random(10, random_state=7).as_quat().reshape(2, 5, 4)
    flip_x = np.where(rng.random((2, 6, 1)) < 0.5, -1.0, 1.0)
    flip_y = np.where(rng.random((2, 5, 1)) < 0.5, -1.0, 1.0)
    np.testing.assert_allclose(S.orientation_energy_score_deg(x * flip_x, y * flip_y),
                               S.orientation_energy_score_deg(x, y), atol=1e-9)
    np.testing.assert_allclose(S.orientation_energy_floor_deg(y * flip_y), S.orientation_energy_floor_deg(y),
                               atol=1e-9)


def test_brier_score_by_hand():
    # p = 1/4 against members that topple, stay, stay: ((3/4)^2 + (1/4)^2 + (1/4)^2) / 3 = 11/48
    assert S.brier_score(0.25, [1, 0, 0]) == pytest.approx((0.5625 + 0.0625 + 0.0625) / 3)
    assert S.brier_score(0.25, [1, 0, 0]) == pytest.approx((0.25 - 1 / 3) ** 2 + (1 / 3) * (2 / 3))
    # floor: K/(K-1) f (1 - f) = 3/2 * 1/3 * 2/3 = 1/3
    assert S.brier_floor([1, 0, 0]) == pytest.approx(1 / 3)
    np.testing.assert_allclose(S.brier_score([0.0, 1.0], [[0, 0], [1, 0]]), [0.0, 0.5])
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        S.brier_score(1.5, [1, 0])


def test_reliability_diagram_and_ece_by_hand(tmp_path):
    p = np.array([0.05, 0.15, 0.12, 0.95, 1.0])
    observed = np.array([0.0, 0.5, 0.0, 1.0, 1.0])  # the members' topple fractions
    d = S.reliability_diagram(p, observed, n_bins=10)
    assert d.count.tolist() == [1, 2, 0, 0, 0, 0, 0, 0, 0, 2]  # 1.0 falls in the last bin
    np.testing.assert_allclose(d.mean_predicted[[0, 1, 9]], [0.05, 0.135, 0.975])
    np.testing.assert_allclose(d.observed_frequency[[0, 1, 9]], [0.0, 0.25, 1.0])
    assert np.isnan(d.mean_predicted[2])
    # (1 * 0.05 + 2 * |0.135 - 0.25| + 2 * 0.025) / 5
    assert d.expected_calibration_error == pytest.approx((0.05 + 2 * 0.115 + 2 * 0.025) / 5)
    # members' 0/1 labels give the same diagram as their fractions
    labels = np.array([[0, 0], [1, 0], [0, 0], [1, 1], [1, 1]])
    assert S.expected_calibration_error(p, labels) == pytest.approx(d.expected_calibration_error)
    png = S.plot_reliability_diagram(d, tmp_path / "figures" / "reliability.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_ece_is_zero_when_calibrated_and_positive_when_not():
    rng = np.random.default_rng(8)
    p = rng.random(20000)
    assert S.expected_calibration_error(p, p) == pytest.approx(0.0, abs=1e-12)  # fractions equal the forecast
    labels = (rng.random((20000, 4)) < p[:, None]).astype(float)  # members drawn with the forecast's probability
    assert S.expected_calibration_error(p, labels) < 0.01
    assert S.expected_calibration_error(p**3, labels) > 0.1  # under-confident about toppling


def test_prediction_radius_is_the_hotelling_region_and_tends_to_chi_square():
    for n in (3, 5, 16, 64):
        hotelling = 2 * (n - 1) * (n + 1) / (n * (n - 2)) * stats.f.ppf(0.9, 2, n - 2)
        assert S.prediction_radius2(n, 0.9) == pytest.approx(hotelling)
    assert S.prediction_radius2(10**7, 0.9) == pytest.approx(stats.chi2.ppf(0.9, 2), rel=1e-5)
    with pytest.raises(ValueError, match="at least 3 samples"):
        S.prediction_radius2(2, 0.9)
    with pytest.raises(ValueError, match="level"):
        S.prediction_radius2(10, 1.0)


def test_the_region_ellipse_by_hand():
    # four points at (+-2, 0), (0, +-1): mean 0, covariance diag(8/3, 2/3) (divisor N - 1 = 3), turned by 30 deg
    turn = Rotation.from_euler("z", 30, degrees=True).as_matrix()[:2, :2]
    points = np.array([[2.0, 0.0], [-2.0, 0.0], [0.0, 1.0], [0.0, -1.0]]) @ turn.T + [1.0, 2.0]
    region = S.position_region(points, 0.9)
    r2 = (4**2 - 1) / 4 * (0.1 ** (-2 / 2) - 1)  # 15/4 * 9 = 33.75
    assert region.radius2 == pytest.approx(r2)
    np.testing.assert_allclose(region.centre, [1.0, 2.0])
    np.testing.assert_allclose(region.semi_axes, np.sqrt(r2 * np.array([8 / 3, 2 / 3])), rtol=1e-9)
    assert region.angle_deg == pytest.approx(30.0)
    outline = region.boundary(16)
    assert outline.shape == (16, 2)
    assert np.allclose(outline[0], outline[-1])
    just_inside = region.centre + 0.999 * region.semi_axes[0] * region.axes[:, 0]
    just_outside = region.centre + 1.001 * region.semi_axes[1] * region.axes[:, 1]
    assert region.contains(just_inside) and not region.contains(just_outside)


def test_coverage_of_same_distribution_is_the_level():
    rng = np.random.default_rng(9)
    cov = np.array([[4.0, 1.2], [1.2, 1.0]]) * 1e-4
    x, y = rng.multivariate_normal([1, 2], cov, size=4000), rng.multivariate_normal([1, 2], cov, size=4000)
    assert S.region_coverage(x, y, 0.9) == pytest.approx(0.9, abs=0.015)
    assert S.region_coverage(x, y, 0.5) == pytest.approx(0.5, abs=0.025)
    region = S.position_region(x, 0.9)
    semi_axes = np.sqrt(stats.chi2.ppf(0.9, 2) * np.linalg.eigvalsh(cov)[::-1])
    np.testing.assert_allclose(region.semi_axes, semi_axes, rtol=0.05)
    # 16 samples a push: the prediction radius keeps the mean coverage at the level
    x, y = rng.multivariate_normal([1, 2], cov, size=(1000, 16)), rng.multivariate_normal([1, 2], cov, size=(1000, 32))
    assert S.region_coverage(x, y, 0.9).mean() == pytest.approx(0.9, abs=0.015)
    # samples all at one point: a tiny region that holds only members there
    assert S.region_coverage(np.zeros((5, 3)), [[0, 0, 0.1], [0.01, 0, 0]], 0.9) == pytest.approx(0.5)


def test_score_pushes_gathers_every_score():
    rng = np.random.default_rng(10)
    positions, members = rng.normal(size=(4, 8, 3)) * 0.01, rng.normal(size=(4, 6, 3)) * 0.01
    q = Rotation.random(32, random_state=11).as_quat().reshape(4, 8, 4)
    qm = Rotation.random(24, random_state=12).as_quat().reshape(4, 6, 4)
    p, topples = rng.random(4), (rng.random((4, 6)) < 0.3).astype(float)
    result = S.score_pushes(positions, members, q, qm, p, topples)
    assert set(result.per_push) == {"position_es_cm", "position_floor_cm", "orientation_es_deg",
                                    "orientation_floor_deg", "brier", "brier_floor", "coverage_50", "coverage_90"}
    assert all(v.shape == (4,) for v in result.per_push.values())
    one = S.position_energy_score_cm(positions[2], members[2])
    np.testing.assert_allclose(result.per_push["position_es_cm"][2], one)
    assert result.mean["brier"] == pytest.approx(np.mean(S.brier_score(p, topples)))
    assert result.mean["ece"] == pytest.approx(S.expected_calibration_error(p, topples))
    assert set(S.score_pushes(positions, members).mean) == {"position_es_cm", "position_floor_cm", "coverage_50",
                                                            "coverage_90"}
    with pytest.raises(ValueError, match="same leading axes"):
        S.score_pushes(positions, members[:3])


def test_importing_the_scores_loads_no_model_code():
    code = ("import sys, physdyn.eval.scores; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'lightning', 'scoringrules')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
