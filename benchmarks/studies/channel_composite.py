"""Two trained models rolled out as one: the linear channels (Δv, Δp) from the first, the angular ones
(Δω, Δθ) from the second. Both networks see the same state at every step (the composite's own velocities
and orientation), each keeps its own LSTM state. The linear model's residual is restricted to the linear
channels as in linear_residual.py (its Δω, Δθ are not used anyway). A study, not a physdyn option.

    python benchmarks/studies/channel_composite.py val runs/qs_linonly/best.ckpt physdyn/assets/bundled.ckpt data/quickstart.zarr
    python benchmarks/studies/channel_composite.py test LIN ROT data/quickstart.zarr
    python benchmarks/studies/channel_composite.py external LIN ROT --work runs/external_val --random 60 --random-from 30 --no-named
"""
import runpy
import sys
from pathlib import Path

import torch

from physdyn.data.store import load_store
from physdyn.eval.baselines import load_checkpoint
from physdyn.eval.evaluate import evaluate
from physdyn.models.rotations import quat_multiply, rotvec_to_quat

LINEAR = torch.tensor([1.0] * 3 + [0.0] * 3 + [1.0] * 3 + [0.0] * 3, dtype=torch.float64)  # [dv, dw, dp, dtheta]


class ChannelComposite:
    """Enough of a DynamicsModel for ``physdyn.eval``: roll-outs and teacher-forced windows."""

    def __init__(self, linear, angular):
        self.linear, self.angular = linear, angular
        self.topple_classifier = getattr(angular, "topple_classifier", None)

    def __getattr__(self, name):  # num_points, uses_orientation, predicts_topple, ...: the angular model's
        return getattr(self.angular, name)

    def to(self, device):  # a study on the CPU
        return self

    def with_spin_inertia(self, code, spin_inertia):  # marks "takes the body's inertia" for physdyn.eval.rollout
        return code

    def predict_window(self, *args, **kwargs):
        a, b = self.linear.predict_window(*args, **kwargs), self.angular.predict_window(*args, **kwargs)
        b.delta_linear_velocity, b.delta_position = a.delta_linear_velocity, a.delta_position
        return b

    def rollout_changes(self, points, linear_velocity0, angular_velocity0, steps, warm_linear=None, warm_angular=None,
                        spin_inertia=None, topple=True):
        assert warm_linear is None, "no warm start in this study"
        models = [self.linear, self.angular]
        f64 = torch.float64
        points = torch.as_tensor(points, dtype=torch.float32)
        B = points.shape[0]
        with torch.inference_mode():
            for m in models:
                m.eval()
            codes = [m.split_code(m.with_spin_inertia(m.encode(points), spin_inertia)) for m in models]
            v = torch.as_tensor(linear_velocity0, dtype=f64).reshape(B, 3)
            w = torch.as_tensor(angular_velocity0, dtype=f64).reshape(B, 3)
            turn = torch.zeros(B, 4, dtype=f64)
            turn[:, 3] = 1.0
            changes = torch.empty(B, steps, 12, dtype=f64)
            fed = torch.empty(B, steps, 6, dtype=f64)
            topple_out = torch.zeros(B, steps, dtype=f64)
            states = [None, None]
            for t in range(steps):
                fed[:, t, :3], fed[:, t, 3:] = v, w
                v32, w32, q = v.float()[:, None], w.float()[:, None], turn.float()[:, None]
                si = []
                for i, (m, (feature, geometry)) in enumerate(zip(models, codes)):
                    inputs = m.network_inputs(feature, v32, w32, q if m.uses_orientation else None)
                    features, states[i] = m.predictor(inputs, states[i])
                    net, logit = m.head(features)
                    if i == 0:
                        net = net * LINEAR.float()
                    elif logit is not None:
                        topple_out[:, t] = torch.sigmoid(logit[:, 0]).to(f64)
                    prior = m.analytic_prior(v32, w32, q, geometry)
                    out = net if prior is None else m.with_residual(net, prior, m.rest_gate(v32, w32))
                    si.append(out[:, 0].to(f64) * m.change_scale.to(f64) + m.change_shift.to(f64))
                step = si[0] * LINEAR + si[1] * (1 - LINEAR)
                changes[:, t] = step
                turn = quat_multiply(rotvec_to_quat(step[:, 9:12]), turn)
                turn = turn / torch.linalg.vector_norm(turn, dim=-1, keepdim=True)
                v, w = v + step[:, 0:3], w + step[:, 3:6]
        return {"changes": changes, "fed": fed, "topple_probability": topple_out if topple else None}


def headline(r):
    h = r["headline"]
    rel = r["rollout"]["non_toppling"]["relative"]
    top = r["topple"] or {}
    return (f"final position {100 * h['final_position_m_median']:.2f} cm, final rotation {h['final_rotation_deg_median']:.1f} deg, "
            f"per step {1000 * h['position']:.2f} mm, topple accuracy {top.get('accuracy', float('nan')):.3f}, "
            f"relative % " + " ".join(f"{k} {100 * x:.2f}" for k, x in rel.items()))


if __name__ == "__main__":
    what, lin, rot = sys.argv[1:4]
    composite = ChannelComposite(load_checkpoint(lin), load_checkpoint(rot))
    if what == "external":  # benchmarks/external_meshes.py, its predictor the composite
        import physdyn.predict.predictor as P

        load = P.load_predictor
        P.load_predictor = lambda checkpoint=None, **kw: load(composite, **kw)
        sys.argv = ["external_meshes.py", *sys.argv[4:]]
        runpy.run_path(str(Path(__file__).resolve().parents[1] / "external_meshes.py"), run_name="__main__")
    else:
        print("composite:", headline(evaluate(composite, load_store(sys.argv[4]), split=what)))
