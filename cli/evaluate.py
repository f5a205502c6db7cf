"""``sensor-agent evaluate``: many closed-loop runs, in parallel, summarised with intervals.

::

    sensor-agent evaluate (--random N [--seed S] | WORLD_OR_DIR ...) --policy P [--jobs J]
                          [--shard K/N] [--json FILE] [--plots DIR] [--cluster ADDRESS]
    sensor-agent evaluate merge A.json B.json ... --json OUT [--plots DIR]
    sensor-agent evaluate plot A.json B.json ... --plots DIR

The run list
    ``--random N``: run ``i`` is the ``i``-th (world, task) of
    ``agent.sim.taskgen.random_tasks(N, seed)``, which depends only on ``(seed, i)``.
    Otherwise the world files in the order given, a directory standing for its ``*.toml``
    files sorted by name; each must have a ``[task]`` table. Run ``i`` drives its task with
    ``--policy`` through the runner (:data:`Runner`; by default
    :func:`closed_loop_runner`), deterministic given (world, task, policy, seed, ``i``).
Shards
    ``--shard K/N`` runs only the runs ``i`` (from 0) with ``i % N == K - 1``; ``K`` counts
    from 1. ``evaluate merge`` joins the shards' JSON files into exactly the file one
    unsharded invocation writes (:func:`merge_documents`), refusing shards of another
    policy, seed or run list, and runs missing or in two shards.
Parallel
    ``--jobs J`` worker processes (default: every core this process may use); each run in a
    worker, results in run order whatever order they finish in. ``--jobs 1`` runs in this
    process. ``--cluster ADDRESS`` sends the runs to a Dask distributed scheduler instead
    (the optional extra ``cluster``: ``dask[distributed]``; its workers must run this
    project, the same sources: ``docs/evaluate.md``). A run that raises, or whose worker
    dies, is an ``error`` outcome carrying its message; the evaluation goes on.

The JSON: ``{"policy", "seed", "run_list", "runs_total", "shard", "runs": [...],
"summary": {...}, "timing": {...}}``; a run is :meth:`RunRecord.to_json`, the summary
:func:`summarise`. Rates carry their 95 % Wilson interval (:func:`wilson`).

Wall clock: every value that depends on it is in :data:`WALL_CLOCK_FIELDS`, and
:func:`without_wall_clock` removes them; the rest of a file is a function of the runs alone.
``realtime_factor_per_core`` is the simulated seconds over the wall seconds the runs
occupied a core each (each run runs on one core, so their sum is the wall time times the
cores used, without the pool's idle time).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import importlib
import itertools
import json
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from agent.errors import ConfigError, WorldFileError
from agent.task import TASK_KINDS
from cli.output import jsonable, progress_bar, write_json

if TYPE_CHECKING:
    from agent.sim.world import World
    from agent.task import Task

__all__ = [
    "COLLIDERS",
    "OUTCOMES",
    "POLICIES",
    "WALL_CLOCK_FIELDS",
    "RunRecord",
    "RunSpec",
    "Runner",
    "TaskSource",
    "closed_loop_runner",
    "downsample_path",
    "evaluate_command",
    "evaluation_document",
    "merge_documents",
    "paired_difference",
    "paired_progress_difference",
    "paired_score_difference",
    "run_all",
    "run_one",
    "shard_indices",
    "summarise",
    "wilson",
    "without_wall_clock",
    "world_paths",
]

CONTROLLERS = ("default", "dwa")  # the vehicle controller's planners (agent.control)
OUTCOMES = ("success", "collision", "timeout", "stale_stop", "error")
COLLIDERS = ("vehicle", "mover")
COLLIDED_WITH = ("static", "mover")
# The head policies evaluate accepts: the one registry of their names (the command refuses
# any other with this list).
POLICIES: dict[str, str] = {
    "forward": "head fixed forward, the full ±20° window",
    "sweep": "a blind sweep, whatever the tracks",
    "active": "where it pays: information along the vehicle's way per second of head time",
    "greedy": "the most track uncertainty reduced, whatever the time or the path",
}
WALL_CLOCK_FIELDS = (
    "timing",
    "runs[].wall_s",
    "runs[].extra.loop_wall_s",
    "summary.realtime_factor_per_core",
    "summary.by_task.*.realtime_factor_per_core",
    "runs[].extra.decision_us",
    "summary.decision_ms_p99",
    "summary.by_task.*.decision_ms_p99",
)
MAX_JSON_BYTES = 1 << 30  # a shard file: 1 GiB is ~10^6 runs with their paths
PATH_POINTS = 200  # a record's downsampled true path: at most this many points


# ------------------------------------------------------------------------------ one run
@dataclass(frozen=True)
class RunSpec:
    """Everything one run needs; picklable, so that a worker process can take it.

    Attributes
    ----------
    index
        The run's place in the whole run list, from 0.
    seed
        The evaluation's seed.
    policy
        The head policy (a key of :data:`POLICIES`).
    world_label
        The world file's path as given, or the random world's name.
    world, task
        The world and its task.
    world_toml
        The world's TOML text (with its ``[task]``), carried into the records of failed runs.
    controller
        The vehicle controller's planner: ``default`` or ``dwa`` (the dynamic window
        baseline).
    """

    index: int
    seed: int
    policy: str
    world_label: str
    world: World
    task: Task
    world_toml: str | None = None
    controller: str = "default"

    @property
    def noise_seed(self) -> int:
        """A seed for the run's noise (odometry, head) drawn from ``(seed, index)`` alone."""
        return int(np.random.SeedSequence([self.seed, self.index]).generate_state(1)[0])


