"""Does the residual network learn what its prior misses? Trains the quickstart recipe teacher forced
(``rollout.feedback=0``) for a few hundred steps and prints, every 100 steps, the model's summed one-step
error on held-out validation windows divided by the prior's alone (zero residual), per channel
[dv_x, dv_y, dv_z, dw_x, dw_y, dw_z], on moving steps (horizontal speed > 0.1 m/s). Below 1: it learns.

    python benchmarks/studies/topple_gradient.py runs/t1/speakers.zarr                                # the paper's head
    python benchmarks/studies/topple_gradient.py runs/t1/speakers.zarr model.head.params.detach_topple=true
    python benchmarks/studies/topple_gradient.py runs/t1/speakers.zarr loss.weights.topple=0

About 2 minutes per 800 steps on one core.
"""
import itertools
import sys
import time

import lightning
import numpy as np
import torch

from physdyn.data.datamodule import DynamicsDataModule
from physdyn.models.dynamics_module import DynamicsModel
from physdyn.models.training import load_experiment_config

STEPS = 800
cfg = load_experiment_config("configs/experiment/quickstart.yaml",
                             [f"data.store={sys.argv[1]}", "rollout.feedback=0.0", *sys.argv[2:]])
lightning.seed_everything(0, verbose=False)
torch.set_num_threads(1)
dm = DynamicsDataModule(cfg.data)
dm.setup("fit")
model = DynamicsModel(cfg, dm.normalization, {"rate_hz": dm.rate_hz, "friction": 0.25, "gravity": 9.81})
optimiser = torch.optim.Adam(model.parameters(), lr=cfg.optim.lr)
held_out = list(itertools.islice(iter(dm.val_dataloader()), 30))


def error_ratio() -> np.ndarray:
    model.eval()
    own, prior_only = np.zeros(6), np.zeros(6)
    with torch.no_grad():
        for b in held_out:
            code = model.encode(b["points"], b.get("spin_inertia"))
            q = b["relative_orientation_xyzw"]
            changes, _, _ = model(code, b["linear_velocity"], b["angular_velocity"], None, q)
            prior = model.analytic_prior(b["linear_velocity"], b["angular_velocity"], q, model.split_code(code)[1])
            si = changes * model.change_scale + model.change_shift
            true = torch.cat([b["delta_linear_velocity"], b["delta_angular_velocity"]], -1)
            moving = ((b["linear_velocity"][..., :2].norm(dim=-1) > 0.1) & b["valid"].bool()).unsqueeze(-1).float()
            own += ((si[..., :6] - true).abs() * moving).sum((0, 1)).numpy()
            prior_only += ((prior[..., :6] - true).abs() * moving).sum((0, 1)).numpy()
    model.train()
    return own / prior_only


start, step = time.time(), 0
while step < STEPS:
    for batch in dm.train_dataloader():
        out = model.compute_loss(batch)
        optimiser.zero_grad()
        out.total.backward()
        optimiser.step()
        step += 1
        if step % 100 == 0:
            print(f"step {step} ({time.time() - start:.0f} s): model / prior one-step error {np.round(error_ratio(), 3)}", flush=True)
        if step >= STEPS:
            break
