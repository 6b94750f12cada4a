"""Each metric against values worked out by hand on small made-up examples."""

import math

import numpy as np
import pytest

from physdyn.eval import metrics as M


def _deltas(dv, dw, dp, dr):
    return {"delta_linear_velocity": np.array([dv], float), "delta_angular_velocity": np.array([dw], float),
            "delta_position": np.array([dp], float), "delta_rotation": np.array([dr], float)}


# one sequence, two steps
PRED = _deltas(dv=[[3, 4, 0], [0, 0, 0]], dw=[[0, 0, 2], [0, 0, 0]], dp=[[1, 0, 0], [0, 2, 0]],
               dr=[[0, 0.3, 0.4], [0.02, 0, 0]])
TRUE = _deltas(dv=[[0, 0, 0], [1, 0, 0]], dw=[[0, 0, 1], [0, 0, 0]], dp=[[1, 1, 0], [0, 1, 0]],
               dr=[[0, 0, 0.5], [0.01, 0, 0]])  # step 1 turns 0.57 deg: below the axis error's 1 deg


def test_step_errors_by_hand():
    e = M.step_errors(PRED, TRUE)
    np.testing.assert_allclose(e["linear_velocity"], [[5.0, 1.0]])
    np.testing.assert_allclose(e["angular_velocity"], [[1.0, 0.0]])
    np.testing.assert_allclose(e["position"], [[1.0, 1.0]])
    # |0.5 - 0.5| = 0 at step 0; |0.02 - 0.01| rad = 0.573 deg at step 1
    np.testing.assert_allclose(e["angle_deg"], [[0.0, math.degrees(0.01)]], atol=1e-12)
    # step 0: cos = (0.4 * 0.5) / (0.5 * 0.5) = 0.8 -> 0.2; step 1: masked (true angle < 1 deg)
    assert e["axis"][0, 0] == pytest.approx(0.2)
    assert np.isnan(e["axis"][0, 1])


def test_axis_error_counts_from_one_degree():
    one_deg = math.radians(1.0)
    pred = _deltas([[0, 0, 0]] * 2, [[0, 0, 0]] * 2, [[0, 0, 0]] * 2, [[0, one_deg, 0], [0, one_deg, 0]])
    true = _deltas([[0, 0, 0]] * 2, [[0, 0, 0]] * 2, [[0, 0, 0]] * 2, [[one_deg * 1.001, 0, 0], [one_deg * 0.999, 0, 0]])
    axis = M.step_errors(pred, true)["axis"]
    assert axis[0, 0] == pytest.approx(1.0)  # perpendicular axes, angle just over 1 deg: counted
    assert np.isnan(axis[0, 1])  # just under: ignored
    # opposite axes give the maximum, 2
    assert M.step_errors(pred, _deltas(*[[[0, 0, 0]]] * 3, [[0, -0.5, 0]]))["axis"][0, 0] == pytest.approx(2.0)


def test_averaged_over_steps_then_over_sequences():
    errors = {"position": np.array([[1.0, 3.0], [10.0, 99.0]])}
    valid = np.array([[True, True], [True, False]])
    per_seq = M.sequence_means(errors, valid)
    np.testing.assert_allclose(per_seq["position"], [2.0, 10.0])
    assert M.mean_over_sequences(per_seq)["position"] == pytest.approx(6.0)  # not the step-weighted 14 / 3
    # NaN steps (masked axis errors) are skipped; a sequence with none left is NaN and skipped too
    per_seq = M.sequence_means({"axis": np.array([[np.nan, 0.5], [np.nan, np.nan]])})
    assert per_seq["axis"][0] == 0.5 and np.isnan(per_seq["axis"][1])
    assert M.mean_over_sequences(per_seq)["axis"] == 0.5


def test_relative_errors_follow_the_documented_definitions():
    seq = M.relative_errors(PRED, TRUE, kind="sequence")
    step = M.relative_errors(PRED, TRUE, kind="step")
    r2 = math.sqrt(2)
    # sequence form: sum_t ||x^ - x|| / sum_t ||x||
    assert seq["position"][0] == pytest.approx(2 / (r2 + 1))
    assert seq["linear_velocity"][0] == pytest.approx(6 / 1)
    assert seq["angle"][0] == pytest.approx(0.01 / 0.51)
    # step form (the paper's relative loss): mean_t ||x^ - x|| / (||x|| + ||x^||)
    assert step["position"][0] == pytest.approx((1 / (r2 + 1) + 1 / 3) / 2)
    assert step["linear_velocity"][0] == pytest.approx(1.0)  # 5/5 and 1/1
    assert step["angle"][0] == pytest.approx((0 / 1.0 + 0.01 / 0.03) / 2)
    # angular velocity step 1: both zero (0/0) is skipped, not counted: only step 0's 1 / (1 + 2)
    assert step["angular_velocity"][0] == pytest.approx(1 / 3)
    # padding is excluded
    valid = np.array([[True, False]])
    assert M.relative_errors(PRED, TRUE, valid, kind="sequence")["position"][0] == pytest.approx(1 / r2)
    assert M.relative_errors(PRED, TRUE, valid, kind="step")["position"][0] == pytest.approx(1 / (r2 + 1))
    # a perfect prediction is 0; a sequence with no true change at all is NaN (nothing to normalise by)
    assert M.relative_errors(TRUE, TRUE)["position"][0] == 0.0
    zero = {k: np.zeros_like(v) for k, v in TRUE.items()}
    assert np.isnan(M.relative_errors(PRED, zero)["position"][0])


