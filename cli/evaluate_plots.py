"""``sensor-agent evaluate``'s figures, written to PNG files.

One evaluation (:func:`evaluation_plots`): outcome rates with their 95 % Wilson intervals and
the scores, per task kind; the clearance histogram by outcome; a gallery of the failed runs,
each world drawn top-down from the record's TOML text with the vehicle's true path.
Several (:func:`comparison_plots`): success and mean score by policy, and the paired score
differences between evaluations of the same seed and worlds.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only, no display

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.patches import Circle

from agent.errors import ConfigError
from cli.evaluate import OUTCOMES, paired_score_difference

__all__ = [
    "GALLERY_MAX",
    "clearance_histogram",
    "comparison_plots",
    "evaluation_plots",
    "failure_gallery",
    "paired_differences",
    "policy_comparison",
    "success_and_score",
]

_DPI = 120
GALLERY_MAX = 48  # failed runs drawn at most (the first, in run order)
_GALLERY_PAGE = (3, 4)  # rows, columns of one gallery page
_OUTCOME_COLOURS = {
    "success": "tab:green",
    "collision": "tab:red",
    "timeout": "tab:orange",
    "stale_stop": "tab:purple",
    "error": "0.4",
}
_RATES = ("success_rate", "collision_rate", "timeout_rate", "stale_stop_rate", "error_rate")


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=_DPI)
    plt.close(fig)
    return path


def _title(doc: Mapping[str, Any]) -> str:
    controller = doc.get("controller", "default")
    which = "" if controller == "default" else f", controller {controller}"
    return f"policy {doc['policy']}{which}, seed {doc['seed']}, {len(doc['runs'])} runs"


def _interval_bars(
    ax: Axes, x: np.ndarray, rates: Sequence[Mapping[str, Any]], width: float, **style: Any
) -> None:
    """Bars at the rates' values with their 95 % intervals as error bars (nulls left out)."""
    value = np.array([np.nan if r["value"] is None else r["value"] for r in rates])
    lo = np.array([np.nan if r["ci95"] is None else r["ci95"][0] for r in rates])
    hi = np.array([np.nan if r["ci95"] is None else r["ci95"][1] for r in rates])
    ax.bar(x, np.nan_to_num(value), width, **style)
    ok = np.isfinite(value)
    ax.errorbar(
        x[ok], value[ok], yerr=[value[ok] - lo[ok], hi[ok] - value[ok]], fmt="none",
        ecolor="k", capsize=3, lw=1,
    )  # fmt: skip


