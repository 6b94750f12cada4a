"""The accuracy-cost frontier: physdyn's predictors against PyBullet at five physics steps and a step schedule,
on meshes new to the model, every figure measured in one run on this machine.

    python benchmarks/frontier.py                                # both sets, fast (the default), bundled and the contact prior
    python benchmarks/frontier.py --quick                        # a smoke check: a few meshes, about a minute
    python benchmarks/frontier.py --predictor mine=runs/X/best.ckpt --predictor bundled=bundled
    python benchmarks/frontier.py --sets wheel --meshes 30 --pushes 10 --out reports/frontier/wheel.md

Mesh sets, none of them in any training data:
- ``pybullet``: pybullet_data's named objects (benchmarks/external_meshes.py), then its random_urdfs, up to
  ``--meshes``;
- ``wheel``: the object meshes inside the wheel of ``metaworld==3.1.1`` (household objects and CAD parts of its
  tasks: a mug, a cup, a thermos, a hammer, a faucet, a laptop, drawers, pegs...), downloaded with
  ``pip download --no-deps`` into ``--work`` on first use and unzipped there (never installed), duplicates
  left out, ``--meshes`` of them spread evenly over the sorted list. No physdyn model or setting was chosen
  on them: keep them for measuring, never for choosing.
Each mesh is scaled as external_meshes.py scales (largest extent into the training shapes' range). A mesh
physdyn rejects is skipped and listed.

Truth: `physdyn simulate`'s ``meshes`` family per the conventions (1/960 s, 15 Hz, a push over one physics
step), ``--pushes`` per mesh; the stores are made under ``--work`` on first use and reused after.

Two regimes:
(a) new meshes: every request treats its mesh as new, and the horizon is each truth's own length. physdyn:
    ``Predictor.predict(fresh trimesh copy, v0, w0, seconds, q0)`` per request (one at a time), and
    ``predict_many`` over all requests of the set in rounds of one push of every mesh (batched: ``--meshes``
    new meshes a call); every request gets its own copy, so its mesh is prepared (the files are parsed
    before the timing), and physdyn's content-keyed PyBullet caches are emptied between requests and calls,
    outside the timing (``Predictor.forget_meshes``). PyBullet: one world per physics step, reused for the whole
    run; per mesh the body (``prepare_body``: cleaning, hull, mass properties; then its collision shape) is
    built inside the timing, once, and pushed from each step-0 state (velocities set directly, as
    ``simulate_from_state`` does); its cost per request is that build plus one roll-out. The steps take
    turns mesh by mesh (with them a step schedule, ``SCHEDULES``: 1/240 s for the first 8 frames, while the
    push's contact settles, then 1/60 s, one body and world like the steps'), and after each mesh's turn
    physdyn's predictors predict that mesh's requests one at a time, request by request, so the shared
    machine's load and its drift over the run fall on all alike (timed one after the other instead, two runs
    of the same code put `fast` at 0.88x and 1.15x of 1/120 s); costs are CPU time. ``--repeats N`` times every timed
    piece N times in a row (a fresh mesh and emptied caches each time) and keeps its fastest: it removes a
    request's stalls. The batched rows are timed after (the ceilings are not timed): compare ratios within a run
    (docs/research/fast-cost.md).
(b) many pushes of one mesh: ``--one-meshes`` meshes of each set, ``--one-mesh-pushes`` simulated pushes
    each, a ``--one-mesh-seconds`` horizon. physdyn: one ``predict_many`` per mesh on one mesh object
    (prepared once, inside the timing); PyBullet: the body built once per mesh; both spread over the pushes.
Information ceilings (regime a, no cost): PyBullet at 1/960 s on the convex hull of
``prepare_body(mesh).points_body(N, method)`` with the body's own inertia (benchmarks/studies/points_ceiling.py),
for surface 256, hull_surface 256 / 512 / 1024 and each predictor's own input.

Figures per row: final position error (median over non-toppling pushes, cm; displacements from step 0) and
its ratio to Coulomb sliding's; final rotation error (median, non-toppling and all pushes); topple accuracy
(the header gives the majority answer's); ms per trajectory, and its ratio to PyBullet's at 1/240 s and
1/120 s. Costs are one core's: one torch thread, one BLAS thread.

The mesh sets, their truth stores and the requests are in frontier_sets.py, the tables and the plot in
frontier_report.py; this script measures and runs.
"""

from __future__ import annotations

import os

for _threads in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_threads] = "1"  # before numpy and torch load: every cost here is one core's

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import shlex  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from dataclasses import dataclass, field, replace  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
import trimesh  # noqa: E402

