"""The results page's verdicts: the sentences that say whether a model beats a baseline and whether a result
agrees with the paper follow the numbers, and turn round when the numbers do. The runs are fake metrics files
in the layout of a real evaluation (``OUT/eval/<name>/metrics.json``), so no training is needed."""

from __future__ import annotations

import json

from physdyn.experiments import results_page as page
from physdyn.experiments.suite import CATEGORIES, FRICTION_WARM_STARTS

QUANTITIES = ("linear_velocity", "angular_velocity", "position", "angle")


def fake_result(position: float, relative: dict[str, float] | None = None) -> dict:
    """One model's (or baseline's) result as `compare` writes it, with the numbers the page reads."""
    nt = {"count": 20, "rollout": {"position": position, "angle_deg": 1.0, "linear_velocity": 0.1, "angular_velocity": 0.2},
          "relative": relative or {k: 0.1 for k in QUANTITIES},
          "final_position_m": {"median": 10 * position}, "final_rotation_deg": {"median": 5.0}}
    return {"rollout": {"non_toppling": nt, "all": {"count": 25}, "toppling": {"count": 5}}, "topple": None}


def write_eval(out, name: str, position: float, relative: dict[str, float] | None = None,
               coulomb: float | None = None) -> None:
    results = {"model": fake_result(position, relative)}
    if coulomb is not None:
        results.update(stay_put=fake_result(10 * coulomb), coulomb_slide=fake_result(coulomb))
    folder = out / "eval" / name
    folder.mkdir(parents=True)
    (folder / "metrics.json").write_text(json.dumps({"model": "model", "results": results}))


def text(lines: list[str]) -> str:
    return "\n".join(lines)


def test_lstm_against_mlp_agrees_with_the_paper_only_when_the_lstm_is_better(tmp_path):
    write_eval(tmp_path / "a", "speakers-lstm", 0.010, coulomb=0.03)
    write_eval(tmp_path / "a", "speakers-mlp", 0.020)
    agrees = text(page._section_mlp(page._Results(tmp_path / "a"), {}))
    assert "As in the paper, the LSTM is better: position error 0.01 vs 0.02 m/step" in agrees
    assert "contradicts" not in agrees

    write_eval(tmp_path / "b", "speakers-lstm", 0.020, coulomb=0.03)
    write_eval(tmp_path / "b", "speakers-mlp", 0.010)
    disagrees = text(page._section_mlp(page._Results(tmp_path / "b"), {}))
    assert "**This contradicts the paper**: the MLP's position error (0.01 m/step) is not above the LSTM's (0.02" in disagrees
    assert "As in the paper" not in disagrees


def test_no_verdict_on_lstm_against_mlp_when_one_of_them_was_not_run(tmp_path):
    write_eval(tmp_path, "speakers-lstm", 0.010, coulomb=0.03)
    section = text(page._section_mlp(page._Results(tmp_path), {}))
    assert "| MLP | not run |" in section
    assert "As in the paper" not in section and "contradicts" not in section


def test_30_hz_agrees_with_the_supplement_only_when_every_relative_error_is_lower(tmp_path):
    at_15 = {"linear_velocity": 0.09, "angular_velocity": 0.08, "position": 0.08, "angle": 0.006}
    write_eval(tmp_path / "a", "speakers-lstm", 0.01, at_15, coulomb=0.03)
    write_eval(tmp_path / "a", "speakers-30hz", 0.01, {k: v / 2 for k, v in at_15.items()})
    agrees = text(page._section_rate(page._Results(tmp_path / "a"), {}))
    assert "As in the supplement, 30 Hz gives lower relative errors on all four quantities." in agrees
    assert "contradicts" not in agrees
    assert "| 30 Hz | ours | 4.50 % | 4.00 % | 4.00 % | 0.30 % |" in agrees

    # only the position error is worse at 30 Hz: the verdict names it and only it
    write_eval(tmp_path / "b", "speakers-lstm", 0.01, at_15, coulomb=0.03)
    write_eval(tmp_path / "b", "speakers-30hz", 0.01, {**{k: v / 2 for k, v in at_15.items()}, "position": 0.09})
    disagrees = text(page._section_rate(page._Results(tmp_path / "b"), {}))
    assert "**This contradicts the paper** for p: the 30 Hz model's relative error is not below" in disagrees
    assert "As in the supplement" not in disagrees


def test_friction_warm_starts_agree_with_the_supplement_only_when_the_error_falls(tmp_path):
    for k, position in zip(FRICTION_WARM_STARTS, (0.04, 0.03, 0.02, 0.01)):
        write_eval(tmp_path / "a", f"friction-warm{k}", position, coulomb=0.05)
    agrees = text(page._section_friction(page._Results(tmp_path / "a"), {}))
    assert "As in the supplement, the position error falls as more true velocity steps are given." in agrees
    assert "contradicts" not in agrees

    for k, position in zip(FRICTION_WARM_STARTS, (0.04, 0.03, 0.035, 0.01)):  # warm start 3 is worse than 1
        write_eval(tmp_path / "b", f"friction-warm{k}", position, coulomb=0.05)
    disagrees = text(page._section_friction(page._Results(tmp_path / "b"), {}))
    assert ("**This contradicts the supplement**: the position error does not fall steadily with more warm-start "
            "steps (0.04, 0.03, 0.035, 0.01 m/step for 0/1/3/5).") in disagrees
    assert "As in the supplement" not in disagrees


def write_generalisation(out, category: str, single: float, combined: float, leaveout: float, coulomb: float) -> None:
    write_eval(out, f"single-{category}", single)
    write_eval(out, f"combined-{category}", combined, coulomb=coulomb)
    write_eval(out, f"leaveout-{category}", leaveout)


def test_a_model_behind_coulomb_sliding_is_flagged_and_one_ahead_is_not(tmp_path):
    for c in CATEGORIES:
        write_generalisation(tmp_path / "ahead", c, single=0.010, combined=0.011, leaveout=0.020, coulomb=0.030)
        combined = 0.040 if c == "mugs" else 0.011  # mugs: the Combined model falls behind sliding
        write_generalisation(tmp_path / "behind", c, single=0.010, combined=combined, leaveout=0.020, coulomb=0.030)

    clean = text(page._section_generalisation(page._Results(tmp_path / "ahead"), {}))
    assert "- nothing flagged (or not run)." in clean and "not below Coulomb sliding's" not in clean

    flagged = text(page._section_generalisation(page._Results(tmp_path / "behind"), {}))
    assert "- mugs: position error not below Coulomb sliding's (0.03 m/step): Combined 0.04 m/step." in flagged
    assert "nothing flagged" not in flagged
    assert sum("not below Coulomb sliding's" in line for line in flagged.splitlines()) == 1  # mugs only


def test_a_leave_out_model_no_worse_than_single_is_flagged(tmp_path):
    for c in CATEGORIES:
        leaveout = 0.008 if c == "bottles" else 0.020  # bottles: the model that never saw the category does better
        write_generalisation(tmp_path, c, single=0.010, combined=0.011, leaveout=leaveout, coulomb=0.030)
    section = text(page._section_generalisation(page._Results(tmp_path), {}))
    assert ("- bottles: Leave-out (0.008 m/step) is not worse than Single (0.01 m/step) on position, although the "
            "Leave-out model never saw this category.") in section
    assert sum("is not worse than Single" in line for line in section.splitlines()) == 1
