"""`physdyn recipe`: train every stage of a predictor preset, in order, with one command."""

from __future__ import annotations

import argparse

ORDER = 33

EPILOG = """\
examples:
  physdyn recipe fast --data data/quickstart_hull_small.zarr --out runs/my_fast
  physdyn recipe fast --data data/mine.zarr --out runs/my_fast --set topple.steps=300 --set correction.steps=300
  physdyn recipe configs/predictor/fast.yaml --data data/a.zarr --data data/b.zarr --out runs/fast_ab
Each step writes its checkpoint under --out and is kept once written: rerun the same command to finish an
interrupted recipe (--overwrite starts again). The last step's checkpoint is the model:
  physdyn predict MESH --checkpoint runs/my_fast/model.ckpt
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("recipe", help="train every stage of a predictor preset (fast, bundled) in one command",
                       description="Run a predictor preset's recipe: its motion stage trained by `physdyn fit`, then "
                       "each learned stage (`fit-topple`, `fit-outcome`), then the model exported, on your stores.",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", action="append", required=True, metavar="STORE",
                   help="store to train on, repeatable: `fit` steps train on the first, the others fit on all")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for every step's checkpoint")
    p.add_argument("--overwrite", action="store_true", help="run every step again, replacing what is in --out")
    p.add_argument("preset", metavar="PRESET", help="a predictor preset with a recipe: fast, bundled "
                   "(`physdyn configs predictor`) or a preset .yaml")
    p.add_argument("--set", action="append", default=[], metavar="STEP.KEY=VALUE", dest="overrides",
                   help="change one step's option or setting, repeatable: --set topple.steps=300 "
                   "--set motion.trainer.max_steps=100")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    import shutil
    from pathlib import Path

    from physdyn.cli import main
    from physdyn.errors import ConfigError
    from physdyn.models.export import export_checkpoint
    from physdyn.pipeline.presets import preset_recipe
    from physdyn.pipeline.recipe import command_line, export_arguments, outputs, with_overrides

    steps = with_overrides(preset_recipe(args.preset), args.overrides)
    for store in args.data:
        if not Path(store).exists():
            raise ConfigError(f"no dataset store at {store}; create one with `physdyn simulate --out {store}`")
    out = Path(args.out)
    made = outputs(steps, out)
    for i, step in enumerate(steps):
        if made[step.name].is_file() and not args.overwrite:
            print(f"physdyn recipe: {step.name} ({step.command}) done: {made[step.name]}; kept")
            continue
        print(f"physdyn recipe: {step.name} ({step.command}), step {i + 1} of {len(steps)}", flush=True)
        if step.command == "export":
            export_checkpoint(**export_arguments(steps, i, out))
            continue
        if step.command == "fit" and (out / step.name).exists():
            shutil.rmtree(out / step.name)  # an unfinished or replaced run of this recipe's own step
        code = main(command_line(steps, i, args.data, out))
        if code:
            return code
    print(f"physdyn recipe: the model is {made[steps[-1].name]}")
    return 0