if __package__:  # imported as benchmarks.frontier by a study (python -m benchmarks.studies.NAME)
    from .frontier_report import TABLE_NOTES, add_cost_ratios, median, plot, regime_header, table
    from .frontier_sets import MeshSet, Requests, collect_set, one_mesh_set, requests_from_store, truth_store
else:  # python benchmarks/frontier.py: Python puts this folder on the path
    from frontier_report import TABLE_NOTES, add_cost_ratios, median, plot, regime_header, table
    from frontier_sets import MeshSet, Requests, collect_set, one_mesh_set, requests_from_store, truth_store
from physdyn.config import PhysicsConfig, config_from_dict  # noqa: E402
from physdyn.eval.metrics import rotation_angle_deg  # noqa: E402
from physdyn.geometry.mesh_io import load_mesh  # noqa: E402
from physdyn.models.export import export_checkpoint  # noqa: E402
from physdyn.predict.body import prepare_body  # noqa: E402
from physdyn.predict.predictor import BUNDLED_CHECKPOINT, Predictor, contact_prior_predictor, load_predictor  # noqa: E402
from physdyn.sim import cloud_body  # noqa: E402
from physdyn.sim.bullet import pb  # noqa: E402
from physdyn.sim.trajectory import place_at_rest, record, topple_labels  # noqa: E402
from physdyn.sim.world import PhysicsWorld  # noqa: E402

SETS = ("pybullet", "wheel")
STEPS_HZ = (960, 480, 240, 120, 60)  # PyBullet's physics steps, 1/hz s
# PyBullet with a fine step while the push's contact settles and a coarse one after, as a user who knows
# where the fine step pays would run it: (fine hz, recorded frames at the fine step, coarse hz). Chosen on
# the pybullet set (docs/research/impact-phase.md); a row of its own beside the steps.
SCHEDULES = ((240, 8, 60),)
CEILINGS = (("surface", 256), ("hull_surface", 256), ("hull_surface", 512), ("hull_surface", 1024))
DEFAULT_PREDICTORS = ("fast=fast", "bundled=bundled", "contact_prior=contact_prior")  # the shipped ones and the planner's screen
# Costs are this process's CPU time (one torch thread; PyBullet runs in-process): the machine is shared, and
# wall time would charge other jobs' load to whichever row ran beside them.
CLOCK = time.process_time
QUICK = {"meshes": 3, "pushes": 2, "one_meshes": 1, "one_mesh_pushes": 16, "one_mesh_seconds": 1.0}


# --------------------------------------------------------------------------------------------------
# Predictors: each gives an Outcome for a set of requests
# --------------------------------------------------------------------------------------------------
@dataclass
class Outcome:
    """disp (R, 3) predicted displacement from step 0 to the horizon, q (R, 4) orientation there, toppled
    (R,) bool; ms: costs per trajectory ("one": one at a time, "batched"; PyBullet also "build": ms per
    mesh of building its body, inside "one", and "rollout")."""

    disp: np.ndarray
    q: np.ndarray
    toppled: np.ndarray
    ms: dict[str, float] = field(default_factory=dict)

    @classmethod
    def empty(cls, count: int) -> "Outcome":
        return cls(np.zeros((count, 3)), np.zeros((count, 4)), np.zeros(count, bool))

    def set(self, r: int, positions: np.ndarray, orientations: np.ndarray, toppled: bool) -> None:
        self.disp[r] = positions[-1] - positions[0]
        self.q[r] = orientations[-1]
        self.toppled[r] = toppled


def open_worlds(physics: PhysicsConfig) -> dict[Any, PhysicsWorld]:
    """One PyBullet world per physics step of ``STEPS_HZ`` (keyed by hz) and per step schedule of
    ``SCHEDULES`` (keyed by the schedule, starting at its fine step), each reused for every roll-out of the run."""
    worlds: dict[Any, PhysicsWorld] = {hz: PhysicsWorld(replace(physics, time_step=1.0 / hz)) for hz in STEPS_HZ}
    worlds.update({plan: PhysicsWorld(replace(physics, time_step=1.0 / plan[0])) for plan in SCHEDULES})
    return worlds


def pushed_body(world: PhysicsWorld, spec: Any, req: Requests, r: int, shape: int | None = None) -> int:
    """A body of ``spec`` in ``world`` (collision shape ``shape``, or a new one) as request ``r`` starts: at rest
    in its step-0 orientation, given its step-0 velocities and its friction. The caller removes it."""
    body = world.add_body(spec, shape)
    place_at_rest(world, body, spec, req.q0[r])
    pb.resetBaseVelocity(body, req.v0[r].tolist(), req.w0[r].tolist(), physicsClientId=world.client)
    world.set_object_friction(body, req.friction[r] / world.physics.lateral_friction_ground)
    return body


