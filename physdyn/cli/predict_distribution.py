"""What `physdyn predict ... --samples N` checks and writes for a distribution of outcomes (docs/distributions.md):
one mesh from the flags (``physdyn.cli.predict.run_distribution``), or the lines of --batch that carry "samples"."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from physdyn.errors import PhysdynError

PLOT_EXTENSIONS = (".png",)


def check_outputs(out: Any, render: Any, plot: Any, overwrite: bool) -> None:
    """Refuse a distribution's output paths before any work: --out .npz or .json, --render .html (the viewer
    draws the fan of samples; an animation shows one trajectory), --plot .png."""
    from physdyn.predict.prediction_files import DISTRIBUTION_EXTENSIONS, check_output_path

    if out:
        check_output_path(out, overwrite, DISTRIBUTION_EXTENSIONS, "distribution output")
    if render:
        from physdyn.viz.viewer import check_viewer_path

        if Path(str(render)).suffix.lower() != ".html":
            raise PhysdynError(f"render {render}: a distribution is drawn on the interactive page; use a .html name")
        check_viewer_path(render, overwrite)
    if plot:
        check_output_path(plot, overwrite, PLOT_EXTENSIONS, "plot")


def write_outputs(result: dict, body: Any, paths: tuple, overwrite: bool) -> list[Path]:
    """Write a distribution's files: paths = (out, render, plot), each None or a path checked by ``check_outputs``."""
    from physdyn.predict.prediction_files import write_prediction

    out, render, plot = paths
    written = []
    if out:
        written.append(write_prediction(result, out, overwrite=overwrite))
    if render:
        from physdyn.viz.viewer import scene_from_prediction, write_viewer

        written.append(write_viewer([scene_from_prediction(result, body)], render, title=f"physdyn: {Path(render).stem}",
                                    overwrite=overwrite))
    if plot:
        from physdyn.viz.distribution_plot import plot_distribution

        written.append(plot_distribution(result, plot, overwrite=overwrite))
    return written


def read_distribution_request(req: dict, request: dict, plot: Path | None, overwrite: bool) -> dict:
    """A --batch line's distribution keys (samples, uncertainty, seed; ``plot`` its path) checked into ``request``."""
    from physdyn.config.uncertainty import resolve_uncertainty
    from physdyn.pipeline.distribution import check_samples

    seed = req.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise PhysdynError(f"\"seed\" must be a whole number, got {seed!r}")
    if request["compare_sim"]:
        raise PhysdynError("\"compare_sim\" simulates one push; drop it from a line with \"samples\"")
    check_outputs(request["out"], request["render"], plot, overwrite)
    request.update(samples=check_samples(req["samples"]), seed=seed, plot=plot,
                   uncertainty=resolve_uncertainty(req.get("uncertainty", "default"), "uncertainty"))
    return request


def predict_request(predictor: Any, r: dict) -> dict:
    """One --batch line with "samples": its distribution."""
    return predictor.predict_distribution(r["body"], r["lin_vel"], r["ang_vel"], r["seconds"], r["uncertainty"],
                                          r["samples"], r["seed"], r["orientation"])
