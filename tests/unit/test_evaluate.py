"""``sensor-agent evaluate``'s machinery with a fake closed loop: argument checks, parallel
runs equal to serial ones in run order, shards merged into the unsharded file, merge
refusals, Wilson intervals against published values, error outcomes, and the plots."""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy import stats

from agent.errors import ConfigError
from agent.sim.movers import Mover
from agent.sim.world import World, world_from_obstacles
from agent.task import TASK_KINDS, Task
from cli.evaluate import (
    RunRecord,
    RunSpec,
    evaluate_command,
    load_document,
    merge_documents,
    paired_score_difference,
    parse_shard,
    shard_indices,
    summarise,
    wilson,
    without_wall_clock,
    world_paths,
)
from cli.evaluate_plots import comparison_plots, evaluation_plots
from cli.main import build_parser, main

ROOT = Path(__file__).resolve().parents[2]
PNG = b"\x89PNG\r\n\x1a\n"
CYCLE = ("success", "collision", "timeout", "success", "stale_stop")
RAISES_AT = 5  # fake_runner raises in runs i % 7 == RAISES_AT


# ------------------------------------------------------------------------------- fakes
def fake_tasks(n: int, seed: int) -> list[tuple[World, Task]]:
    """n small worlds with tasks, world i from (seed, i) alone."""
    out = []
    for i in range(n):
        rng = np.random.default_rng([seed, i])
        x = float(rng.uniform(2.0, 4.0))
        world = world_from_obstacles(
            walls=[([[x, -1.5], [x, 1.5]], 1.0)],
            boxes=[((x - 1.0, 0.6), (0.4, 0.3), 0.3, 0.8)],
            cylinders=[((x - 0.8, -0.7), 0.15, 1.0)],
            movers=[Mover(0.2, 0.8, np.array([[1.0, -1.0], [1.0, 1.0]]), 0.4)],
            name=f"fake {seed}-{i}",
        )
        kind = TASK_KINDS[i % 3]
        task = Task(
            kind, (x - 0.6, 0.0), goal_yaw_rad=0.5 if kind == "park" else None, time_limit_s=30.0
        )
        out.append((world, task))
    return out


def fake_runner(spec: RunSpec) -> RunRecord:
    """A record from the run index alone; raises in some runs. Early runs finish last."""
    i = spec.index
    time.sleep(0.02 * max(0, 4 - i))  # so that completion order differs from run order
    if i % 7 == RAISES_AT:
        raise RuntimeError(f"boom in run {i}")
    outcome = CYCLE[i % len(CYCLE)]
    dock = spec.task.kind == "dock"
    return RunRecord(
        world="overwritten", task="overwritten", outcome=outcome,
        collision_by=("vehicle", "mover")[i % 2] if outcome == "collision" else None,
        time_s=10.0 + i, min_clearance_m=0.05 * (i % 6), path_ratio=1.0 + 0.1 * (i % 3),
        score=1.0 / (1 + i), dock_error_mm=3.0 * i if dock else None,
        dock_error_deg=0.5 * i if dock else None, final_pose=(1.0, 0.1 * i, 2.0 * i),
        sim_time_s=10.0 + i, true_path=[[0.0, 0.0], [0.5, 0.05 * i], [1.0, 0.1 * i]],
    )  # fmt: skip


def pid_runner(spec: RunSpec) -> RunRecord:
    """fake_runner, noting the process it ran in."""
    record = fake_runner(spec)
    return RunRecord(**{**record.__dict__, "extra": {"pid": os.getpid()}})


def wrong_type_runner(spec: RunSpec) -> Any:
    return {"outcome": "success"}


def evaluate(argv: list[str], runner: Any = fake_runner) -> int:
    args = build_parser().parse_args(["evaluate", *argv])
    return evaluate_command(args, runner=runner, task_source=fake_tasks)


def comparable_doc(doc: dict[str, Any]) -> str:
    """The JSON without its wall-clock fields, as bytes to compare."""
    return json.dumps(without_wall_clock(doc), sort_keys=True)


