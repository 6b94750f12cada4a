"""The network's residual on the linear channels only (Δv, Δp); spin and rotation (Δω, Δθ) from the contact
prior alone. A patch of DynamicsNetwork.with_residual for the length of the run (not a physdyn option), and
the one-object roll-out routed through the batched one, which applies it.

    python benchmarks/studies/linear_residual.py fit configs/experiment/quickstart.yaml model.head.params.detach_topple=true out_dir=runs/qs_linonly
    python benchmarks/studies/linear_residual.py val runs/qs_linonly/best.ckpt data/quickstart.zarr
    python benchmarks/studies/linear_residual.py external --work runs/external_val --random 60 --random-from 30 --no-named --checkpoint runs/qs_linonly/best.ckpt
    python benchmarks/studies/linear_residual.py run benchmarks/studies/table1_parts.py runs/t1/speakers.zarr runs/t1/lin15/best.ckpt
"""
import runpy
import sys
from pathlib import Path

import torch

from physdyn.models.dynamics_network import DynamicsNetwork
from physdyn.models.single_rollout import SingleRollout

KEEP = torch.tensor([1.0] * 3 + [0.0] * 3 + [1.0] * 3 + [0.0] * 3)  # [dv, dw, dp, dtheta]
original = DynamicsNetwork.with_residual
DynamicsNetwork.with_residual = lambda self, changes, prior, moving: original(self, changes * KEEP.to(changes), prior, moving)
SingleRollout.supports = staticmethod(lambda model: False)

what, args = sys.argv[1], sys.argv[2:]
if what == "fit":
    from physdyn.models.training import fit, load_experiment_config

    print(fit(load_experiment_config(args[0], args[1:])).metrics)
elif what == "val":
    from physdyn.data.store import load_store
    from physdyn.eval.baselines import load_checkpoint
    from physdyn.eval.evaluate import evaluate

    h = evaluate(load_checkpoint(args[0]), load_store(args[1]), split="val")["headline"]
    print(f"final position {100 * h['final_position_m_median']:.2f} cm, final rotation {h['final_rotation_deg_median']:.1f} deg, "
          f"per step {1000 * h['position']:.2f} mm")
elif what == "external":
    sys.argv = ["external_meshes.py", *args]
    runpy.run_path(str(Path(__file__).resolve().parents[1] / "external_meshes.py"), run_name="__main__")
elif what == "run":  # any other script, with the patch applied
    sys.argv = list(args)
    runpy.run_path(args[0], run_name="__main__")
else:
    sys.exit("usage: linear_residual.py fit|val|external|run ...")