def roll_out(world: PhysicsWorld, spec: Any, shape: int, req: Requests, r: int, rate_hz: float, out: Outcome,
             schedule: tuple[int, int, int] | None = None) -> None:
    """Request ``r`` on the body ``spec`` (collision shape ``shape`` of ``world``): at rest in its step-0
    orientation, given its step-0 velocities, recorded until it rests or reaches its horizon. With a
    ``schedule`` (fine hz, frames, coarse hz; ``world`` steps at the fine one) the first frames are
    recorded at the fine step and the rest at the coarse one."""
    body = pushed_body(world, spec, req, r, shape)
    frames = int(req.steps[r]) + 1
    try:
        fine = frames if schedule is None else min(frames, schedule[1] + 1)
        parts = [record(world, body, spec, rate_hz, max_frames=fine)]
        if len(parts[0]) == fine < frames:  # neither at rest nor at the horizon: on at the coarse step
            world.set_time_step(1.0 / schedule[2])
            try:
                parts.append(record(world, body, spec, rate_hz, max_frames=frames - fine + 1))
            finally:
                world.set_time_step(1.0 / schedule[0])
    finally:
        world.remove_body(body)
    # the coarse part starts from the fine part's last frame: it is recorded once
    positions = np.concatenate([parts[0].com_position] + [p.com_position[1:] for p in parts[1:]])
    orientations = np.concatenate([parts[0].orientation_xyzw] + [p.orientation_xyzw[1:] for p in parts[1:]])
    # toppled by the 45 degree rule from step 0's pose, over the whole run (each part alone would judge its
    # tilt from its own first frame)
    out.set(r, positions, orientations, topple_labels(orientations)[1] >= 0)


def pybullet_rows(worlds: dict[Any, PhysicsWorld], meshes: dict[str, trimesh.Trimesh], req: Requests, rate_hz: float,
                  new_mesh_each: bool, repeats: int = 1,
                  after_mesh: Callable[[np.ndarray], Any] = lambda idx: None) -> dict[Any, Outcome]:
    """PyBullet on each mesh's convex hull with its exact mass properties, at each world's step. The body
    (``prepare_body`` on a fresh copy, then its collision shape) is built inside the timing, once per mesh
    and step. Cost per trajectory: with ``new_mesh_each`` (regime a) a build and a roll-out, every request
    being a new mesh; else (regime b) the builds spread over all the pushes. The steps take turns mesh by
    mesh, so a change in the shared machine's load falls on all of them alike; a build, the same work at
    every step, costs the median of its five timings (a stall of the machine is not the body's; a schedule's
    build is priced at that median too). With
    ``repeats`` each build and each roll-out is timed that many times, its fastest kept. ``after_mesh(idx)``
    runs after each mesh's turn with its requests' indices: regime (a) times physdyn there, so that the
    machine's drift over a run falls on PyBullet and physdyn alike (one phase after the other, the ratio to
    1/120 s moved by 0.88 -> 1.15 between two runs of the same code)."""
    outs = {hz: Outcome.empty(len(req)) for hz in worlds}
    rollouts = dict.fromkeys(worlds, 0.0)
    build = 0.0
    groups = req.by_mesh()
    for key, idx in groups.items():
        builds = []
        for hz, world in worlds.items():
            def make_body(mesh: trimesh.Trimesh, world: PhysicsWorld = world) -> tuple[Any, int]:
                spec = prepare_body(mesh).spec
                return spec, world.collision_shape(spec)

            seconds, (spec, shape) = best_of(repeats, make_body, meshes[key].copy)
            for r in idx:
                rollouts[hz] += best_of(repeats, lambda _: roll_out(world, spec, shape, req, r, rate_hz, outs[hz],
                                                                    hz if hz in SCHEDULES else None))[0]
            if hz in STEPS_HZ:  # the same work for the schedule: its build is priced as the steps' median
                builds.append(seconds)
        build += float(np.median(builds))
        after_mesh(idx)
    for hz, out in outs.items():
        out.ms = {"build": 1000 * build / len(groups), "rollout": 1000 * rollouts[hz] / len(req)}
        spread = 1000 * (build + rollouts[hz]) / len(req)
        out.ms["one"] = out.ms["build"] + out.ms["rollout"] if new_mesh_each else spread
    return outs