@dataclass(frozen=True)
class RunRecord:
    """One run's outcome, as the JSON's ``runs`` hold it (:meth:`to_json`).

    The runner fills the outcome's fields; :func:`run_one` sets ``index``, ``seed``,
    ``world``, ``task`` and ``wall_s`` from the run itself, and ``world_toml`` for a failed
    run that has none.

    Attributes
    ----------
    world
        The world file's path as given, or the random world's name.
    task
        The task's kind: ``goto``, ``park`` or ``dock``.
    outcome
        One of :data:`OUTCOMES`.
    collision_by
        ``vehicle`` (it drove into something) or ``mover`` (something walked into it) for a
        collision; ``None`` otherwise.
    collision_with
        What it touched: ``static`` (a wall, box or cylinder) or ``mover``; ``None`` when
        there was no collision or the runner does not say.
    time_s
        Simulated seconds from the start to the outcome.
    min_clearance_m
        The least distance between the vehicle's outline and any obstacle over the run.
    path_ratio
        The distance driven over ``shortest_path_m``.
    score
        The run's score (the runner's definition; higher is better).
    dock_error_mm, dock_error_deg
        ``dock`` only: the final pose's distance and heading from the docking pose.
    final_pose
        The true final pose: (x_m, y_m, yaw_deg), world frame.
    index, seed
        The run's place in the run list and the evaluation's seed.
    error
        ``error`` outcome only: what was raised, one line.
    shortest_path_m, sim_time_s, wall_s
        The shortest collision-free path to the goal; the simulated seconds run (which can
        pass ``time_s``); the wall seconds the run took (set by :func:`run_one`).
    true_path
        Optional, the true path downsampled (:func:`downsample_path`): [[x_m, y_m], ...].
    world_toml
        Optional, the world's TOML text (the failure gallery draws from it).
    extra
        Anything else worth keeping (e.g. counters), JSON-able.
    """

    world: str
    task: str
    outcome: str
    collision_by: str | None = None
    collision_with: str | None = None
    time_s: float | None = None
    min_clearance_m: float | None = None
    path_ratio: float | None = None
    score: float | None = None
    dock_error_mm: float | None = None
    dock_error_deg: float | None = None
    final_pose: tuple[float, float, float] | None = None
    index: int = 0
    seed: int = 0
    error: str | None = None
    shortest_path_m: float | None = None
    sim_time_s: float | None = None
    wall_s: float | None = None
    true_path: Sequence[Sequence[float]] | None = None
    world_toml: str | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.outcome not in OUTCOMES:
            raise ValueError(f"RunRecord.outcome must be one of {OUTCOMES}, got {self.outcome!r}")
        if self.collision_by is not None and self.collision_by not in COLLIDERS:
            raise ValueError(
                f"RunRecord.collision_by must be None or one of {COLLIDERS}, "
                f"got {self.collision_by!r}"
            )
        if self.collision_with is not None and self.collision_with not in COLLIDED_WITH:
            raise ValueError(
                f"RunRecord.collision_with must be None or one of {COLLIDED_WITH}, "
                f"got {self.collision_with!r}"
            )
        if self.final_pose is not None and len(self.final_pose) != 3:
            raise ValueError("RunRecord.final_pose must be (x_m, y_m, yaw_deg)")

    @classmethod
    def failed(cls, spec: RunSpec, exc: BaseException) -> RunRecord:
        """The ``error`` record of a run that raised ``exc``: its type, message and where."""
        where = ""
        frames = traceback.extract_tb(exc.__traceback__)
        if frames:
            last = frames[-1]
            where = f" (at {Path(last.filename).name}:{last.lineno} in {last.name})"
        text = " ".join(f"{type(exc).__name__}: {exc}".split())
        return cls(
            world=spec.world_label, task=spec.task.kind, outcome="error",
            index=spec.index, seed=spec.seed, error=text + where,
        )  # fmt: skip

    def to_json(self) -> dict[str, Any]:
        """A JSON object (finite floats, NaN and infinities as null; optional keys only when
        set: ``error``, ``true_path``, ``world_toml``, ``extra``)."""
        out: dict[str, Any] = {
            "index": self.index,
            "seed": self.seed,
            "world": self.world,
            "task": self.task,
            "outcome": self.outcome,
            "collision_by": self.collision_by,
            "collision_with": self.collision_with,
            "time_s": self.time_s,
            "min_clearance_m": self.min_clearance_m,
            "path_ratio": self.path_ratio,
            "score": self.score,
            "dock_error_mm": self.dock_error_mm,
            "dock_error_deg": self.dock_error_deg,
            "final_pose": None if self.final_pose is None else list(self.final_pose),
            "shortest_path_m": self.shortest_path_m,
            "sim_time_s": self.sim_time_s,
            "wall_s": self.wall_s,
        }
        if self.error is not None:
            out["error"] = self.error
        if self.true_path is not None:
            out["true_path"] = [list(p) for p in self.true_path]
        if self.world_toml is not None:
            out["world_toml"] = self.world_toml
        if self.extra:
            out["extra"] = dict(self.extra)
        result: dict[str, Any] = jsonable(out)
        return result


Runner = Callable[[RunSpec], RunRecord]
"""Drives one run to its outcome. It must be picklable (a module-level function) to run in
worker processes, and deterministic given the spec."""
TaskSource = Callable[[int, int], Sequence[tuple["World", "Task"]]]
"""``(n, seed) -> [(world, task)] * n``, entry ``i`` depending only on ``(seed, i)``."""


def closed_loop_runner(spec: RunSpec) -> RunRecord:
    """The default runner: the closed loop of :mod:`cli.closed_loop` (``run_record``)."""
    from cli import closed_loop

    run_record: Runner = closed_loop.run_record  # type: ignore[attr-defined]
    return run_record(spec)


