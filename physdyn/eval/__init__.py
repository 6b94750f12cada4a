"""Evaluation: roll-outs of a model or a baseline, the reference code's metrics, and reports.

- ``rollout``: the model's own predicted velocities fed back, the pose integrated (``rollout.py``)
- ``metrics``: per-step, relative, accumulated and topple-classification errors (pure numpy)
- ``baselines``: predictors that need no learning (stay put, Coulomb slide)
- ``evaluate``: every metric over a store's split, per category, and side-by-side comparisons
"""