def ceiling_row(world: PhysicsWorld, bodies: dict[str, Any], req: Requests, rate_hz: float, method: str,
                num_points: int) -> Outcome:
    """The information ceiling of a point representation: PyBullet on the convex hull of each body's
    ``points_body(num_points, method)``, with the body's own inertia (not timed)."""
    out = Outcome.empty(len(req))
    for key, idx in req.by_mesh().items():
        spec = bodies[key].spec
        per_mass = (spec.principal_axes * spec.inertia_diag) @ spec.principal_axes.T / spec.mass
        cloud = cloud_body.cloud_body_spec(bodies[key].points_body(num_points, method), per_mass)
        shape = world.collision_shape(cloud)
        for r in idx:
            roll_out(world, cloud, shape, req, r, rate_hz, out)
    return out


class OneAtATime:
    """``Predictor.predict`` per request, each on a fresh copy of its mesh, new to physdyn, timed; the
    predictors take turns request by request (the PyBullet steps take turns mesh by mesh). ``run(requests)`` some requests
    (regime (a) runs each mesh's between PyBullet's turns), ``outcomes()`` when all have run."""

    def __init__(self, predictors: dict[str, Predictor], meshes: dict[str, trimesh.Trimesh], req: Requests,
                 repeats: int = 1):
        self.predictors, self.meshes, self.req, self.repeats = predictors, meshes, req, repeats
        self.outs = {name: Outcome.empty(len(req)) for name in predictors}
        self.spent = dict.fromkeys(predictors, 0.0)

    def run(self, requests: Any) -> None:
        req = self.req
        for r in requests:
            for name, predictor in self.predictors.items():
                def new_mesh(predictor: Predictor = predictor, key: str = req.mesh[r]) -> trimesh.Trimesh:
                    predictor.forget_meshes()  # outside the timing: the mesh is new to physdyn
                    return self.meshes[key].copy()

                seconds, result = best_of(self.repeats, lambda mesh: predictor.predict(
                    mesh, req.v0[r], req.w0[r], seconds=req.steps[r] / predictor.rate_hz, orientation_xyzw=req.q0[r]),
                    new_mesh)
                self.spent[name] += seconds
                self.outs[name].set(r, result["com_position"], result["orientation_xyzw"], result["toppled"])

    def outcomes(self) -> dict[str, Outcome]:
        for name, out in self.outs.items():
            out.ms = {"one": 1000 * self.spent[name] / len(self.req)}
        return self.outs


def physdyn_batched(predictors: dict[str, Predictor], meshes: dict[str, trimesh.Trimesh], req: Requests,
                    batches: list[np.ndarray], one_object: bool, repeats: int = 1) -> dict[str, Outcome]:
    """One timed ``Predictor.predict_many`` per batch (indices into ``req``) and predictor, its meshes new
    to physdyn: each request with a fresh copy of its mesh, or (``one_object``, a batch of one mesh's
    pushes) one copy shared by all, prepared once. The predictors take turns batch by batch."""
    outs = {name: Outcome.empty(len(req)) for name in predictors}
    spent = dict.fromkeys(predictors, 0.0)
    for idx in batches:
        for name, predictor in predictors.items():
            def new_meshes(predictor: Predictor = predictor) -> list[trimesh.Trimesh]:
                predictor.forget_meshes()
                shared = meshes[req.mesh[idx[0]]].copy()
                return [shared if one_object else meshes[req.mesh[r]].copy() for r in idx]

            seconds, results = best_of(repeats, lambda copies: predictor.predict_many(
                copies, req.v0[idx], req.w0[idx], seconds=list(req.steps[idx] / predictor.rate_hz),
                orientation_xyzw=req.q0[idx]), new_meshes)
            spent[name] += seconds
            for r, result in zip(idx, results):
                outs[name].set(r, result["com_position"], result["orientation_xyzw"], result["toppled"])
    for name, out in outs.items():
        out.ms = {"batched": 1000 * spent[name] / len(req)}
    return outs


def best_of(repeats: int, run: Callable[[Any], Any], setup: Callable[[], Any] = lambda: None) -> tuple[float, Any]:
    """The fastest of ``repeats`` timings of ``run(setup())`` (CPU seconds; ``setup`` untimed: a fresh mesh,
    emptied caches) and the last run's result."""
    fastest, result = np.inf, None
    for _ in range(repeats):
        given = setup()
        t0 = CLOCK()
        result = run(given)
        fastest = min(fastest, CLOCK() - t0)
    return fastest, result


def sliding_outcome(req: Requests) -> Outcome:
    """Coulomb sliding along v0: no rotation, nothing topples (the bar for position)."""
    return Outcome(req.slide_disp, req.q0, np.zeros(len(req), bool))