@pytest.fixture(scope="module")
def serial(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    out = tmp_path_factory.mktemp("serial") / "all.json"
    assert evaluate(["--random", "10", "--seed", "3", "--policy", "sweep", "--jobs", "1",
                     "--json", str(out)]) == 0  # fmt: skip
    return load_document(out)


# ------------------------------------------------------------------------ argument checks
@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--random", "3", "worlds", "--policy", "forward"], "not both"),
        (["--policy", "forward"], "give --random N or world files"),
        (["--random", "0", "--policy", "forward"], "--random must be at least 1, got 0"),
        (["--random", "3"], "--policy must be one of forward, sweep, active, greedy, got none"),
        (["--random", "3", "--policy", "stare"], "forward, sweep, active, greedy, got 'stare'"),
        (["--random", "3", "--policy", "forward", "--jobs", "0"], "--jobs must be at least 1"),
        (["--random", "3", "--policy", "forward", "--jobs", "2", "--cluster", "h:1"], "not --jobs"),
        (["--random", "3", "--policy", "forward", "--shard", "0/3"], "got '0/3'"),
        (["--random", "3", "--policy", "forward", "--shard", "4/3"], "got '4/3'"),
        (["--random", "3", "--policy", "forward", "--shard", "2"], "K/N with 1 <= K <= N"),
        (["--random", "3", "--policy", "forward", "--shard", "a/b"], "got 'a/b'"),
        (["nowhere.toml", "--policy", "forward"], "nowhere.toml: no such world file"),
        (["merge", "a.json"], "--json OUT is required"),
        (["merge", "--json", "out.json"], "give the shards' JSON files"),
        (["merge", "a.json", "--json", "o.json", "--policy", "sweep"], "merge takes no --policy"),
        (["plot", "a.json"], "--plots DIR is required"),
        (["plot", "a.json", "--plots", "d", "--shard", "1/2"], "plot takes no --shard"),
    ],
)
def test_bad_arguments_are_one_line_and_status_2(
    argv: list[str], expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["evaluate", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("sensor-agent: evaluate"), err
    assert expected in err


def test_a_world_without_a_task_is_refused_naming_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    shutil.copy(ROOT / "worlds" / "box_before_wall.toml", tmp_path / "plain.toml")
    assert main(["evaluate", str(tmp_path), "--policy", "forward"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"world file {tmp_path / 'plain.toml'}: no [task] table" in err


def test_an_empty_directory_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", str(tmp_path), "--policy", "forward"]) == 2
    assert f"directory {tmp_path}: no *.toml world files" in capsys.readouterr().err


def test_a_directory_is_its_toml_files_sorted(tmp_path: Path) -> None:
    for name in ("b.toml", "a.toml", "notes.txt", "c.toml"):
        (tmp_path / name).write_text("")
    (tmp_path / "d.toml").mkdir()
    single = tmp_path / "d.toml" / "z.toml"  # a file given by name: where it was given
    single.write_text("")
    assert world_paths([str(single), str(tmp_path)]) == [
        single, tmp_path / "a.toml", tmp_path / "b.toml", tmp_path / "c.toml",
    ]  # fmt: skip


def test_shards_split_the_runs_by_index() -> None:
    assert parse_shard("2/3") == (2, 3)
    assert shard_indices(10, 1, 3) == [0, 3, 6, 9]
    assert shard_indices(10, 3, 3) == [2, 5, 8]
    parts = [shard_indices(11, k, 4) for k in range(1, 5)]
    assert sorted(i for part in parts for i in part) == list(range(11))
    assert shard_indices(2, 3, 3) == []


def test_cluster_without_dask_says_which_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # as if not installed
    with pytest.raises(ConfigError, match=r"pip install '\.\[cluster\]'"):
        evaluate(["--random", "2", "--policy", "forward", "--cluster", "tcp://127.0.0.1:1"])


# ---------------------------------------------------------------------------------- runs
def test_runs_carry_the_run_and_errors_do_not_stop_the_evaluation(
    serial: dict[str, Any],
) -> None:
    runs = serial["runs"]
    assert [r["index"] for r in runs] == list(range(10))
    assert all(r["seed"] == 3 and r["world"] == f"fake 3-{r['index']}" for r in runs)
    assert [r["task"] for r in runs[:3]] == ["goto", "park", "dock"]
    error = runs[RAISES_AT]
    assert error["outcome"] == "error"
    assert error["error"].startswith(f"RuntimeError: boom in run {RAISES_AT} (at test_evaluate.py:")
    assert error["score"] is None and error["final_pose"] is None
    assert serial["summary"]["outcomes"]["error"] == 1
    assert all(r["outcome"] != "error" for r in runs if r["index"] != RAISES_AT)
    # failed runs carry their world's text (with its task); successes do not
    assert all(("world_toml" in r) == (r["outcome"] != "success") for r in runs)
    assert "[task]" in error["world_toml"]


def test_a_runner_returning_something_else_is_an_error_outcome(tmp_path: Path) -> None:
    out = tmp_path / "e.json"
    assert evaluate(["--random", "2", "--policy", "forward", "--jobs", "1", "--json", str(out)],
                    runner=wrong_type_runner) == 0  # fmt: skip
    runs = load_document(out)["runs"]
    assert [r["outcome"] for r in runs] == ["error", "error"]
    assert "returned dict, not a RunRecord" in runs[0]["error"]


def test_parallel_runs_equal_serial_ones_in_run_order(
    serial: dict[str, Any], tmp_path: Path
) -> None:
    out = tmp_path / "parallel.json"
    assert evaluate(["--random", "10", "--seed", "3", "--policy", "sweep", "--jobs", "2",
                     "--json", str(out)], runner=pid_runner) == 0  # fmt: skip
    parallel = load_document(out)
    assert parallel["timing"]["workers"] == 2
    pids = {r.pop("extra")["pid"] for r in parallel["runs"] if r["outcome"] != "error"}
    assert os.getpid() not in pids  # ran in worker processes
    parallel["timing"] = serial["timing"]
    assert comparable_doc(parallel) == comparable_doc(serial)
    # the error outcome came back from the worker too
    assert parallel["runs"][RAISES_AT]["error"].startswith("RuntimeError: boom in run 5")


def test_shards_merge_into_the_unsharded_json(serial: dict[str, Any], tmp_path: Path) -> None:
    shards = [tmp_path / f"s{k}.json" for k in (1, 2, 3)]
    for k, path in enumerate(shards, 1):
        assert evaluate(["--random", "10", "--seed", "3", "--policy", "sweep", "--jobs", "1",
                         "--shard", f"{k}/3", "--json", str(path)]) == 0  # fmt: skip
    second = load_document(shards[1])
    assert [r["index"] for r in second["runs"]] == [1, 4, 7] and second["shard"] == "2/3"
    merged = tmp_path / "merged.json"
    # any order of the shards
    assert main(["evaluate", "merge", *map(str, shards[::-1]), "--json", str(merged)]) == 0
    doc = load_document(merged)
    assert doc["shard"] is None
    assert comparable_doc(doc) == comparable_doc(serial)
    assert [s["file"] for s in doc["timing"]["shards"]] == list(map(str, shards[::-1]))


def _two_shards() -> tuple[dict[str, Any], dict[str, Any]]:
    """Shards 1/2 and 2/2 of six runs, policy forward, seed 1."""
    docs = []
    for k in (1, 2):
        runs = [
            RunRecord(world=f"w{i}", task="goto", outcome="success", index=i, seed=1).to_json()
            for i in shard_indices(6, k, 2)
        ]
        docs.append({
            "policy": "forward", "seed": 1, "run_list": {"random": 6}, "runs_total": 6,
            "shard": f"{k}/2", "runs": runs, "timing": {},
        })  # fmt: skip
    return docs[0], docs[1]


@pytest.mark.parametrize(
    ("second", "expected"),
    [
        ("other_policy", "other.json: policy 'sweep' differs from a.json's 'forward'"),
        ("other_seed", "other.json: seed 2 differs from a.json's 1"),
        ("other_list", "other.json: run_list"),
        ("overlap", "other.json: run 0 is also in a.json"),
        ("missing", "runs 1, 3, 5 of 6 are in none of a.json, other.json"),
        ("outside", "other.json: run 6 is outside the run list"),
    ],
)
def test_merge_refuses_shards_that_do_not_make_one_run(
    second: str,
    expected: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    a, b = _two_shards()
    other = {
        "other_policy": {**b, "policy": "sweep"},
        "other_seed": {**b, "seed": 2},
        "other_list": {**b, "run_list": {"random": 7}, "runs_total": 7},
        "overlap": a,
        "missing": {**b, "runs": []},
        "outside": {**b, "runs": [*b["runs"], {**b["runs"][0], "index": 6}]},
    }[second]
    (tmp_path / "a.json").write_text(json.dumps(a))
    (tmp_path / "other.json").write_text(json.dumps(other))
    monkeypatch.chdir(tmp_path)
    assert main(["evaluate", "merge", "a.json", "other.json", "--json", "m.json"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and expected in err, err
    assert not (tmp_path / "m.json").exists()
    # the two good shards do merge
    (tmp_path / "b.json").write_text(json.dumps(b))
    assert main(["evaluate", "merge", "a.json", "b.json", "--json", "m.json"]) == 0


def test_merge_refuses_a_file_that_is_not_an_evaluation(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "bad.json").write_text("{not json")
    (tmp_path / "other.json").write_text(json.dumps({"policy": "forward"}))
    for name, expected in (("bad.json", "not JSON"), ("other.json", "not an evaluation's JSON")):
        assert main(["evaluate", "merge", str(tmp_path / name), "--json", "m.json"]) == 2
        err = capsys.readouterr().err
        assert f"{tmp_path / name}: {expected}" in err


# ------------------------------------------------------------------------------- figures
@pytest.mark.parametrize(
    ("k", "n", "lo", "hi"),
    [  # Newcombe (1998), Statistics in Medicine 17, 857-872, table I, method 3 (Wilson)
        (81, 263, 0.2553, 0.3662),
        (15, 148, 0.0624, 0.1605),
        (0, 20, 0.0, 0.1611),
        (1, 29, 0.0061, 0.1718),
    ],
)
def test_wilson_intervals_match_published_values(k: int, n: int, lo: float, hi: float) -> None:
    rate = wilson(k, n)
    assert rate["value"] == pytest.approx(k / n)
    assert rate["ci95"] == pytest.approx([lo, hi], abs=5e-5)  # published to 4 decimals


def test_wilson_of_no_runs_is_null() -> None:
    assert wilson(0, 0) == {"value": None, "ci95": None}


def test_summary_counts_rates_and_percentiles() -> None:
    runs = [
        RunRecord(world="a", task="dock", outcome="success", score=1.0, dock_error_mm=10.0 * i,
                  dock_error_deg=float(i), min_clearance_m=0.1 * (i + 1), time_s=20.0 + i,
                  sim_time_s=20.0, wall_s=4.0, index=i).to_json()
        for i in range(5)
    ] + [
        RunRecord(world="b", task="goto", outcome="collision", collision_by="vehicle",
                  collision_with="mover", score=0.0, min_clearance_m=0.0, sim_time_s=5.0,
                  wall_s=1.0, index=5).to_json(),
        RunRecord(world="c", task="goto", outcome="collision", collision_by="mover",
                  collision_with="mover", score=0.0, sim_time_s=5.0, wall_s=1.0,
                  index=6).to_json(),
        RunRecord(world="d", task="goto", outcome="error", error="x", index=7).to_json(),
    ]  # fmt: skip
    s = summarise(runs)
    assert s["runs"] == 8
    assert s["outcomes"] == {"success": 5, "collision": 2, "timeout": 0, "stale_stop": 0,
                             "error": 1}  # fmt: skip
    assert s["success_rate"] == wilson(5, 8)
    assert (s["vehicle_collisions"], s["mover_collisions"]) == (1, 1)
    assert s["collisions_with_mover"] == 2
    assert s["score_mean"] == pytest.approx(5 / 7) and s["scored_runs"] == 7
    assert s["dock_runs"] == 5
    assert s["dock_error_mm_p95"] == pytest.approx(38.0)  # linear between 30 and 40 mm
    assert s["min_clearance_m"]["min"] == 0.0
    assert s["time_to_goal_s_median"] == 22.0
    assert s["realtime_factor_per_core"] == pytest.approx(110.0 / 22.0)
    assert list(s["by_task"]) == ["goto", "dock"]
    assert s["by_task"]["goto"]["collision_rate"] == wilson(2, 3)
    assert s["by_task"]["goto"]["dock_error_mm_p95"] is None


def test_summary_says_where_the_time_went_standing_and_who_stopped_off_the_goal() -> None:
    runs = [
        RunRecord(world="a", task="park", outcome="timeout", time_s=60.0, index=0,
                  extra={"standing_s": {"yielding": 30.0, "looking": 3.0},
                         "arrived_wrong": True}).to_json(),
        RunRecord(world="b", task="goto", outcome="success", time_s=40.0, index=1,
                  extra={"standing_s": {"looking": 1.0, "unknown_ahead": 5.0},
                         "arrived_wrong": False}).to_json(),
        RunRecord(world="c", task="goto", outcome="error", error="x", index=2).to_json(),
    ]  # fmt: skip
    s = summarise(runs)
    assert s["stopped_off_goal"] == 1
    share = s["standing_share"]
    assert list(share) == ["yielding", "unknown_ahead", "looking"]  # largest first
    assert share["yielding"] == pytest.approx(0.3) and share["looking"] == pytest.approx(0.04)
    assert s["by_task"]["goto"]["standing_share"] == pytest.approx(
        {"unknown_ahead": 0.125, "looking": 0.025}
    )
    assert summarise(runs[2:])["standing_share"] is None


def test_paired_score_differences_have_the_t_interval(serial: dict[str, Any]) -> None:
    other = json.loads(json.dumps(serial))
    other["policy"] = "forward"
    shift = [0.1, 0.0, 0.3, -0.1, 0.2, 0.0, 0.1, 0.1, 0.0, 0.2]
    for r, step in zip(other["runs"], shift, strict=True):
        if r["score"] is not None:
            r["score"] += step
    diff = paired_score_difference(serial, other)
    assert diff is not None
    d = np.array([s for s, r in zip(shift, serial["runs"], strict=True) if r["score"] is not None])
    assert diff["pairs"] == 9 and diff["differences"] == pytest.approx(d)
    half = stats.t.ppf(0.975, d.size - 1) * d.std(ddof=1) / math.sqrt(d.size)
    assert diff["mean"] == pytest.approx(d.mean())
    assert diff["ci95"] == pytest.approx([d.mean() - half, d.mean() + half])
    other["seed"] = 4
    assert paired_score_difference(serial, other) is None


def test_merged_documents_keep_their_json_types(serial: dict[str, Any]) -> None:
    merged = merge_documents([("only.json", serial)])
    assert comparable_doc(merged) == comparable_doc(serial)


# --------------------------------------------------------------------------------- plots
def test_plots_are_written(serial: dict[str, Any], tmp_path: Path) -> None:
    paths = evaluation_plots(serial, tmp_path / "one")
    names = sorted(p.name for p in paths)
    assert names == ["clearance.png", "failures_1.png", "success_score.png"]
    other = json.loads(json.dumps(serial))
    other["policy"] = "forward"
    for r in other["runs"]:
        if r["score"] is not None:
            r["score"] *= 1.5
    paths += comparison_plots([("sweep", serial), ("forward", other)], tmp_path / "two")
    assert sorted(p.name for p in paths[3:]) == ["paired_score.png", "policies.png"]
    for path in paths:
        data = path.read_bytes()
        assert data.startswith(PNG) and len(data) > 5000, path


def test_plot_command_prints_the_comparison(
    serial: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(serial))
    b.write_text(json.dumps({**serial, "seed": 9}))
    assert main(["evaluate", "plot", str(a), str(b), "--plots", str(tmp_path / "p")]) == 0
    out = capsys.readouterr().out
    assert "not paired (another seed or run list)" in out
    assert (tmp_path / "p" / "policies.png").read_bytes().startswith(PNG)
    assert not (tmp_path / "p" / "paired_score.png").exists()


def test_without_wall_clock_drops_every_wall_clock_field() -> None:
    doc = {
        "timing": {"wall_s": 3.0},
        "runs": [{"world": "w", "wall_s": 1.0, "extra": {"loop_wall_s": 0.9, "kept": 1}}],
        "summary": {
            "realtime_factor_per_core": 20.0,
            "by_task": {"goto": {"realtime_factor_per_core": 19.0, "runs": 1}},
        },
    }
    assert without_wall_clock(doc) == {
        "runs": [{"world": "w", "extra": {"kept": 1}}],
        "summary": {"by_task": {"goto": {"runs": 1}}},
    }
    assert doc["runs"][0]["extra"]["loop_wall_s"] == 0.9  # a copy: the input is untouched


@pytest.mark.parametrize(
    ("field", "value"),
    [("outcome", "crash"), ("collision_by", "wall"), ("collision_with", "wall")],
)
def test_a_record_with_an_unknown_outcome_or_collider_is_refused(field: str, value: str) -> None:
    kwargs: dict[str, Any] = {"world": "w", "task": "goto", "outcome": "collision", field: value}
    with pytest.raises(ValueError, match=f"RunRecord.{field} must be"):
        RunRecord(**kwargs)