def test_final_errors_use_each_sequences_last_real_step():
    s = math.sqrt(0.5)
    q_true = np.array([[[0, 0, 0, 1], [0, 0, 0, 1], [0, 0, 0, 1]]], float).repeat(2, axis=0)
    q_pred = q_true.copy()
    q_pred[0, 1] = [0, 0, s, s]  # 90 deg about z at step 1 (sequence 0's last real step)
    q_pred[1, 2] = [0, 0, 0, -1]  # -q is the same rotation: 0 deg
    p_true = np.zeros((2, 3, 3))
    p_pred = np.zeros((2, 3, 3))
    p_pred[0, 1] = [0.3, 0.4, 0]
    p_pred[0, 2] = [9, 9, 9]  # padding past sequence 0's end: ignored
    p_pred[1, 2] = [0, 0, 0.1]
    out = M.final_errors(p_pred, q_pred, p_true, q_true, last=np.array([1, 2]))
    np.testing.assert_allclose(out["position_m"], [0.5, 0.1])
    np.testing.assert_allclose(out["rotation_deg"], [90.0, 0.0], atol=1e-6)
    assert M.rotation_angle_deg(np.array([0, 0, 1.0, 0]), np.array([0, 0, 0, 1.0])) == pytest.approx(180.0)


def test_topple_classification_rates_by_hand():
    prob = np.array([
        [0, 0.6, 0.2],   # toppled, predicted (any step >= 0.5): TP
        [0, 0.49, 0.5],  # toppled; the 0.5 is on padding past its end: FN
        [0, 0.1, 0.2],   # upright: TN
        [0, 0.5, 0.0],   # upright, 0.5 counts as a topple: FP
        [0, 0.0, 0.0],   # upright: TN
    ])
    valid = np.ones_like(prob, dtype=bool)
    valid[1, 2] = False
    predicted = M.predicted_topple(prob, valid)
    np.testing.assert_array_equal(predicted, [True, False, False, True, False])
    out = M.topple_classification(predicted, np.array([True, True, False, False, False]))
    assert (out["tp"], out["fn"], out["tn"], out["fp"]) == (1, 1, 2, 1)
    assert out["tp_rate"] == pytest.approx(1 / 2) and out["fn_rate"] == pytest.approx(1 / 2)
    assert out["tn_rate"] == pytest.approx(2 / 3) and out["fp_rate"] == pytest.approx(1 / 3)
    assert out["accuracy"] == pytest.approx(3 / 5)
    assert out["f1"] == pytest.approx(2 * 1 / (2 * 1 + 1 + 1))
    empty = M.topple_classification(np.array([False]), np.array([False]))
    assert math.isnan(empty["tp_rate"]) and math.isnan(empty["f1"]) and empty["tn_rate"] == 1.0


def test_error_curve_is_the_mean_over_sequences_still_running():
    errors = np.array([[1.0, 2.0, 3.0], [3.0, np.nan, 5.0]])
    valid = np.array([[True, True, False], [True, True, True]])
    mean, count = M.error_curve(errors, valid)
    np.testing.assert_allclose(mean, [2.0, 2.0, 5.0])
    np.testing.assert_array_equal(count, [2, 1, 1])
    mean, count = M.error_curve(np.ones((1, 2)), np.array([[True, False]]))
    assert np.isnan(mean[1]) and count[1] == 0
    np.testing.assert_allclose(M.position_error_curve(np.array([[[0, 3, 4.0]]]), np.zeros((1, 1, 3))), [[5.0]])


def test_error_quantiles_are_over_the_sequences_still_running():
    errors = np.array([[1.0, 2.0, 9.0], [3.0, np.nan, 5.0], [5.0, 4.0, 7.0], [7.0, 6.0, 1.0]])
    valid = np.array([[True, True, False], [True, True, True], [True, True, True], [True, True, False]])
    q = M.error_quantiles(errors, valid)
    np.testing.assert_allclose(q[:, 0], np.quantile([1, 3, 5, 7], [0.25, 0.5, 0.75]))
    np.testing.assert_allclose(q[:, 1], np.quantile([2, 4, 6], [0.25, 0.5, 0.75]))  # the NaN does not count
    np.testing.assert_allclose(q[:, 2], np.quantile([5, 7], [0.25, 0.5, 0.75]))  # ended sequences do not count
    assert np.isnan(M.error_quantiles(np.ones((2, 2)), np.array([[True, False], [True, False]]))[:, 1]).all()