def warm_up(predictor: Predictor, mesh: trimesh.Trimesh) -> None:
    """One untimed prediction: a user's process has loaded its libraries and weights before timing counts.
    open3d too: a cloud of a hull with more than 1,024 vertices is thinned with it, and its first import
    (0.7 s, it loads IPython and plotly) fell on the first predictor's first such mesh, about 2 ms a request
    over the pybullet set's 300, charged to the first predictor named unless it is imported here."""
    import open3d  # noqa: F401

    predictor.predict(mesh.copy(), [0.5, 0.0, 0.0], [0.0, 0.0, 0.0], seconds=0.5)


# --------------------------------------------------------------------------------------------------
# Scores and rows
# --------------------------------------------------------------------------------------------------
def score(req: Requests, out: Outcome) -> dict[str, float]:
    """Medians of the final errors (position over non-toppling pushes, as a fraction of Coulomb sliding's
    too; rotation over non-toppling and all pushes) and the topple accuracy."""
    still = ~req.toppled
    position = np.linalg.norm(out.disp - req.true_disp, axis=1)
    sliding = np.linalg.norm(req.slide_disp - req.true_disp, axis=1)
    rotation = rotation_angle_deg(out.q, req.true_q)
    return {"position_cm": 100 * median(position[still]),
            "position_over_sliding": median(position[still]) / median(sliding[still]),
            "rotation_deg": median(rotation[still]), "rotation_all_deg": median(rotation),
            "topple_accuracy": float(np.mean(out.toppled == req.toppled))}


def make_row(name: str, kind: str, req: Requests, out: Outcome, **extra: Any) -> dict:
    return {"name": name, "kind": kind, **score(req, out), "ms": dict(out.ms), **extra}


@dataclass
class Progress:
    """One line per measured row, so a long run shows where it is."""

    label: str
    started: float = field(default_factory=time.perf_counter)

    def measure(self, name: str, run: Callable[[], Any]) -> Any:
        t0 = time.perf_counter()
        with warnings.catch_warnings():  # notes about a mesh (an open surface...) are the user's, not ours
            warnings.simplefilter("ignore")
            out = run()
        print(f"  {self.label}: {name} ({time.perf_counter() - t0:.0f} s)", flush=True)
        return out


def ceiling_variants(predictors: dict[str, Predictor]) -> dict[tuple[str, int], list[str]]:
    """(method, points) -> the predictors whose input it is: the fixed ``CEILINGS`` and each model's own."""
    variants: dict[tuple[str, int], list[str]] = {variant: [] for variant in CEILINGS}
    for name, predictor in predictors.items():
        variants.setdefault((predictor.points_method, predictor.num_points), []).append(name)
    return variants


def pybullet_table_rows(req: Requests, outs: dict[Any, Outcome], rate_hz: float) -> list[dict]:
    """The fixed steps' rows (kind "pybullet", in ``STEPS_HZ`` order), then the schedules' ("pybullet_schedule")."""
    rows = [make_row(f"PyBullet 1/{hz} s", "pybullet", req, outs[hz], hz=hz) for hz in STEPS_HZ]
    return rows + [make_row(schedule_name(plan, rate_hz), "pybullet_schedule", req, outs[plan], schedule=list(plan))
                   for plan in SCHEDULES]


def schedule_name(plan: tuple[int, int, int], rate_hz: float) -> str:
    fine, frames, coarse = plan
    return f"PyBullet 1/{fine} s for the first {frames / rate_hz:.2f} s, then 1/{coarse} s"


def regime_new_meshes(meshes: dict[str, trimesh.Trimesh], req: Requests, worlds: dict[Any, PhysicsWorld],
                      predictors: dict[str, Predictor], rate_hz: float, progress: Progress, repeats: int = 1) -> list[dict]:
    """Regime (a): each request a mesh new to the predictor; rows in table order."""
    rows = [make_row("Coulomb sliding (no rotation, no topple)", "baseline", req, sliding_outcome(req))]
    timer = OneAtATime(predictors, meshes, req, repeats)
    label = "PyBullet at every step (and schedule) and physdyn one at a time, mesh by mesh"
    rows += pybullet_table_rows(req, progress.measure(label, lambda: pybullet_rows(
        worlds, meshes, req, rate_hz, new_mesh_each=True, repeats=repeats, after_mesh=timer.run)), rate_hz)
    one = timer.outcomes()
    batched = progress.measure("physdyn, batched", lambda: physdyn_batched(predictors, meshes, req, req.rounds(), False,
                                                                           repeats))
    for name in predictors:
        one[name].ms.update(batched[name].ms)
        rows.append(make_row(name, "physdyn", req, one[name], batched=score(req, batched[name])))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bodies = {key: prepare_body(mesh) for key, mesh in meshes.items()}
    for (method, n), users in ceiling_variants(predictors).items():
        name = f"ceiling {method} {n}" + (f" (input of {', '.join(users)})" if users else "")
        out = progress.measure(name, lambda: ceiling_row(worlds[STEPS_HZ[0]], bodies, req, rate_hz, method, n))
        rows.append(make_row(name, "ceiling", req, out, method=method, points=n, of=users))
    return add_cost_ratios(rows)