def success_and_score(doc: Mapping[str, Any], path: Path) -> Path:
    """Outcome rates with 95 % Wilson intervals per task kind (and over all), beside each
    kind's scores (points) and their mean (bar)."""
    s = doc["summary"]
    columns = [("all", s), *s["by_task"].items()]
    fig, (rates_ax, score_ax) = plt.subplots(1, 2, figsize=(11.0, 4.2))
    x = np.arange(len(columns), dtype=np.float64)
    width = 0.8 / len(_RATES)
    for j, key in enumerate(_RATES):
        outcome = key.removesuffix("_rate")
        _interval_bars(
            rates_ax, x + (j - (len(_RATES) - 1) / 2) * width, [c[key] for _, c in columns],
            width, color=_OUTCOME_COLOURS[outcome], label=outcome.replace("_", " "),
        )  # fmt: skip
    rates_ax.set_xticks(x, [f"{name}\n({c['runs']} runs)" for name, c in columns])
    rates_ax.set_ylim(0.0, 1.05)
    rates_ax.set_ylabel("fraction of runs (95 % Wilson interval)")
    rates_ax.set_title(f"Outcomes: {_title(doc)}", fontsize=9)
    rates_ax.legend(fontsize=7, ncol=3)
    rates_ax.grid(axis="y", alpha=0.3)
    rng = np.random.default_rng(0)  # jitter only
    for k, (name, c) in enumerate(columns):
        runs = [r for r in doc["runs"] if name == "all" or r["task"] == name]
        for outcome in OUTCOMES:
            scores = [
                r["score"] for r in runs if r["outcome"] == outcome and r["score"] is not None
            ]
            if scores:
                jitter = rng.uniform(-0.25, 0.25, len(scores))
                score_ax.plot(k + jitter, scores, ".", ms=4, color=_OUTCOME_COLOURS[outcome],
                              label=outcome.replace("_", " ") if k == 0 else None)  # fmt: skip
        if c["score_mean"] is not None:
            score_ax.plot([k - 0.35, k + 0.35], [c["score_mean"]] * 2, "-", color="k", lw=2,
                          label="mean" if k == 0 else None)  # fmt: skip
    score_ax.set_xticks(x, [name for name, _ in columns])
    score_ax.set_ylabel("score")
    score_ax.set_title("Scores by run, coloured by outcome", fontsize=9)
    score_ax.legend(fontsize=7)
    score_ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def clearance_histogram(doc: Mapping[str, Any], path: Path) -> Path:
    """The runs' minimum clearance, stacked by outcome."""
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    values = {
        o: [r["min_clearance_m"] for r in doc["runs"]
            if r["outcome"] == o and r["min_clearance_m"] is not None]
        for o in OUTCOMES
    }  # fmt: skip
    shown = [o for o in OUTCOMES if values[o]]
    every = [v for o in shown for v in values[o]]
    if every:
        bins = np.histogram_bin_edges(every, bins=min(30, max(5, len(every) // 3))).tolist()
        ax.hist([values[o] for o in shown], bins=bins, stacked=True,
                color=[_OUTCOME_COLOURS[o] for o in shown],
                label=[o.replace("_", " ") for o in shown])  # fmt: skip
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no clearance recorded", ha="center", va="center",
                transform=ax.transAxes)  # fmt: skip
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel("minimum clearance over the run (m)")
    ax.set_ylabel("runs")
    ax.set_title(f"Clearance: {_title(doc)}", fontsize=9)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def _draw_world(ax: Axes, run: Mapping[str, Any]) -> None:
    """One run top-down: its world (from ``world_toml``), start, goal, true path, end."""
    from agent.sim.world_file import parse_world
    from agent.toml_files import parse_toml

    def error(problem: str) -> ConfigError:
        return ConfigError(problem)

    doc = parse_toml(run["world_toml"], error)
    task = doc.pop("task", None)  # drawn here; parse_world need not know the table
    world = parse_world(doc)
    for a, b in zip(world.segments_start, world.segments_end, strict=True):
        ax.plot([a[0], b[0]], [a[1], b[1]], color="0.45", lw=1.2)
    for c, r in zip(world.circles_center, world.circles_radius, strict=True):
        ax.add_patch(Circle((float(c[0]), float(c[1])), float(r), color="0.65"))
    for m in world.movers:
        ax.plot(m.path[:, 0], m.path[:, 1], ":", color="tab:purple", lw=1)
        ax.add_patch(Circle((float(m.path[0, 0]), float(m.path[0, 1])), m.radius_m,
                            fill=False, color="tab:purple", lw=0.8))  # fmt: skip
    x, y, yaw = world.vehicle_pose
    ax.plot(x, y, marker=(3, 0, math.degrees(yaw) - 90.0), ms=9, color="tab:blue")
    if isinstance(task, Mapping) and "goal" in task:
        gx, gy = task["goal"]
        ax.plot(gx, gy, "*", ms=12, color="gold", mec="k", mew=0.6)
    if run.get("true_path"):
        xy = np.asarray(run["true_path"], dtype=np.float64).reshape(-1, 2)
        ax.plot(xy[:, 0], xy[:, 1], "-", color="k", lw=1)
    if run.get("final_pose") is not None:
        fx, fy, _ = run["final_pose"]
        ax.plot(fx, fy, "x", ms=8, mew=2, color=_OUTCOME_COLOURS.get(run["outcome"], "r"))
    ax.set_aspect("equal", adjustable="datalim")


def failure_gallery(doc: Mapping[str, Any], directory: Path) -> list[Path]:
    """The failed runs (the first :data:`GALLERY_MAX`), 12 to a page
    (``failures_1.png``, ...): each world top-down with its start (blue), goal (star), true
    path (black) and end (a cross in the outcome's colour). None when every run succeeded."""
    failed = [r for r in doc["runs"] if r["outcome"] != "success"][:GALLERY_MAX]
    rows, cols = _GALLERY_PAGE
    paths = []
    for page, start in enumerate(range(0, len(failed), rows * cols), 1):
        chunk = failed[start : start + rows * cols]
        fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 3.0 * rows), squeeze=False)
        for ax, run in itertools.zip_longest(axes.ravel(), chunk):
            if run is None:
                ax.set_axis_off()
                continue
            why = run["outcome"] + (f" by {run['collision_by']}" if run["collision_by"] else "")
            ax.set_title(f"run {run['index']}: {run['world']}\n{run['task']}, {why}", fontsize=7)
            ax.tick_params(labelsize=6)
            if not run.get("world_toml"):
                ax.text(0.5, 0.5, "no world text in the record", ha="center", va="center",
                        fontsize=7, transform=ax.transAxes)  # fmt: skip
                continue
            try:
                _draw_world(ax, run)
            except ConfigError as exc:
                ax.text(0.5, 0.5, f"world not drawable:\n{exc}", ha="center", va="center",
                        fontsize=6, wrap=True, transform=ax.transAxes)  # fmt: skip
        fig.suptitle(f"Failed runs: {_title(doc)}", fontsize=9)
        paths.append(_save(fig, directory / f"failures_{page}.png"))
    return paths


