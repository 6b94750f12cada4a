"""`physdyn fit-spread`: fit a predictor's calibrated distribution stage to ensemble stores."""

from __future__ import annotations

import argparse

ORDER = 34

EPILOG = """\
example:
  physdyn simulate --config configs/data/ensemble_calibrate.yaml --out data/ensemble_calibrate.zarr --workers 2
  physdyn fit-spread fast --data data/ensemble_calibrate.zarr --out runs/fast_spread.yaml
  physdyn predict MESH --lin-vel 1 0 0 --ang-vel 0 0 2 --samples 32 --checkpoint runs/fast_spread.yaml
The preset written is PRESET with its distribution stage replaced (`calibrated`, the coefficients fitted);
docs/distributions.md says what they mean.
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fit-spread", help="fit a predictor's distribution forecast to ensemble stores (seconds)",
                       description="Roll PRESET out on every push of the --data ensemble stores and fit its calibrated "
                       "distribution stage: the spread of where a push ends and how far it turns, one part for the "
                       "push's uncertainty (the members' spread) and one for the model's own error (the members' "
                       "distance from the roll-out), by maximum likelihood. Writes a predictor preset.",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("preset", metavar="PRESET", help="a predictor preset: fast (`physdyn configs predictor`) or a preset .yaml")
    p.add_argument("--data", action="append", required=True, metavar="STORE",
                   help="an ensemble store (simulated with an ensemble: block), repeatable; every push of it is used")
    p.add_argument("--out", required=True, metavar="FILE.yaml", help="the predictor preset to write")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    import dataclasses
    from pathlib import Path

    import numpy as np
    import yaml

    from physdyn.data.store import load_store
    from physdyn.errors import PhysdynError
    from physdyn.eval.distribution_eval import has_ensemble
    from physdyn.pipeline.presets import build_pipeline, preset_file, read_preset
    from physdyn.pipeline.spread import CalibratedSpread
    from physdyn.pipeline.spread_fit import fit_spread, outcome_residuals, spread_coverage

    out = Path(args.out)
    if out.suffix not in (".yaml", ".yml"):
        raise PhysdynError(f"--out {out}: a predictor preset is a .yaml file; e.g. --out runs/fast_spread.yaml")
    if out.exists() and not args.overwrite:
        raise PhysdynError(f"{out} exists; pass --overwrite to replace it, or choose another --out")
    path = Path(args.preset) if Path(args.preset).suffix in (".yaml", ".yml") else preset_file(args.preset)
    if not path.is_file():
        raise PhysdynError(f"no predictor preset '{args.preset}'; pass a shipped one (`physdyn configs predictor`) or a .yaml")
    preset = read_preset(path)
    pipeline = build_pipeline(preset)
    data = []
    for url in args.data:
        if not Path(url).exists():
            raise PhysdynError(f"no dataset store at {url}; simulate one with an ensemble: block, e.g. "
                               "`physdyn simulate --config configs/data/ensemble_calibrate.yaml --out " + url + "`")
        store = load_store(url)
        if not has_ensemble(store):
            raise PhysdynError(f"{url} holds no ensemble members; simulate it with an ensemble: block "
                               "(configs/data/ensemble_calibrate.yaml)")
        print(f"physdyn fit-spread: rolling {preset.name} out on {store.num_sims} pushes of {url}", flush=True)
        data.append(outcome_residuals(pipeline, store, np.arange(store.num_sims)))
    pushes = sum(len(d["features"]) for d in data)
    config = fit_spread(data, f"{pushes} pushes of {', '.join(Path(u).name for u in args.data)}")
    stage = CalibratedSpread(config)
    held = np.mean([spread_coverage(stage, d) for d in data], axis=0)
    preset_dict = {"name": f"{preset.name}_spread" if out.stem == preset.name else out.stem,
                   "weights": preset.weights,
                   **{kind: {"name": getattr(preset, kind).name, "params": getattr(preset, kind).params}
                      for kind in ("motion", "topple", "correction")},
                   "distribution": {"name": "calibrated", "params": dataclasses.asdict(config)}}
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(out.name + ".partial")
    partial.write_text(f"# physdyn fit-spread {args.preset} --data {' --data '.join(args.data)}\n"
                       + yaml.safe_dump(preset_dict, sort_keys=False, default_flow_style=None))
    partial.replace(out)
    print(f"wrote {out}: the central 90 % of each component holds {held[0]:.2f} (along), {held[1]:.2f} (across) "
          f"and {held[2]:.2f} (turn, upright members) of the fitted stores' members")
    return 0