def regime_one_mesh(meshes: dict[str, trimesh.Trimesh], req: Requests, worlds: dict[Any, PhysicsWorld],
                    predictors: dict[str, Predictor], rate_hz: float, progress: Progress, repeats: int = 1) -> list[dict]:
    """Regime (b): many pushes of each of a few meshes; rows in table order."""
    rows = [make_row("Coulomb sliding (no rotation, no topple)", "baseline", req, sliding_outcome(req))]
    rows += pybullet_table_rows(req, progress.measure("PyBullet, every step", lambda: pybullet_rows(
        worlds, meshes, req, rate_hz, new_mesh_each=False, repeats=repeats)), rate_hz)
    batches = list(req.by_mesh().values())
    outs = progress.measure("physdyn, predict_many on one mesh", lambda: physdyn_batched(
        predictors, meshes, req, batches, one_object=True, repeats=repeats))
    rows += [make_row(name, "physdyn", req, out) for name, out in outs.items()]
    return add_cost_ratios(rows)


# --------------------------------------------------------------------------------------------------
# The run
# --------------------------------------------------------------------------------------------------
def machine_lines() -> list[str]:
    """The exact command and what it ran on."""
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor()) if Path("/proc/cpuinfo").is_file() else platform.processor()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).resolve().parent).stdout.strip() or "unknown"
    return [f"command: python {shlex.join(sys.argv)}",
            f"machine: {cpu}, {os.cpu_count()} CPUs ({len(os.sched_getaffinity(0))} usable), load average "
            f"{os.getloadavg()[0]:.2f} at the start; torch {torch.__version__} with {torch.get_num_threads()} thread(s), "
            f"OMP/MKL threads {os.environ['OMP_NUM_THREADS']}/{os.environ['MKL_NUM_THREADS']}; physdyn at {commit}; "
            f"{time.strftime('%Y-%m-%d %H:%M')}"]


def start_run(work: str) -> tuple[list[str], float, Path]:
    """How a benchmark run begins: one torch thread, the machine's lines printed, the work folder made. Returns
    the header lines, the start time (``time.perf_counter``) and the work folder."""
    torch.set_num_threads(1)
    started = time.perf_counter()
    header = machine_lines()
    print("\n".join(header), flush=True)
    folder = Path(work)
    folder.mkdir(parents=True, exist_ok=True)
    return header, started, folder


def closing_line(started: float) -> str:
    """The header's last line: the run's wall clock since ``started`` and the load it ended under."""
    return f"{time.perf_counter() - started:.0f} s in all; load average {os.getloadavg()[0]:.2f} at the end"


def networks_checkpoint(work: Path) -> Path:
    """The bundled model exported with ``model.sim_seconds=0`` (its networks alone) into ``work``, once per
    bundled file (its content names the copy)."""
    digest = hashlib.sha256(BUNDLED_CHECKPOINT.read_bytes()).hexdigest()[:12]
    path = work / f"bundled_networks_{digest}.ckpt"
    if not path.is_file():
        export_checkpoint(BUNDLED_CHECKPOINT, path, settings=["model.sim_seconds=0"])
    return path


def load_predictors(specs: list[str], work: Path) -> dict[str, Predictor]:
    """``NAME=CHECKPOINT`` -> predictors; CHECKPOINT is a path, ``bundled``, ``networks`` (the bundled
    model's networks alone) or ``contact_prior`` (the contact prior alone, no network: the planner's screen)."""
    predictors = {}
    for spec in specs:
        name, sep, checkpoint = spec.partition("=")
        if not (sep and name and checkpoint):
            raise SystemExit(f"--predictor {spec!r}: use NAME=CHECKPOINT (a path, 'bundled', 'networks' or 'contact_prior')")
        if checkpoint == "bundled":
            predictors[name] = load_predictor("bundled")
        elif checkpoint == "contact_prior":
            predictors[name] = contact_prior_predictor()
        elif checkpoint == "networks":
            predictors[name] = load_predictor(str(networks_checkpoint(work)))
        else:
            predictors[name] = load_predictor(checkpoint)
    return predictors