def evaluation_plots(doc: Mapping[str, Any], directory: Path) -> list[Path]:
    """Every figure of one evaluation, in ``directory``: ``success_score.png``,
    ``clearance.png``, ``failures_*.png``."""
    directory.mkdir(parents=True, exist_ok=True)
    return [
        success_and_score(doc, directory / "success_score.png"),
        clearance_histogram(doc, directory / "clearance.png"),
        *failure_gallery(doc, directory),
    ]


# ----------------------------------------------------------------------------- several
def _mean_interval(scores: Sequence[float]) -> tuple[float, float, float] | None:
    """Mean and its 95 % t interval (``scipy.stats.ttest_1samp``); None without two scores."""
    if len(scores) < 2:
        return None
    from scipy.stats import ttest_1samp

    ci = ttest_1samp(scores, 0.0).confidence_interval(0.95)
    mean = float(np.mean(scores))
    if not (math.isfinite(ci.low) and math.isfinite(ci.high)):
        return mean, mean, mean  # every score the same
    return mean, float(ci.low), float(ci.high)


def policy_comparison(labelled: Sequence[tuple[str, Mapping[str, Any]]], path: Path) -> Path:
    """Success rate (95 % Wilson interval) and mean score (95 % t interval) by evaluation."""
    fig, (success_ax, score_ax) = plt.subplots(1, 2, figsize=(10.0, 4.2))
    x = np.arange(len(labelled), dtype=np.float64)
    names = [label for label, _ in labelled]
    _interval_bars(success_ax, x, [d["summary"]["success_rate"] for _, d in labelled], 0.6,
                   color=_OUTCOME_COLOURS["success"])  # fmt: skip
    success_ax.set_xticks(x, names)
    success_ax.set_ylim(0.0, 1.05)
    success_ax.set_ylabel("success rate (95 % Wilson interval)")
    success_ax.set_title("Success by policy", fontsize=9)
    success_ax.grid(axis="y", alpha=0.3)
    for k, (_, doc) in enumerate(labelled):
        scores = [r["score"] for r in doc["runs"] if r.get("score") is not None]
        stats = _mean_interval(scores)
        if stats is not None:
            mean, lo, hi = stats
            score_ax.errorbar([k], [mean], yerr=[[mean - lo], [hi - mean]], fmt="o",
                              color="k", capsize=4)  # fmt: skip
        elif scores:
            score_ax.plot([k], [float(np.mean(scores))], "o", color="k")
    score_ax.set_xticks(x, names)
    score_ax.set_xlim(-0.5, len(labelled) - 0.5)
    score_ax.set_ylabel("mean score (95 % t interval)")
    score_ax.set_title("Score by policy", fontsize=9)
    score_ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def paired_differences(
    labelled: Sequence[tuple[str, Mapping[str, Any]]], path: Path
) -> Path | None:
    """Per pair of evaluations of the same seed and worlds: the per-run score differences
    (points) and their mean with its 95 % interval; None when no two are paired."""
    pairs = []
    for (la, a), (lb, b) in itertools.combinations(labelled, 2):
        diff = paired_score_difference(a, b)
        if diff is not None and diff["pairs"]:
            pairs.append((f"{lb}\n− {la}", diff))
    if not pairs:
        return None
    fig, ax = plt.subplots(figsize=(max(5.0, 1.8 * len(pairs) + 2.0), 4.2))
    rng = np.random.default_rng(0)  # jitter only
    for k, (_, diff) in enumerate(pairs):
        d = np.asarray(diff["differences"], dtype=np.float64)
        ax.plot(k + rng.uniform(-0.2, 0.2, d.size), d, ".", ms=4, color="tab:blue", alpha=0.6)
        if diff["ci95"] is not None:
            lo, hi = diff["ci95"]
            ax.errorbar([k + 0.3], [diff["mean"]], yerr=[[diff["mean"] - lo], [hi - diff["mean"]]],
                        fmt="s", color="k", capsize=4)  # fmt: skip
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlim(-0.5, len(pairs) - 0.3)
    ax.set_xticks(range(len(pairs)), [name for name, _ in pairs], fontsize=8)
    ax.set_ylabel("score difference per run (mean, 95 % interval)")
    ax.set_title("Paired score differences (same seed, same worlds)", fontsize=9)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def comparison_plots(
    labelled: Sequence[tuple[str, Mapping[str, Any]]], directory: Path
) -> list[Path]:
    """``policies.png`` and, when two evaluations share seed and worlds,
    ``paired_score.png``, in ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = [policy_comparison(labelled, directory / "policies.png")]
    paired = paired_differences(labelled, directory / "paired_score.png")
    if paired is not None:
        paths.append(paired)
    return paths
