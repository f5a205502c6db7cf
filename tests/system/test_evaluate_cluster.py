"""``sensor-agent evaluate --cluster``: on a Dask scheduler with two worker processes, the
same records as a local run of the same seeds; a run that raises, or kills its worker, is an
``error`` record and the others go on; an unreachable scheduler, and workers without this
project, are refused in one line."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from agent.errors import ConfigError
from cli.evaluate import (
    RunRecord,
    RunSpec,
    random_specs,
    random_task_source,
    run_all,
    run_one,
    without_wall_clock,
)
from cli.main import main
from tests.system.conftest import ROOT

distributed = pytest.importorskip("distributed", reason="needs the cluster extra")
dask = pytest.importorskip("dask")

pytestmark = pytest.mark.timeout(150)


@pytest.fixture(scope="module")
def cluster() -> Iterator[Any]:
    """A scheduler in this process and two worker processes of one thread each. A task
    whose worker dies is not retried on another (allowed-failures 0): it fails at once. The
    scheduler's HTTP server on a free port (with None it would still take 8787)."""
    with (
        dask.config.set({"distributed.scheduler.allowed-failures": 0}),
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
        ) as running,
    ):
        yield running


def evaluate(out: Path, *argv: str) -> dict[str, Any]:
    """``sensor-agent evaluate ARGV --json OUT`` in a subprocess; the JSON it wrote."""
    done = subprocess.run(
        [sys.executable, "-m", "cli.main", "evaluate", *argv, "--json", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    doc: dict[str, Any] = json.loads(out.read_text())
    return doc


def comparable(doc: dict[str, Any]) -> dict[str, Any]:
    """The JSON without its wall-clock fields (WALL_CLOCK_FIELDS)."""
    return without_wall_clock(doc)


@pytest.fixture(scope="module")
def worlds(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """The demo hall and the first two ``--random`` worlds of seed 3, as world files whose
    tasks stop after 8 s of simulated time, so that the runs are short whatever the
    controller does."""
    from agent.sim.taskgen import random_tasks
    from agent.sim.world_file import load_world
    from agent.sim.world_toml import world_toml

    where = tmp_path_factory.mktemp("worlds")
    drawn = list(random_tasks(2, 3))
    demo = load_world(ROOT / "worlds" / "demo.toml")
    assert demo.task is not None
    drawn.insert(0, (demo, demo.task))
    paths = []
    for i, (world, task) in enumerate(drawn):
        path = where / f"{i}.toml"
        path.write_text(world_toml(world, dataclasses.replace(task, time_limit_s=8.0)))
        paths.append(str(path))
    return paths


def test_the_cluster_s_records_equal_a_local_run_of_the_same_seeds(
    cluster: Any, worlds: list[str], tmp_path: Path
) -> None:
    address = cluster.scheduler_address
    runs = (*worlds, "--seed", "3", "--policy", "forward")
    on_cluster = evaluate(tmp_path / "cluster.json", *runs, "--cluster", address)
    local = evaluate(tmp_path / "local.json", *runs, "--jobs", "2")
    assert on_cluster["timing"]["cluster"] == address
    assert local["timing"]["cluster"] is None
    assert "run_one" in cluster.scheduler.task_prefixes  # the scheduler ran them
    assert [r["index"] for r in on_cluster["runs"]] == [0, 1, 2]
    assert [r["task"] for r in on_cluster["runs"]] == ["dock", "goto", "goto"]
    assert all(r["outcome"] != "error" for r in on_cluster["runs"])
    assert comparable(on_cluster) == comparable(local)


def faulty_runner(spec: RunSpec) -> RunRecord:
    """Run 1 raises, run 3 kills its worker process; the others succeed at once."""
    if spec.index == 1:
        raise RuntimeError("boom in run 1")
    if spec.index == 3:
        time.sleep(1.0)  # so that the report of the run before it reaches the scheduler
        os._exit(3)
    return RunRecord(world="", task="", outcome="success", score=1.0 / (1 + spec.index))


def test_a_run_that_raises_or_kills_its_worker_is_an_error_record(cluster: Any) -> None:
    # The killer is the last run: a worker runs its runs in the order submitted, so no other
    # run is on the worker when it dies (one would fail with it: allowed-failures is 0).
    specs = random_specs(4, 3, "forward", range(4), random_task_source)
    records = run_all(specs, faulty_runner, 1, cluster=cluster.scheduler_address)
    assert [r.index for r in records] == [0, 1, 2, 3]
    assert [r.outcome for r in records] == ["success", "error", "success", "error"]
    # Raised in the run: the same record as in this process, but for the wall clock.
    here = run_one(faulty_runner, specs[1])
    assert records[1].wall_s is not None
    assert records[1].to_json() == {**here.to_json(), "wall_s": records[1].wall_s}
    assert records[1].error is not None and records[1].error.startswith(
        "RuntimeError: boom in run 1 (at test_evaluate_cluster.py:"
    )
    # Its worker died: the scheduler's KilledWorker, as the pool's BrokenProcessPool locally.
    assert records[3].error is not None and records[3].error.startswith("KilledWorker: ")
    assert (records[3].world, records[3].task, records[3].seed) == (specs[3].world_label, "goto", 3)


def test_an_unreachable_scheduler_is_one_line_and_status_2(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        argv = ["--random", "1", "--policy", "forward", "--cluster", "tcp://127.0.0.1:1"]
        assert main(["evaluate", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert err.startswith("sensor-agent: evaluate --cluster tcp://127.0.0.1:1: no scheduler there")


# A worker for which this project is not there: its imports of agent, cli and processes fail.
WORKER_WITHOUT_THE_PROJECT = """
import sys
class Absent:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("agent", "cli", "processes"):
            raise ModuleNotFoundError(f"No module named {name!r}")
sys.meta_path.insert(0, Absent())
from distributed.cli.dask_worker import main
sys.argv = ["dask worker", sys.argv[1], "--no-nanny", "--nthreads", "1", "--no-dashboard"]
main()
"""


def test_workers_without_the_project_are_refused_naming_them() -> None:
    with distributed.LocalCluster(n_workers=0, processes=True, dashboard_address=":0") as empty:
        worker = subprocess.Popen(
            [sys.executable, "-c", WORKER_WITHOUT_THE_PROJECT, empty.scheduler_address],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        try:
            with distributed.Client(empty.scheduler_address) as client:
                client.wait_for_workers(1, timeout=60)
                (address,) = client.scheduler_info()["workers"]
            specs = random_specs(1, 3, "forward", [0], random_task_source)
            with pytest.raises(ConfigError) as refused:
                run_all(specs, faulty_runner, 1, cluster=empty.scheduler_address)
            assert f"{address} cannot import it (" in str(refused.value)
            assert "No module named 'cli'" in str(refused.value)
            assert "pip install '.[cluster]'" in str(refused.value)
        finally:
            worker.terminate()
            worker.wait(timeout=30)