def _default_runner_missing() -> str | None:
    """Why the default runner cannot run, or None."""
    try:
        from cli import closed_loop
    except ImportError as exc:
        return f"the closed-loop runner cannot be imported ({exc})"
    if not callable(getattr(closed_loop, "run_record", None)):
        return "the closed-loop runner cli.closed_loop.run_record is not available"
    return None


def random_task_source(n: int, seed: int) -> Sequence[tuple[World, Task]]:
    """The default ``--random`` worlds: ``agent.sim.taskgen.random_tasks(n, seed)``."""
    try:
        taskgen = importlib.import_module("agent.sim.taskgen")
    except ImportError as exc:
        raise ConfigError(f"evaluate --random: no random task generator ({exc})") from None
    worlds: Sequence[tuple[World, Task]] = taskgen.random_tasks(n, seed)
    return worlds


def downsample_path(xy: Any, max_points: int = PATH_POINTS) -> list[list[float]]:
    """A (k, 2) path as at most ``max_points`` points, first and last kept, to the mm."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) > max_points:
        xy = xy[np.unique(np.linspace(0, len(xy) - 1, max_points).round().astype(np.int64))]
    rounded: list[list[float]] = np.round(xy, 3).tolist()
    return rounded


def run_one(runner: Runner, spec: RunSpec) -> RunRecord:
    """Run ``spec`` through ``runner``, timed; whatever it raises becomes an ``error`` record."""
    started = time.perf_counter()
    try:
        record = runner(spec)
        if not isinstance(record, RunRecord):
            raise TypeError(f"the runner returned {type(record).__name__}, not a RunRecord")
    except Exception as exc:
        record = RunRecord.failed(spec, exc)
    wall_s = time.perf_counter() - started
    failed = record.outcome != "success"
    return dataclasses.replace(
        record,
        index=spec.index,
        seed=spec.seed,
        world=spec.world_label,
        task=spec.task.kind,
        wall_s=wall_s,
        world_toml=spec.world_toml if failed and record.world_toml is None else record.world_toml,
    )


def default_jobs() -> int:
    """Every core this process may use."""
    count: Callable[[], int | None] = getattr(os, "process_cpu_count", os.cpu_count)
    return max(1, count() or 1)


def _pool_context() -> Any:
    """Workers started from a clean server process (forking this one would copy its
    threads' state: tqdm's monitor, numba's pool)."""
    import multiprocessing

    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")


def run_all(
    specs: Sequence[RunSpec],
    runner: Runner,
    jobs: int,
    progress: Callable[[int, int], None] | None = None,
    cluster: str | None = None,
) -> list[RunRecord]:
    """Run every spec; records in the order of ``specs``, whatever order they finish in.

    ``jobs`` worker processes (1: in this process, no pool), or the Dask scheduler at
    ``cluster``. A run that raises, or whose worker dies, is an ``error`` record.
    """
    if cluster is not None:
        return _run_on_cluster(specs, runner, cluster, progress)
    total = len(specs)
    if jobs <= 1 or total <= 1:
        records = []
        for done, spec in enumerate(specs, 1):
            records.append(run_one(runner, spec))
            if progress is not None:
                progress(done, total)
        return records
    pool = ProcessPoolExecutor(max_workers=min(jobs, total), mp_context=_pool_context())
    try:
        futures: dict[Future[RunRecord], int] = {
            pool.submit(run_one, runner, spec): k for k, spec in enumerate(specs)
        }
        return _collect(specs, ((futures[f], f) for f in as_completed(futures)), progress)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _collect(
    specs: Sequence[RunSpec],
    finished: Iterable[tuple[int, Any]],
    progress: Callable[[int, int], None] | None,
) -> list[RunRecord]:
    """The records of ``specs`` from their futures, ``(k, future)`` in the order they finish
    (a pool's or Dask's), put in the order of ``specs``. A future that raises (its worker
    died, the spec did not pickle) is the run's ``error`` record."""
    results: dict[int, RunRecord] = {}
    for k, future in finished:
        try:
            results[k] = future.result()
        except Exception as exc:
            results[k] = RunRecord.failed(specs[k], exc)
        if progress is not None:
            progress(len(results), len(specs))
    return [results[k] for k in range(len(specs))]


def _run_on_cluster(
    specs: Sequence[RunSpec],
    runner: Runner,
    address: str,
    progress: Callable[[int, int], None] | None,
) -> list[RunRecord]:
    """:func:`run_all` on the Dask distributed scheduler at ``address``: each run submitted
    as the pool would run it (:func:`run_one` with ``runner`` and the spec), collected as it
    finishes (:func:`_collect`). The workers must run this project's sources: checked first
    (:func:`_project_fingerprint`) on every worker the scheduler has."""
    try:
        distributed = importlib.import_module("dask.distributed")
    except ImportError:
        raise ConfigError("--cluster needs dask.distributed (pip install '.[cluster]')") from None
    try:
        client = distributed.Client(address)
    except (OSError, ValueError) as exc:  # unreachable (a timeout is an OSError), or no address
        raise ConfigError(f"evaluate --cluster {address}: no scheduler there ({exc})") from None
    with client:
        _check_workers(client, address)
        futures = [client.submit(run_one, runner, spec, pure=False) for spec in specs]
        where = {future.key: k for k, future in enumerate(futures)}
        finished = distributed.as_completed(futures)
        return _collect(specs, ((where[f.key], f) for f in finished), progress)


def _project_fingerprint() -> str:
    """SHA-256 of this project's installed modules and data (``agent``, ``cli``,
    ``processes``: their ``*.py`` and ``*.npz`` files by relative path), to tell whether a
    worker runs the same project as this host."""
    import hashlib
    import importlib.util

    digest = hashlib.sha256()
    for package in ("agent", "cli", "processes"):
        spec = importlib.util.find_spec(package)
        roots = () if spec is None else spec.submodule_search_locations or ()
        for root in map(Path, roots):
            for path in sorted(root.rglob("*")):
                if path.suffix in (".py", ".npz") and "__pycache__" not in path.parts:
                    digest.update(f"{package}/{path.relative_to(root).as_posix()}\0".encode())
                    digest.update(path.read_bytes())
    return digest.hexdigest()


def _check_workers(client: Any, address: str) -> None:
    """Refuse workers that cannot import this project or run other sources of it."""
    here = _project_fingerprint()
    found = client.run(_project_fingerprint, on_error="return")
    wrong = [
        f"{worker} cannot import it ({value})"
        if isinstance(value, BaseException)
        else f"{worker} runs other sources of it"
        for worker, value in sorted(found.items())
        if value != here
    ]
    if wrong:
        more = f" and {len(wrong) - 3} more" if len(wrong) > 3 else ""
        raise ConfigError(
            f"evaluate --cluster {address}: the workers must run this project, the same "
            f"version (pip install '.[cluster]' on every host): {'; '.join(wrong[:3])}{more}"
        )
    if not found:
        print(f"evaluate: no workers at {address} yet; the runs wait for them", file=sys.stderr)


# ----------------------------------------------------------------------------- run lists
def world_paths(targets: Sequence[str]) -> list[Path]:
    """World files in order; a directory stands for its ``*.toml`` files sorted by name."""
    paths: list[Path] = []
    for target in targets:
        path = Path(target)
        if path.is_dir():
            found = sorted(p for p in path.glob("*.toml") if p.is_file())
            if not found:
                raise ConfigError(f"evaluate: directory {path}: no *.toml world files")
            paths.extend(found)
        elif path.exists():
            paths.append(path)
        else:
            raise ConfigError(f"evaluate: {path}: no such world file or directory")
    return paths


def file_specs(
    paths: Sequence[Path], policy: str, seed: int, indices: Iterable[int]
) -> list[RunSpec]:
    """The runs ``indices`` of the run list ``paths``; every file is read and checked first
    (a world without a ``[task]`` is refused naming the file)."""
    from agent.sim.world_file import load_world

    worlds = []
    for path in paths:
        world = load_world(path)
        task = getattr(world, "task", None)
        if task is None:
            raise WorldFileError(path, "no [task] table (evaluate drives each world's task)")
        worlds.append((path, world, task))
    specs = []
    for i in indices:
        path, world, task = worlds[i]
        text = path.read_text(encoding="utf-8")
        specs.append(RunSpec(i, seed, policy, str(path), world, task, text))
    return specs


def random_specs(
    n: int, seed: int, policy: str, indices: Iterable[int], source: TaskSource
) -> list[RunSpec]:
    """The runs ``indices`` of ``source(n, seed)``."""
    from agent.sim.world_toml import world_toml

    drawn = list(source(n, seed))
    if len(drawn) != n:
        raise ConfigError(f"evaluate --random {n}: the generator gave {len(drawn)} worlds")
    specs = []
    for i in indices:
        world, task = drawn[i]
        label = world.name or f"random {i}"
        specs.append(RunSpec(i, seed, policy, label, world, task, world_toml(world, task)))
    return specs


def parse_shard(text: str) -> tuple[int, int]:
    """``"K/N"`` to (K, N), 1 <= K <= N."""
    k_text, slash, n_text = text.partition("/")
    try:
        k, n = int(k_text), int(n_text)
    except ValueError:
        k = n = 0
    if not slash or not 1 <= k <= n:
        raise ConfigError(f"evaluate: --shard must be K/N with 1 <= K <= N, got {text!r}")
    return k, n


def shard_indices(total: int, k: int, n: int) -> list[int]:
    """The runs of shard ``k`` of ``n`` (``k`` from 1): ``i % n == k - 1``."""
    return list(range(k - 1, total, n))


# ------------------------------------------------------------------------------ summary
def wilson(k: int, n: int) -> dict[str, Any]:
    """``{"value": k/n, "ci95": [lo, hi]}``: the 95 % Wilson score interval
    (:func:`agent.scoring.closed_loop.wilson_interval`); nulls when n is 0."""
    if n == 0:
        return {"value": None, "ci95": None}
    from agent.scoring.closed_loop import wilson_interval

    lo, hi = wilson_interval(k, n, 0.95)
    return {"value": k / n, "ci95": [lo, hi]}


def _values(runs: Sequence[Mapping[str, Any]], key: str) -> np.ndarray:
    return np.array([r[key] for r in runs if r.get(key) is not None], dtype=np.float64)


def _extra(runs: Sequence[Mapping[str, Any]], key: str) -> np.ndarray:
    values = [(r.get("extra") or {}).get(key) for r in runs]
    return np.array([v for v in values if v is not None], dtype=np.float64)


def _stat(values: np.ndarray, how: Callable[[np.ndarray], Any]) -> float | None:
    return float(how(values)) if values.size else None


def _standing(runs: Sequence[Mapping[str, Any]]) -> dict[str, float] | None:
    """The share of the runs' time the vehicle stood, by the controller's reason (the
    runs' ``extra.standing_s`` summed, over their summed time), largest first; ``None``
    when no run records it."""
    kept = [r for r in runs if isinstance((r.get("extra") or {}).get("standing_s"), dict)]
    total = sum(float(r.get("time_s") or 0.0) for r in kept)
    if not kept or total <= 0.0:
        return None
    stood: dict[str, float] = {}
    for r in kept:
        for reason, seconds in r["extra"]["standing_s"].items():
            stood[reason] = stood.get(reason, 0.0) + float(seconds)
    return {k: v / total for k, v in sorted(stood.items(), key=lambda kv: -kv[1])}


def _summary_of(runs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    n = len(runs)
    outcome = [r["outcome"] for r in runs]
    count = {o: outcome.count(o) for o in OUTCOMES}
    successes = [r for r in runs if r["outcome"] == "success"]
    docks = [r for r in runs if r["task"] == "dock"]
    clearance = _values(runs, "min_clearance_m")
    scores = _values(runs, "score")
    timed = [r for r in runs if r.get("sim_time_s") is not None and r.get("wall_s")]
    sim_s = sum(float(r["sim_time_s"]) for r in timed)
    wall_s = sum(float(r["wall_s"]) for r in timed)
    decisions = np.array(
        [us for r in runs for us in (r.get("extra") or {}).get("decision_us", [])],
        dtype=np.float64,
    )
    return {
        "runs": n,
        "outcomes": count,
        "success_rate": wilson(count["success"], n),
        "collision_rate": wilson(count["collision"], n),
        "vehicle_collisions": sum(r.get("collision_by") == "vehicle" for r in runs),
        "mover_collisions": sum(r.get("collision_by") == "mover" for r in runs),
        "collisions_with_mover": sum(r.get("collision_with") == "mover" for r in runs),
        "timeout_rate": wilson(count["timeout"], n),
        "stale_stop_rate": wilson(count["stale_stop"], n),
        "error_rate": wilson(count["error"], n),
        "score_mean": _stat(scores, np.mean),
        "scored_runs": int(scores.size),
        "min_clearance_m": {
            "min": _stat(clearance, np.min),
            "p05": _stat(clearance, lambda v: np.percentile(v, 5)),
            "median": _stat(clearance, np.median),
        },
        "time_to_goal_s_median": _stat(_values(successes, "time_s"), np.median),
        "path_ratio_median": _stat(_values(successes, "path_ratio"), np.median),
        "dock_runs": len(docks),
        "dock_error_mm_p95": _stat(_values(docks, "dock_error_mm"), lambda v: np.percentile(v, 95)),
        "dock_error_deg_p95": _stat(
            _values(docks, "dock_error_deg"), lambda v: np.percentile(v, 95)
        ),
        "sim_time_s": sim_s,
        "realtime_factor_per_core": sim_s / wall_s if wall_s > 0 else None,
        "path_known_ahead_mean": _stat(_extra(runs, "path_known_ahead"), np.mean),
        "known_way_m_mean": _stat(_extra(runs, "known_way_m"), np.mean),
        "mean_speed_m_s": _stat(_extra(runs, "mean_speed_m_s"), np.mean),
        "progress_mean": _stat(_extra(runs, "progress"), np.mean),
        "standing_share": _standing(runs),
        "stopped_off_goal": int(np.count_nonzero(_extra(runs, "arrived_wrong"))),
        "decisions": int(decisions.size),
        "decision_ms_p99": _stat(decisions, lambda v: np.percentile(v, 99) / 1000.0),
    }


def _kinds(runs: Sequence[Mapping[str, Any]]) -> list[str]:
    present = {str(r["task"]) for r in runs}
    return [k for k in TASK_KINDS if k in present] + sorted(present - set(TASK_KINDS))


def summarise(runs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The summary of run records in their JSON form, over all and per task kind
    (``by_task``): outcome counts and rates with 95 % Wilson intervals, collisions by who
    moved, mean score, clearance (min, 5th percentile, median), time to goal and path ratio
    of the successes (medians), docking errors (95th percentile over dock runs), what the
    vehicle knew of its way (``path_known_ahead_mean``: :func:`cli.closed_loop.known_ahead`;
    ``known_way_m_mean``: :func:`cli.closed_loop.known_way`; means over runs), its mean
    speed and how much of the way it made (``progress_mean``: :func:`cli.closed_loop.
    progress`), where its time went standing (``standing_share``: the share of the runs'
    time the wheel command was zero, by the controller's reason, sampled every 0.25 s)
    and how many runs it stopped on its goal as it placed it but off it in truth
    (``stopped_off_goal``), the head planner's decision time
    (``decision_ms_p99`` over every decision; none for the passive policies), and the
    realtime factor per core (module docstring)."""
    summary = _summary_of(runs)
    summary["by_task"] = {
        kind: _summary_of([r for r in runs if r["task"] == kind]) for kind in _kinds(runs)
    }
    result: dict[str, Any] = jsonable(summary)
    return result


def evaluation_document(
    policy: str,
    seed: int,
    run_list: Mapping[str, Any],
    runs_total: int,
    shard: str | None,
    runs: Sequence[Mapping[str, Any]],
    timing: Mapping[str, Any],
    controller: str = "default",
) -> dict[str, Any]:
    """The JSON an evaluation writes (module docstring)."""
    doc = {
        "policy": policy,
        "seed": seed,
        "run_list": dict(run_list),
        "runs_total": runs_total,
        "shard": shard,
        "runs": list(runs),
        "summary": summarise(runs),
        "timing": dict(timing),
        "controller": controller,
    }
    result: dict[str, Any] = jsonable(doc)
    return result


def without_wall_clock(doc: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of an evaluation's JSON without :data:`WALL_CLOCK_FIELDS`."""
    out = copy.deepcopy(dict(doc))
    out.pop("timing", None)
    for run in out.get("runs", []):
        run.pop("wall_s", None)
        extra = run.get("extra")
        if isinstance(extra, dict):
            extra.pop("loop_wall_s", None)
            extra.pop("decision_us", None)
    summary = out.get("summary", {})
    for part in [summary, *summary.get("by_task", {}).values()]:
        part.pop("realtime_factor_per_core", None)
        part.pop("decision_ms_p99", None)
    return out


# -------------------------------------------------------------------------- merge, load
_DOCUMENT_KEYS = ("policy", "seed", "run_list", "runs_total", "runs")


def load_document(path: str | Path) -> dict[str, Any]:
    """An evaluation's JSON file, checked for the keys merge and plot use."""
    from agent.toml_files import read_limited

    def error(problem: str) -> ConfigError:
        return ConfigError(f"evaluate: {path}: {problem}")

    data = read_limited(path, error, max_bytes=MAX_JSON_BYTES)
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise error(f"not JSON ({exc})") from None
    if not isinstance(doc, dict) or any(key not in doc for key in _DOCUMENT_KEYS):
        raise error(f"not an evaluation's JSON (needs {', '.join(_DOCUMENT_KEYS)})")
    runs = doc["runs"]
    if not isinstance(runs, list) or not all(
        isinstance(r, dict) and isinstance(r.get("index"), int) for r in runs
    ):
        raise error("runs must be a list of records with an integer index")
    if not isinstance(doc["runs_total"], int):
        raise error("runs_total must be an integer")
    return doc


def _show_runs(indices: Sequence[int]) -> str:
    shown = ", ".join(str(i) for i in indices[:10])
    return shown + (f" and {len(indices) - 10} more" if len(indices) > 10 else "")


def merge_documents(docs: Sequence[tuple[str, Mapping[str, Any]]]) -> dict[str, Any]:
    """Join shards (``(file name, JSON)`` pairs) into the JSON one unsharded invocation
    writes: runs in their global order, the summary recomputed from them; the shards'
    ``timing`` kept under ``timing.shards``.

    Raises
    ------
    ConfigError
        Naming the file: a shard of another policy, seed or run list, a run in two shards,
        a run outside the list; or naming the runs that no shard has.
    """
    if not docs:
        raise ConfigError("evaluate merge: no shard files")
    first_name, first = docs[0]
    owner: dict[int, str] = {}
    runs: list[Mapping[str, Any]] = []
    for name, doc in docs:
        for key in ("policy", "seed", "controller"):
            if doc.get(key, "default") != first.get(key, "default"):
                raise ConfigError(
                    f"evaluate merge: {name}: {key} {doc.get(key)!r} differs from "
                    f"{first_name}'s {first.get(key)!r}"
                )
        if (doc["run_list"], doc["runs_total"]) != (first["run_list"], first["runs_total"]):
            raise ConfigError(f"evaluate merge: {name}: run_list differs from {first_name}'s")
        for run in doc["runs"]:
            i = run["index"]
            if not 0 <= i < first["runs_total"]:
                raise ConfigError(
                    f"evaluate merge: {name}: run {i} is outside the run list "
                    f"(0 to {first['runs_total'] - 1})"
                )
            if i in owner:
                raise ConfigError(f"evaluate merge: {name}: run {i} is also in {owner[i]}")
            owner[i] = name
            runs.append(run)
    missing = sorted(set(range(first["runs_total"])) - set(owner))
    if missing:
        raise ConfigError(
            f"evaluate merge: runs {_show_runs(missing)} of {first['runs_total']} are in none "
            f"of {', '.join(name for name, _ in docs)}"
        )
    runs.sort(key=lambda r: int(r["index"]))
    return evaluation_document(
        first["policy"], first["seed"], first["run_list"], first["runs_total"], None, runs,
        {"shards": [{"file": name, **dict(doc.get("timing") or {})} for name, doc in docs]},
        first.get("controller", "default"),
    )  # fmt: skip


def comparable(a: Mapping[str, Any], b: Mapping[str, Any]) -> bool:
    """Whether two evaluations ran the same worlds: same seed and run list."""
    return bool(a["seed"] == b["seed"] and a["run_list"] == b["run_list"])


def paired_difference(
    a: Mapping[str, Any],
    b: Mapping[str, Any],
    value: Callable[[Mapping[str, Any]], float | None],
) -> dict[str, Any] | None:
    """``value`` of ``b``'s runs minus ``a``'s, run by run (runs with a value in both), with
    the 95 % t interval of the mean difference (``scipy.stats.ttest_rel``); None unless the
    two ran the same worlds (:func:`comparable`)."""
    if not comparable(a, b):
        return None
    of_a = {r["index"]: value(r) for r in a["runs"]}
    pairs = [
        (of_a[r["index"]], vb)
        for r in b["runs"]
        if (vb := value(r)) is not None and of_a.get(r["index"]) is not None
    ]
    d = np.array([vb - va for va, vb in pairs], dtype=np.float64)
    out: dict[str, Any] = {"pairs": int(d.size), "differences": d, "mean": None, "ci95": None}
    if d.size:
        out["mean"] = float(d.mean())
    if d.size >= 2 and np.ptp(d) > 0:
        from scipy.stats import ttest_rel

        ci = ttest_rel([p[1] for p in pairs], [p[0] for p in pairs]).confidence_interval(0.95)
        out["ci95"] = [float(ci.low), float(ci.high)]
    elif d.size >= 2:
        out["ci95"] = [out["mean"], out["mean"]]  # every pair differs by the same amount
    result: dict[str, Any] = jsonable(out)
    return result


def paired_score_difference(a: Mapping[str, Any], b: Mapping[str, Any]) -> dict[str, Any] | None:
    """:func:`paired_difference` of the runs' scores."""
    return paired_difference(a, b, lambda r: r.get("score"))


def paired_progress_difference(a: Mapping[str, Any], b: Mapping[str, Any]) -> dict[str, Any] | None:
    """:func:`paired_difference` of the runs' progress (``extra["progress"]``)."""
    return paired_difference(a, b, lambda r: (r.get("extra") or {}).get("progress"))


# -------------------------------------------------------------------------------- table
def _share(summary: Mapping[str, Any], rank: int) -> str:
    """The ``rank``-th largest standing share of a summary, as ``reason 0.31``; ``-``."""
    shares = list((summary.get("standing_share") or {}).items())
    if rank >= len(shares):
        return "-"
    reason, share = shares[rank]
    return f"{reason} {share:.2f}"


def _show(value: Any, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def _rate(r: Mapping[str, Any]) -> str:
    if r["value"] is None:
        return "-"
    lo, hi = r["ci95"]
    return f"{r['value']:.2f} [{lo:.2f}, {hi:.2f}]"


def _header(doc: Mapping[str, Any]) -> str:
    run_list = doc["run_list"]
    where = (
        f"random {run_list['random']}" if "random" in run_list
        else f"{len(run_list.get('worlds', []))} world files"
    )  # fmt: skip
    shard = f", shard {doc['shard']}" if doc.get("shard") else ""
    return (
        f"evaluate: {len(doc['runs'])} of {doc['runs_total']} runs ({where}{shard}), "
        f"policy {doc['policy']}, controller {doc.get('controller', 'default')}, "
        f"seed {doc['seed']}"
    )


def print_table(doc: Mapping[str, Any]) -> None:
    """Outcome rates with their 95 % Wilson intervals, score, clearance, docking error and
    the realtime factor: over all runs and per task kind."""
    s = doc["summary"]
    columns = [("all", s), *s["by_task"].items()]
    print(_header(doc))
    timing = doc.get("timing") or {}
    if "wall_s" in timing:
        on = timing.get("cluster") or f"{timing.get('workers', 1)} worker(s)"
        print(f"  {timing['wall_s']:.1f} s wall on {on}")
    width = 20
    print(f"  {'':26s}" + "".join(f"{name:>{width}s}" for name, _ in columns))

    def row(label: str, show: Callable[[Mapping[str, Any]], str]) -> None:
        print(f"  {label:26s}" + "".join(f"{show(c):>{width}s}" for _, c in columns))

    row("runs", lambda c: str(c["runs"]))
    for key, label in (
        ("success_rate", "success"),
        ("collision_rate", "collision"),
        ("timeout_rate", "timeout"),
        ("stale_stop_rate", "stale stop"),
        ("error_rate", "error"),
    ):
        row(label, lambda c, key=key: _rate(c[key]))  # type: ignore[misc]
    row(
        "  collisions: vehicle/mover",
        lambda c: f"{c['vehicle_collisions']}/{c['mover_collisions']}",
    )
    row("  collisions with a mover", lambda c: str(c["collisions_with_mover"]))
    row("score (mean)", lambda c: _show(c["score_mean"], ".3f"))
    row("clearance min (m)", lambda c: _show(c["min_clearance_m"]["min"], ".3f"))
    row("clearance p5 / median (m)", lambda c: (
        f"{_show(c['min_clearance_m']['p05'], '.3f')} / "
        f"{_show(c['min_clearance_m']['median'], '.3f')}"
    ))  # fmt: skip
    row("time to goal, median (s)", lambda c: _show(c["time_to_goal_s_median"], ".1f"))
    row("path ratio, median", lambda c: _show(c["path_ratio_median"], ".2f"))
    row("dock error p95 (mm / deg)", lambda c: (
        "-" if not c["dock_runs"]
        else f"{_show(c['dock_error_mm_p95'], '.0f')} / {_show(c['dock_error_deg_p95'], '.1f')}"
    ))  # fmt: skip
    row("path known ahead (2 s, mean)", lambda c: _show(c.get("path_known_ahead_mean"), ".3f"))
    row("way known clear (m, of 1 m)", lambda c: _show(c.get("known_way_m_mean"), ".3f"))
    row("mean speed (m/s)", lambda c: _show(c.get("mean_speed_m_s"), ".3f"))
    row("progress (of the way, mean)", lambda c: _show(c.get("progress_mean"), ".3f"))
    row("stopped off its goal (runs)", lambda c: str(c.get("stopped_off_goal", "-")))
    for rank in range(3):  # where the time went standing: the three largest shares
        row(f"standing, share {rank + 1}", lambda c, rank=rank: _share(c, rank))  # type: ignore[misc]
    row("realtime factor per core", lambda c: _show(c["realtime_factor_per_core"], ".2f"))
    row("head decision p99 (ms)", lambda c: _show(c.get("decision_ms_p99"), ".2f"))
    errors = [r for r in doc["runs"] if r["outcome"] == "error"]
    for r in errors[:5]:
        print(f"  run {r['index']} ({r['world']}): error: {r.get('error', '')}")
    if len(errors) > 5:
        print(f"  ... and {len(errors) - 5} more errors (in the JSON)")


def print_comparison(labelled: Sequence[tuple[str, Mapping[str, Any]]]) -> None:
    """Success with its interval, mean score and mean progress per evaluation; paired
    differences of score and of progress between every two that ran the same worlds."""
    print(
        f"  {'':24s} {'runs':>6s} {'success [95 %]':>22s} {'score (mean)':>13s} "
        f"{'progress (mean)':>16s}"
    )
    for label, doc in labelled:
        s = doc["summary"]
        print(
            f"  {label:24s} {s['runs']:6d} {_rate(s['success_rate']):>22s} "
            f"{_show(s['score_mean'], '.3f'):>13s} {_show(s.get('progress_mean'), '.3f'):>16s}"
        )
    for (la, a), (lb, b) in itertools.combinations(labelled, 2):
        for name, diff in (
            ("score", paired_score_difference(a, b)),
            ("progress", paired_progress_difference(a, b)),
        ):
            if diff is None:
                print(f"  {lb} - {la}: not paired (another seed or run list)")
                break
            if diff["mean"] is None:
                continue
            if diff["ci95"] is None:
                print(f"  {lb} - {la}: {name} {diff['mean']:+.3f} over {diff['pairs']} runs")
            else:
                lo, hi = diff["ci95"]
                print(
                    f"  {lb} - {la}: {name} {diff['mean']:+.3f} [{lo:+.3f}, {hi:+.3f}] "
                    f"(95 %, paired over {diff['pairs']} runs)"
                )


def labels_of(names: Sequence[str], docs: Sequence[Mapping[str, Any]]) -> list[str]:
    """The policy of each evaluation, with its file's stem where two share a policy."""
    policies = [str(d["policy"]) for d in docs]
    return [
        p if policies.count(p) == 1 else f"{p} ({Path(n).stem})"
        for n, p in zip(names, policies, strict=True)
    ]


# ------------------------------------------------------------------------------ command
def _refuse(args: argparse.Namespace, what: str, options: Sequence[str]) -> None:
    for option in options:
        if getattr(args, option.lstrip("-").replace("-", "_"), None) is not None:
            raise ConfigError(f"evaluate {what} takes no {option}")


def _merge(args: argparse.Namespace, files: Sequence[str]) -> int:
    _refuse(args, "merge", ("--random", "--seed", "--policy", "--jobs", "--shard", "--cluster"))
    if not files:
        raise ConfigError("evaluate merge: give the shards' JSON files")
    if args.json is None:
        raise ConfigError("evaluate merge: --json OUT is required")
    doc = merge_documents([(name, load_document(name)) for name in files])
    print_table(doc)
    write_json(Path(args.json), doc)
    if args.plots is not None:
        from cli.evaluate_plots import evaluation_plots

        for path in evaluation_plots(doc, Path(args.plots)):
            print(f"wrote {path}")
    return 0


def _plot(args: argparse.Namespace, files: Sequence[str]) -> int:
    _refuse(
        args, "plot", ("--random", "--seed", "--policy", "--jobs", "--shard", "--cluster", "--json")
    )
    if not files:
        raise ConfigError("evaluate plot: give the evaluations' JSON files")
    if args.plots is None:
        raise ConfigError("evaluate plot: --plots DIR is required")
    docs = [load_document(name) for name in files]
    labels = labels_of(files, docs)
    for label, doc in zip(labels, docs, strict=True):
        if len(doc["runs"]) != doc["runs_total"]:
            print(f"  {label}: {len(doc['runs'])} of {doc['runs_total']} runs (a shard)")
    labelled = list(zip(labels, docs, strict=True))
    print_comparison(labelled)
    from cli.evaluate_plots import comparison_plots

    for path in comparison_plots(labelled, Path(args.plots)):
        print(f"wrote {path}")
    return 0


def evaluate_command(
    args: argparse.Namespace,
    runner: Runner | None = None,
    task_source: TaskSource | None = None,
) -> int:
    """``sensor-agent evaluate`` (module docstring); ``runner`` and ``task_source`` replace
    the closed loop and the random task generator (tests)."""
    targets: list[str] = list(args.targets)
    if targets and targets[0] == "merge":
        return _merge(args, targets[1:])
    if targets and targets[0] == "plot":
        return _plot(args, targets[1:])
    if args.random is not None and targets:
        raise ConfigError("evaluate: give --random N or world files, not both")
    if args.random is None and not targets:
        raise ConfigError("evaluate: give --random N or world files or directories")
    if args.random is not None and args.random < 1:
        raise ConfigError(f"evaluate: --random must be at least 1, got {args.random}")
    if args.policy is None or args.policy not in POLICIES:
        got = "none" if args.policy is None else repr(args.policy)
        raise ConfigError(f"evaluate: --policy must be one of {', '.join(POLICIES)}, got {got}")
    controller = getattr(args, "controller", None) or "default"
    if controller not in CONTROLLERS:
        raise ConfigError(
            f"evaluate: --controller must be one of {', '.join(CONTROLLERS)}, got {controller!r}"
        )
    jobs = default_jobs() if args.jobs is None else args.jobs
    if jobs < 1:
        raise ConfigError(f"evaluate: --jobs must be at least 1, got {jobs}")
    if args.cluster is not None and args.jobs is not None:
        raise ConfigError("evaluate: --cluster runs on the scheduler's workers, not --jobs")
    k, n = (1, 1) if args.shard is None else parse_shard(args.shard)
    seed = 0 if args.seed is None else args.seed
    if args.random is not None:
        total = args.random
        run_list: dict[str, Any] = {"random": total}
        specs = random_specs(
            total, seed, args.policy, shard_indices(total, k, n), task_source or random_task_source
        )
    else:
        paths = world_paths(targets)
        total = len(paths)
        run_list = {"worlds": [str(p) for p in paths]}
        specs = file_specs(paths, args.policy, seed, shard_indices(total, k, n))
    specs = [dataclasses.replace(spec, controller=controller) for spec in specs]
    if runner is None:
        why = _default_runner_missing()
        if why is not None:
            raise ConfigError(f"evaluate: {why}")
        runner = closed_loop_runner
    workers = None if args.cluster is not None else max(1, min(jobs, len(specs)))
    started = time.perf_counter()
    with progress_bar(f"evaluate {args.policy}") as progress:
        records = run_all(specs, runner, jobs, progress, args.cluster)
    timing = {
        "wall_s": time.perf_counter() - started,
        "jobs": jobs,
        "workers": workers,
        "cluster": args.cluster,
    }
    doc = evaluation_document(
        args.policy, seed, run_list, total, args.shard and f"{k}/{n}",
        [r.to_json() for r in records], timing, controller,
    )  # fmt: skip
    print_table(doc)
    if args.json is not None:
        write_json(Path(args.json), doc)
    if args.plots is not None:
        from cli.evaluate_plots import evaluation_plots

        for path in evaluation_plots(doc, Path(args.plots)):
            print(f"wrote {path}")
    return 0
