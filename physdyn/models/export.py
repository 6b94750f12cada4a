"""Slim a training checkpoint for shipping: weights, config and normalisation, no optimiser state.

    python -m physdyn.models.export runs/quickstart/best.ckpt physdyn/assets/bundled.ckpt
    python -m physdyn.models.export runs/bundled/best.ckpt physdyn/assets/bundled.ckpt --set model.contact_inertia=body
    python -m physdyn.models.export runs/bundled/topple.ckpt physdyn/assets/bundled.ckpt --linear-from runs/quickstart_linear/best.ckpt

``--set`` changes a setting that acts at inference only (chosen on validation after training, as the
bundled model's rest gate was) or the model's name in reports: ``INFERENCE_KEYS``; the weights stay as
trained. In a file of two networks (``--linear-from``, or such a file as SRC) a setting reaches both.

``--linear-from CKPT`` combines two trained models into one file: the velocity and position changes come
from CKPT's network (best trained with ``model.residual_channels=linear``), spin, rotation and toppling from
SRC's, both networks fed the same state at every step (``DynamicsNetwork.linear_channels``). CKPT's own topple
classifier and optimiser state are left out.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch
from omegaconf import OmegaConf

from physdyn.config import ExperimentConfig, config_from_dict, parse_override, to_dict
from physdyn.errors import ConfigError, PhysdynError
from physdyn.models.checkpoint_file import read_checkpoint, write_torch_file
from physdyn.models.dynamics_network import DynamicsNetwork
from physdyn.models.training import validate_experiment_config

# What DynamicsModel.load_from_checkpoint needs; the optimiser, loops and callbacks are only for resuming.
KEEP = ("state_dict", "hyper_parameters", "hparams_name", "pytorch-lightning_version", "epoch", "global_step",
        "topple_classifier", "outcome_correction", "linear_channels")
# Settings that change what a trained network is combined with, not the network itself, and the name
# reports give the model.
INFERENCE_KEYS = ("model.residual_gate_linear", "model.residual_gate_angular", "model.contact_inertia",
                  "model.contact_footprint", "model.contact_substeps", "model.sim_seconds", "name")


def apply_settings(hyper_parameters: dict, settings: list[str]) -> dict:
    """hyper_parameters with each ``key=value`` of ``settings`` (keys from ``INFERENCE_KEYS``) written into
    its config, checked as ``physdyn fit`` checks a config. Raises ``ConfigError``."""
    config = dict(hyper_parameters["config"])
    for item in settings:
        key, sep, _ = item.partition("=")
        if not sep or key not in INFERENCE_KEYS:
            raise ConfigError(f"--set {item!r}: use KEY=VALUE with KEY one of {', '.join(INFERENCE_KEYS)}")
        parsed = OmegaConf.to_container(parse_override(item))  # the value read as `physdyn fit` reads one
        if "." in key:
            section, name = key.split(".")
            config[section] = {**config[section], name: parsed[section][name]}
        else:
            config[key] = parsed[key]
    checked = validate_experiment_config(config_from_dict(ExperimentConfig, config))
    return {**hyper_parameters, "config": to_dict(checked)}


def with_linear_channels(slim: dict, linear: dict, name: str) -> dict:
    """A slim checkpoint whose velocity and position changes come from the checkpoint ``linear`` (its dict;
    ``name`` for errors): its weights under ``linear_channels.`` and its hyper-parameters beside. Checked by
    building the combined model. Raises ``ConfigError``."""
    if linear.get("linear_channels"):
        raise ConfigError(f"--linear-from {name} combines two networks itself; pass a checkpoint of `physdyn fit`")
    state = {k: v for k, v in slim["state_dict"].items() if not k.startswith("linear_channels.")}
    state.update({f"linear_channels.{k}": v for k, v in linear["state_dict"].items()})
    out = {**slim, "state_dict": state, "linear_channels": {"hyper_parameters": linear["hyper_parameters"]}}
    model = DynamicsNetwork(**slim["hyper_parameters"])
    model.attach_linear_channels(DynamicsNetwork(**linear["hyper_parameters"]))  # the rate and orientation checks
    for key in ("change_shift", "velocity_shift"):  # checkpoints from before per-channel normalisation
        state.setdefault(f"linear_channels.{key}", torch.zeros_like(getattr(model, key)))
    missing, unexpected = model.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise ConfigError(f"--linear-from {name}: its weights do not fit its own config ({len(missing)} missing, "
                          f"{len(unexpected)} unexpected); pass a checkpoint of `physdyn fit`")
    return out


def export_checkpoint(src: str | Path, dst: str | Path, overwrite: bool = False, settings: list[str] | None = None,
                      linear_from: str | Path | None = None) -> Path:
    src, dst = Path(src), Path(dst)
    checkpoint = read_checkpoint(src)
    if dst.exists() and not overwrite:
        raise PhysdynError(f"{dst} exists; pass --overwrite to replace it")
    slim = {key: checkpoint[key] for key in KEEP if key in checkpoint}
    if linear_from is not None:
        slim = with_linear_channels(slim, read_checkpoint(linear_from), str(linear_from))
    if settings:
        slim["hyper_parameters"] = apply_settings(slim["hyper_parameters"], settings)
        if slim.get("linear_channels"):  # both networks run with the setting (each computes its own prior)
            network = [item for item in settings if item.partition("=")[0] != "name"]
            linear = slim["linear_channels"]["hyper_parameters"]
            slim["linear_channels"] = {**slim["linear_channels"], "hyper_parameters": apply_settings(linear, network)}
    dst.parent.mkdir(parents=True, exist_ok=True)
    write_torch_file(slim, dst)  # never a half-written checkpoint under the final name
    return dst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("src")
    parser.add_argument("dst")
    parser.add_argument("--overwrite", action="store_true")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help=f"an inference setting to write into the config: {', '.join(INFERENCE_KEYS)}")
    parser.add_argument("--linear-from", default=None, metavar="CKPT",
                        help="take the velocity and position changes from this checkpoint's network")
    args = parser.parse_args()
    try:
        out = export_checkpoint(args.src, args.dst, args.overwrite, args.set, args.linear_from)
    except PhysdynError as exc:  # one line, like the physdyn command
        print(f"export: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()
