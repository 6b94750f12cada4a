"""Study: a model's roll-outs with ``model.sim_seconds`` set to each value given, on a store's split
(docs/research/simulated-start.md): median final position and rotation of the
non-toppling pushes and the supplement's relative errors (Table 1's v, w, P, |theta|).

    python benchmarks/studies/sim_seconds_sweep.py CKPT STORE SPLIT SECONDS ... [--step HZ]

``--step 240`` runs the simulated start at 1/240 s instead of the conventions' 1/960 s (a patch of the
process's shared simulator for the length of the run). The topple classifier is left out (trajectories only).
"""

import argparse

from physdyn.eval.baselines import load_checkpoint
from physdyn.eval.evaluate import evaluate
from physdyn.sim import cloud_body


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("store")
    ap.add_argument("split")
    ap.add_argument("seconds", type=float, nargs="+")
    ap.add_argument("--step", type=float, default=0.0, help="physics rate of the simulated start in Hz (default: 960)")
    args = ap.parse_args()
    for seconds in args.seconds:
        model = load_checkpoint(args.checkpoint)
        model.topple_classifier = None
        model.config.model.sim_seconds = seconds
        if args.step:  # every time step the roll-out asks for gets a simulator at this one
            cloud_body._SHARED = _Always(cloud_body.CloudSimulator(time_step=1.0 / args.step))
        r = evaluate(model, args.store, split=args.split)
        h, rel = r["headline"], r["rollout"]["non_toppling"]["relative"]
        print(f"sim_seconds {seconds:g}: final {100 * h['final_position_m_median']:.2f} cm "
              f"{h['final_rotation_deg_median']:.1f} deg; relative v {100 * rel['linear_velocity']:.1f} % "
              f"w {100 * rel['angular_velocity']:.1f} % P {100 * rel['position']:.2f} % theta {100 * rel['angle']:.1f} %",
              flush=True)


class _Always(dict):
    """A stand-in for the shared simulators' dict that answers every time step with one simulator."""

    def __init__(self, simulator):
        super().__init__()
        self.simulator = simulator

    def __contains__(self, key):
        return True

    def __getitem__(self, key):
        return self.simulator


if __name__ == "__main__":
    main()
