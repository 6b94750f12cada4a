"""The ``meshes`` family: every mesh file in a folder (ShapeNet exports, scans, CAD parts...).

Files are listed once, sorted, so instance ``index`` is the same file on every worker and every run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from physdyn.config import MeshFolderConfig
from physdyn.errors import ShapeError
from physdyn.geometry.families.base import ShapeFamily, ShapeInstance
from physdyn.geometry.mesh_io import MESH_EXTENSIONS, load_mesh
from physdyn.registry import SHAPE_FAMILIES


def list_mesh_files(folder: Path, recursive: bool = True) -> list[Path]:
    """Mesh files (by extension, any case) under ``folder``, sorted by their path relative to it."""
    pattern = folder.rglob("*") if recursive else folder.glob("*")
    files = [p for p in pattern if p.is_file() and p.suffix.lower() in MESH_EXTENSIONS]
    # Sort on the relative POSIX path: independent of the filesystem's listing order and of the OS.
    return sorted(files, key=lambda p: p.relative_to(folder).as_posix())


@SHAPE_FAMILIES.register("meshes")
class MeshFolder(ShapeFamily):
    """Every mesh file in a folder (meshes.dir), one instance per file; ``make`` ignores ``rng``."""

    Config = MeshFolderConfig

    def __init__(self, config: MeshFolderConfig | None = None):
        config = config if config is not None else MeshFolderConfig()
        super().__init__(config)
        self.category = config.category
        if not config.dir:
            raise ShapeError("meshes.dir is not set; pass meshes.dir=PATH (a folder of mesh files)")
        folder = Path(config.dir).expanduser()
        if not folder.is_dir():
            raise ShapeError(
                f"meshes.dir {folder} is not a folder; pass meshes.dir=PATH to an existing folder"
            )
        self.files = list_mesh_files(folder, config.recursive)
        if not self.files:
            where = "in or under" if config.recursive else "directly in"
            raise ShapeError(
                f"meshes.dir {folder} has no mesh files {where} it; add {', '.join(MESH_EXTENSIONS)} files"
                + ("" if config.recursive else " or set meshes.recursive=true")
            )

    def num_shapes(self, requested: int) -> int:
        return len(self.files)

    def make(self, index: int, rng: np.random.Generator) -> ShapeInstance:
        if not 0 <= index < len(self.files):
            raise ShapeError(
                f"meshes: index {index} is out of range; {self.config.dir} has {len(self.files)} mesh files"
            )
        path = self.files[index]
        mesh = load_mesh(path, scale=self.config.scale)
        return ShapeInstance(mesh=mesh, category=self.category, source=str(path))