def store_skipped(store, meshes: MeshSet) -> list[dict]:
    """The meshes the truth's generator could not use ({"mesh", "reason"})."""
    files = sorted(meshes.origin)  # the meshes family lists a folder sorted, and the names are all there is
    return [{"mesh": meshes.origin[files[s["index"]]], "reason": s["reason"]} for s in store.attrs.get("skipped", [])]


def measure_set(set_name: str, args: argparse.Namespace, predictors: dict[str, Predictor], work: Path) -> dict:
    """Both regimes on one mesh set: its rows and what they were measured on."""
    meshes = collect_set(set_name, work, args.meshes)
    store = truth_store(meshes, args.pushes)
    rate = store.rate_hz
    for name, predictor in predictors.items():
        if abs(predictor.rate_hz - rate) > 1e-9:
            raise SystemExit(f"predictor {name} predicts at {predictor.rate_hz} Hz, the truth is recorded at {rate} Hz")
    worlds = open_worlds(config_from_dict(PhysicsConfig, store.attrs["physics"]))
    parsed = {key: load_mesh(key) for key in dict.fromkeys(map(str, store.source))}  # files parsed before any timing
    for predictor in predictors.values():
        warm_up(predictor, next(iter(parsed.values())))
    req = requests_from_store(store)
    rows_a = regime_new_meshes(parsed, req, worlds, predictors, rate, Progress(f"{set_name} (a)"), args.repeats)

    few = one_mesh_set(meshes, args.one_meshes)
    store_b = truth_store(few, args.one_mesh_pushes)
    parsed_b = {key: load_mesh(key) for key in dict.fromkeys(map(str, store_b.source))}
    req_b = requests_from_store(store_b, horizon=int(round(args.one_mesh_seconds * rate)))
    rows_b = regime_one_mesh(parsed_b, req_b, worlds, predictors, rate, Progress(f"{set_name} (b)"), args.repeats)
    for world in worlds.values():
        world.close()
    return {
        "meshes": list(meshes.origin.values()), "skipped": meshes.skipped + store_skipped(store, meshes),
        "new_meshes": {"meshes": len(parsed), "pushes": len(req), "header": regime_header(
            f"{set_name}, (a) new meshes, each request a mesh new to the predictor, to the truth's own length",
            req, len(parsed)), "rows": rows_a},
        "one_mesh": {"meshes": list(few.origin.values()), "pushes_per_mesh": args.one_mesh_pushes,
                     "seconds": args.one_mesh_seconds, "header": regime_header(
                         f"{set_name}, (b) {args.one_mesh_pushes} pushes of each mesh, {args.one_mesh_seconds:g} s "
                         f"each ({', '.join(few.origin.values())})", req_b, len(parsed_b)), "rows": rows_b},
    }


def skipped_line(result: dict) -> str:
    return "Skipped: " + "; ".join(f"{s['mesh']} ({s['reason']})" for s in result["skipped"]) if result["skipped"] else ""


def verdicts(set_name: str, rows: list[dict], hz: int = 120) -> list[str]:
    """One line per physdyn predictor of regime (a) and reference: where it stands against PyBullet at 1/hz s
    on the set's new meshes (the issue's bar: no worse in position, rotation and toppling, and no dearer),
    then against each step schedule (the simulator as a user who knows where the fine step pays runs it)."""
    references = [(r, f"PyBullet at 1/{hz} s") for r in rows if r["kind"] == "pybullet" and r["hz"] == hz]
    references += [(r, f"{r['name']} (the step schedule)") for r in rows if r["kind"] == "pybullet_schedule"]
    return [line for reference, label in references for line in verdicts_against(set_name, rows, reference, label)]


def verdicts_against(set_name: str, rows: list[dict], reference: dict, label: str) -> list[str]:
    lines = []
    for row in (r for r in rows if r["kind"] == "physdyn"):
        pairs = [("position / sliding", row["position_over_sliding"], reference["position_over_sliding"], "{:.2f}", False),
                 ("rotation", row["rotation_deg"], reference["rotation_deg"], "{:.1f} deg", False),
                 ("topple accuracy", row["topple_accuracy"], reference["topple_accuracy"], "{:.3f}", True),
                 ("ms for a new mesh", row["ms"]["one"], reference["ms"]["one"], "{:.1f}", False)]
        better = [(ours >= theirs) if higher else (ours <= theirs) for _, ours, theirs, _, higher in pairs]
        figures = ", ".join(f"{label} {fmt_.format(ours)} vs {fmt_.format(theirs)}" for label, ours, theirs, fmt_, _ in pairs)
        worse = ", ".join(p[0] for p, b in zip(pairs[:3], better[:3]) if not b)
        cost = "as cheap or cheaper" if better[3] else "dearer"
        if all(better):
            word = "as accurate or better, and as cheap or cheaper: on the frontier beside it"
        elif all(better[:3]):
            word = "as accurate or better, but dearer"
        elif not any(better):
            word = "less accurate on every figure and dearer: dominated"
        elif not any(better[:3]):
            word = "as cheap or cheaper, less accurate on every figure"
        else:
            word = f"{cost}, less accurate on {worse}"
        lines.append(f"{row['name']} against {label} on {set_name}'s new meshes: {figures}: {word}.")
    return lines


