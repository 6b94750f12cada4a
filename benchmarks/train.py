"""Training throughput: sequences per second and the share of step time spent waiting for data.

    python benchmarks/train.py [STORE] [--steps N] [--presets quickstart paper] [--threads T]

Uses the real presets (configs/experiment/*.yaml) with the given store, the real DataModule and the
model's own loss; one optimiser step per batch, as in training. The first steps are warm-up and not
timed. Aim: data wait < 10 % of step time.

Beside each preset, the shape encoder alone (forward and backward of the same batch, nothing else): its
multiply-adds per sequence, the arithmetic rate this CPU reaches on them, and the sequences/s it allows —
a ceiling on training throughput, since every step encodes every window's cloud.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]


def measure(preset: str, store: str, steps: int, warmup: int = 2, overrides: list[str] | None = None) -> dict:
    from physdyn.data.datamodule import DynamicsDataModule
    from physdyn.models.dynamics_module import DynamicsModel
    from physdyn.models.training import load_experiment_config

    cfg = load_experiment_config(ROOT / "configs" / "experiment" / f"{preset}.yaml", [f"data.store={store}", *(overrides or [])])
    dm = DynamicsDataModule(cfg.data)
    dm.setup("fit")
    model = DynamicsModel(cfg, dm.normalization)
    model.train()
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.optim.lr)
    data_s = compute_s = 0.0
    sequences = 0
    done = 0
    while done < warmup + steps:
        it = iter(dm.train_dataloader())
        while done < warmup + steps:
            t0 = time.perf_counter()
            try:
                batch = next(it)
            except StopIteration:
                break
            t1 = time.perf_counter()
            loss = model.compute_loss(batch).total
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            t2 = time.perf_counter()
            if done >= warmup:
                data_s += t1 - t0
                compute_s += t2 - t1
                sequences += len(batch["sim"])
            done += 1
    total = data_s + compute_s
    params = sum(p.numel() for p in model.parameters())
    encoder_s, macs = encoder_alone(model, batch["points"], steps)
    return {
        "encoder_sequences_per_s": len(batch["points"]) / encoder_s, "encoder_macs": macs,
        "encoder_gflops": 3 * 2 * macs * len(batch["points"]) / encoder_s / 1e9,
        "preset": preset, "params": params, "batch": cfg.data.batch_size, "points": cfg.data.num_points,
        "sequences_per_s": sequences / total, "data_share": data_s / total, "steps": steps,
    }


def encoder_alone(model, points: torch.Tensor, steps: int) -> tuple[float, float]:
    """Seconds per forward + backward of the encoder on one batch, and its multiply-adds per sequence
    (the per-point layers of a PointNet-like encoder: in x out channels x points; the layers after the
    pooling are a rounding error)."""
    encoder = model.encoder
    macs = 0.0
    for layer in encoder.modules():
        if isinstance(layer, torch.nn.Conv1d):
            macs += layer.in_channels * layer.out_channels * points.shape[1]
    scaled = points / model.point_scale
    times = []
    for _ in range(max(steps, 3)):
        t0 = time.perf_counter()
        encoder(scaled).sum().backward()
        times.append(time.perf_counter() - t0)
    return sorted(times)[len(times) // 2], macs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("store", nargs="?", default="data/quickstart.zarr")
    parser.add_argument("--presets", nargs="+", default=["quickstart", "paper"])
    parser.add_argument("--steps", type=int, default=None, help="timed steps per preset (default 30 quickstart, 4 others)")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"store {args.store}; torch {torch.__version__}, {torch.get_num_threads()} CPU threads, "
          f"CUDA {'yes' if torch.cuda.is_available() else 'no'} (this benchmark runs on the CPU)")
    for preset in args.presets:
        steps = args.steps or (30 if preset == "quickstart" else 4)
        r = measure(preset, args.store, steps)
        print(
            f"{r['preset']:<12} {r['params'] / 1e6:6.2f} M params, batch {r['batch']}, {r['points']} points: "
            f"{r['sequences_per_s']:7.1f} sequences/s, data wait {100 * r['data_share']:4.1f} % of step time "
            f"({r['steps']} steps)"
        )
        print(
            f"{'':<12} the encoder alone: {r['encoder_macs'] / 1e6:.1f} M multiply-adds per sequence forward, "
            f"forward + backward at {r['encoder_gflops']:.0f} GFLOP/s (x3 for the backward pass): at most "
            f"{r['encoder_sequences_per_s']:.0f} sequences/s"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
