"""An animation of a predicted trajectory: the mesh moving over the ground, beside the simulation if any.

Matplotlib 3D (Agg) draws each frame; Pillow writes a GIF, or matplotlib's ffmpeg writer an MP4 when
ffmpeg is installed. The mesh is decimated to at most ``MAX_FACES`` faces so a 4 s clip renders in
seconds. Poses follow the conventions: a mesh vertex x is drawn at R (x - com_mesh) + com_position.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from physdyn.errors import PhysdynError
from physdyn.files import atomic_output
from physdyn.geometry.rotations import quat_to_matrix
from physdyn.predict.prediction_files import check_output_path
from physdyn.viz.meshes import decimate, mesh_to_draw
from physdyn.viz.viewer import scene_from_prediction, write_viewer

MAX_FACES = 500
ANIMATION_EXTENSIONS = (".gif", ".mp4")
RENDER_EXTENSIONS = (*ANIMATION_EXTENSIONS, ".html")  # .html: the interactive viewer page
_PANEL_COLOURS = {"prediction": (0.27, 0.51, 0.71), "simulation": (0.85, 0.45, 0.2)}
_LIGHT = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])


class RenderError(PhysdynError):
    """An animation that cannot be written (format, missing encoder)."""


def ffmpeg_available() -> bool:
    from matplotlib.animation import FFMpegWriter  # heavy (matplotlib): loaded when asked

    return bool(FFMpegWriter.isAvailable())


def check_animation_path(path: str | Path, overwrite: bool = False) -> Path:
    """Refuse an unsupported extension, an MP4 without ffmpeg, or an existing file, before any work.
    An .html path is a viewer page (``physdyn.viz.viewer``)."""

    path = check_output_path(path, overwrite, RENDER_EXTENSIONS, what="animation")
    if path.suffix.lower() == ".mp4" and not ffmpeg_available():
        raise RenderError(f"animation {path}: MP4 needs ffmpeg, which is not installed; write a .gif instead or install ffmpeg")
    return path


def _posed(vertices: np.ndarray, com_mesh: np.ndarray, q_xyzw: np.ndarray, com_position: np.ndarray) -> np.ndarray:
    return (vertices - com_mesh) @ quat_to_matrix(q_xyzw).T + com_position


def _shade(tris: np.ndarray, colour: tuple[float, float, float]) -> np.ndarray:
    """Per-face RGBA (F, 4): a fixed light, two-sided Lambert plus ambient."""
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    k = 0.45 + 0.55 * np.abs(n @ _LIGHT)
    rgb = np.clip(np.asarray(colour)[None] * k[:, None], 0, 1)
    return np.concatenate([rgb, np.ones((len(rgb), 1))], axis=1)


def render_animation(mesh: Any, result: dict[str, Any], path: str | Path, fps: float = 15, scale: float = 1.0,
                     overwrite: bool = False) -> Path:
    """Animate ``result`` (a ``Predictor.predict`` dict) with ``mesh`` (a path, a ``trimesh.Trimesh`` or a
    ``PreparedBody``, at ``scale`` as predicted) into ``path`` (.gif, or .mp4 with ffmpeg; .html writes the
    interactive viewer page instead).

    One frame per 1/fps s of the trajectory (the nearest recorded step): with fps = rate_hz, one frame per
    step. With ``result["simulated"]`` the prediction and the simulation are drawn side by side. Each
    panel shows the ground, the trail of the centre of mass and the time.
    """
    import matplotlib  # heavy (~0.4 s): loaded when an animation is drawn

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    path = check_animation_path(path, overwrite)
    if path.suffix.lower() == ".html":
        m = mesh_to_draw(mesh, scale)
        return write_viewer([scene_from_prediction(result, m)], path, title=f"physdyn: {path.stem}", overwrite=overwrite)
    if not np.isfinite(fps) or fps <= 0:
        raise RenderError(f"fps must be a positive number, got {fps}")
    m = mesh_to_draw(mesh, scale)
    vertices, faces = decimate(np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64), MAX_FACES)
    panels = [("prediction", result)]
    if result.get("simulated"):
        panels.append(("simulation", result["simulated"]))
    rate = float(result["rate_hz"])
    T = len(result["time"])
    n_frames = int(round((T - 1) / rate * fps)) + 1
    steps = np.minimum(np.round(np.arange(n_frames) * rate / fps).astype(int), T - 1)

    # One box that holds every pose of every panel, so the camera does not move.
    com_mesh = np.asarray(result["com_mesh"], np.float64)
    radius = float(np.linalg.norm(vertices - com_mesh, axis=1).max())
    coms = np.concatenate([np.asarray(res["com_position"]) for _, res in panels])
    lo = np.minimum(coms.min(axis=0) - radius, [np.inf, np.inf, 0.0])
    hi = coms.max(axis=0) + radius
    centre, half = (lo + hi) / 2, float((hi - lo).max()) / 2
    lo, hi = centre - half, centre + half
    lo[2], hi[2] = 0.0, 2 * half

    fig = plt.figure(figsize=(4.0 * len(panels), 4.0), dpi=80)
    artists = []
    for i, (label, res) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), i + 1, projection="3d")
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=25, azim=-60)
        ax.set_xlabel("x (m)", fontsize=7)
        ax.set_ylabel("y (m)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.set_zticks([])
        ax.grid(False)
        topple = " (topples)" if res.get("toppled") else ""
        ax.set_title(f"{label}{topple}", fontsize=9)
        ground = [[(lo[0], lo[1], 0), (hi[0], lo[1], 0), (hi[0], hi[1], 0), (lo[0], hi[1], 0)]]
        ax.add_collection3d(Poly3DCollection(ground, facecolors=(0.85, 0.85, 0.85, 0.6), edgecolors="none"))
        body = Poly3DCollection(np.zeros((len(faces), 3, 3)), edgecolors="none")
        ax.add_collection3d(body)
        (trail,) = ax.plot([], [], [], color="k", lw=1.2)
        clock = ax.text2D(0.02, 0.95, "", transform=ax.transAxes, fontsize=8)
        artists.append((res, _PANEL_COLOURS[label], body, trail, clock))
    fig.tight_layout()

    images = []
    for k, step in enumerate(steps):
        for res, colour, body, trail, clock in artists:
            tris = _posed(vertices, com_mesh, res["orientation_xyzw"][step], res["com_position"][step])[faces]
            body.set_verts(tris)
            body.set_facecolor(_shade(tris, colour))
            p = np.asarray(res["com_position"][: step + 1])
            trail.set_data_3d(p[:, 0], p[:, 1], p[:, 2])
            clock.set_text(f"t = {k / fps:.2f} s")  # also keeps identical frames distinct in a GIF
        fig.canvas.draw()
        rgba = np.asarray(fig.canvas.buffer_rgba())
        images.append(Image.fromarray(rgba[..., :3].copy()))
    plt.close(fig)
    _write(images, path, fps)
    return path


def _write(images: list, path: Path, fps: float) -> None:
    with atomic_output(path, suffix=path.suffix) as tmp:
        if path.suffix.lower() == ".gif":
            palette = images[0].quantize(colors=128, method=Image.Quantize.MEDIANCUT)
            frames = [im.quantize(palette=palette, dither=Image.Dither.NONE) for im in images]
            frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:],
                           duration=int(round(1000 / fps)), loop=0, disposal=1)
        else:
            _write_mp4(images, str(tmp), fps)


def _write_mp4(images: list, path: str, fps: float) -> None:
    import matplotlib.pyplot as plt  # heavy: loaded when an animation is written
    from matplotlib.animation import FFMpegWriter

    h, w = np.asarray(images[0]).shape[:2]
    fig = plt.figure(figsize=(w / 100, h / 100), dpi=100)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.axis("off")
    shown = ax.imshow(np.asarray(images[0]))
    writer = FFMpegWriter(fps=fps)
    with writer.saving(fig, path, dpi=100):
        for im in images:
            shown.set_data(np.asarray(im))
            writer.grab_frame()
    plt.close(fig)