def report(results: dict[str, dict], header: list[str]) -> str:
    """The markdown page: the command and machine, then per set its tables and skipped meshes."""
    parts = ["# The accuracy-cost frontier (benchmarks/frontier.py)", "", *[f"- {line}" for line in header], "",
             TABLE_NOTES, ""]
    for set_name, result in results.items():
        parts += [f"## {set_name}", ""]
        for regime in ("new_meshes", "one_mesh"):
            parts += [result[regime]["header"], "", table(result[regime]["rows"]), ""]
        parts += [*verdicts(set_name, result["new_meshes"]["rows"]), "", skipped_line(result), ""]
    return "\n".join(parts)


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", nargs="+", choices=SETS, default=list(SETS))
    ap.add_argument("--meshes", type=int, default=60, help="meshes per set")
    ap.add_argument("--pushes", type=int, default=5, help="simulated pushes per mesh, regime (a)")
    ap.add_argument("--one-meshes", type=int, default=2, help="meshes per set of regime (b)")
    ap.add_argument("--one-mesh-pushes", type=int, default=512, help="pushes of each mesh, regime (b)")
    ap.add_argument("--one-mesh-seconds", type=float, default=2.0, help="horizon of regime (b)")
    ap.add_argument("--predictor", action="append", default=None, metavar="NAME=CHECKPOINT",
                    help="a physdyn predictor (repeatable); CHECKPOINT: a path, 'bundled', 'networks' (the bundled "
                         f"model exported with model.sim_seconds=0) or 'contact_prior' (no network); default: {' '.join(DEFAULT_PREDICTORS)}")
    ap.add_argument("--work", default="runs/frontier", help="meshes, the wheel, truth stores (reused when present)")
    ap.add_argument("--out", default=None, help="markdown report; the figures go beside it as .json "
                                                "(default reports/frontier/frontier.md)")
    ap.add_argument("--plot", default=None, help="the plot (default: --out with .png; docs/performance.md's "
                                                 "run passed --plot docs/figures/frontier.png)")
    ap.add_argument("--repeats", type=int, default=1,
                    help="time every request (and PyBullet's builds and roll-outs) this many times and keep the fastest "
                         "(a request's stalls go, the machine's drift between phases does not; 5: about 4x the run time)")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke check: " + ", ".join(f"--{k.replace('_', '-')} {v}" for k, v in QUICK.items())
                         + "; report and plot under WORK/quick/ unless given")
    args = ap.parse_args()
    if args.repeats < 1:
        ap.error(f"--repeats: at least 1, got {args.repeats}")
    if args.quick:
        for key, value in QUICK.items():
            setattr(args, key, value)
    quick_dir = Path(args.work) / "quick"
    args.out = Path(args.out or (quick_dir / "frontier.md" if args.quick else "reports/frontier/frontier.md"))
    args.plot = Path(args.plot or args.out.with_suffix(".png"))
    args.predictor = args.predictor or list(DEFAULT_PREDICTORS)
    return args


def main() -> None:
    args = parse_args()
    header, started, work = start_run(args.work)
    predictors = load_predictors(args.predictor, work)
    results = {}
    for set_name in args.sets:
        results[set_name] = result = measure_set(set_name, args, predictors, work)
        for regime in ("new_meshes", "one_mesh"):
            print(f"\n{result[regime]['header']}\n{table(result[regime]['rows'])}", flush=True)
        if result["skipped"]:
            print(skipped_line(result), flush=True)
        for line in verdicts(set_name, result["new_meshes"]["rows"]):
            print(line, flush=True)
    header.append(closing_line(started))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(report(results, header))
    args.out.with_suffix(".json").write_text(json.dumps({"header": header, "sets": results}, indent=1))
    plot(results, args.plot)
    print(f"\n{header[-1]}\nwrote {args.out}, {args.out.with_suffix('.json')} and {args.plot}")


if __name__ == "__main__":
    main()
