"""Figures written to PNG files: the chapter's figs. 6.7-6.13 from simulated data."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.patches import Circle

from agent.arrays import FloatArray
from agent.calibration.build import PlaneObservations
from agent.calibration.characterisation import CharacterisationResult, LogFit
from agent.perception.features import Feature
from agent.perception.filtering import SampleFlag
from agent.runtime.messages import CalibratedScan as CalibratedScanMessage, FilteredScan
from agent.sensor.samples import CalibratedScan

_DPI = 120


def _save(fig: plt.Figure, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=_DPI)
    plt.close(fig)
    return path


def _log_log_figure(
    ranges: np.ndarray,
    values: np.ndarray,
    fit: LogFit,
    scale: float,
    measured: str,
    fitted: str,
    ylabel: str,
    title: str,
    path: Path,
) -> Path:
    """Measured points and their least-squares line on log-log axes (figs. 6.8, 6.9)."""
    fig, ax = plt.subplots(figsize=(5.6, 4.2))
    ax.loglog(ranges, scale * values, "x", ms=8, label=measured)
    r = np.geomspace(ranges.min() * 0.9, ranges.max() * 1.1, 50)
    ax.plot(r, scale * 10 ** (fit.intercept + fit.slope * np.log10(r)), "-", label=fitted)
    ax.set_xlabel("range z (m)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(which="both", alpha=0.3)
    return _save(fig, path)


def calibration_curves(
    planes: Sequence[PlaneObservations],
    detector_centre_m: float,
    detector_length_m: float,
    path: Path,
) -> Path:
    """Fig. 6.7: image position against scan angle for planar targets at known ranges."""
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for obs in planes:
        ok = np.isfinite(obs.position_norm)
        order = np.argsort(obs.scan_angle_rad[ok])
        p_mm = 1e3 * (detector_centre_m + obs.position_norm[ok] * 0.5 * detector_length_m)
        ax.plot(
            np.degrees(obs.scan_angle_rad[ok][order]),
            p_mm[order],
            ".",
            ms=1.5,
            label=f"{obs.distance_m:.1f} m",
        )
    ax.set_xlabel("scan angle (deg)")
    ax.set_ylabel("image position p (mm)")
    ax.set_title("Calibration curves: image position against scan angle")
    ax.legend(title="planar target", fontsize=8, ncol=3, loc="lower center")
    ax.grid(alpha=0.3)
    return _save(fig, path)


def signal_vs_range(res: CharacterisationResult, path: Path) -> Path:
    """Fig. 6.8: log signal current against log range, with the least-squares line."""
    return _log_log_figure(
        res.ranges_m, res.mean_signal_A, res.signal_fit, 1e9, "measured (mean)",
        f"fit: slope {res.signal_fit.slope:.3f}, S = {res.fit_S_Am2:.3g} A·m²",
        "signal current I_s (nA)", "Signal current against range", path,
    )  # fmt: skip


def resolution_vs_range(res: CharacterisationResult, path: Path) -> Path:
    """Fig. 6.9: log image resolution (σ of normalised position) against log range."""
    return _log_log_figure(
        res.ranges_m, res.position_sd, res.position_fit, 1.0, "measured σ(p_norm)",
        f"fit: slope {res.position_fit.slope:.3f}, I_n = {1e12 * res.fit_I_n_A:.1f} pA",
        "image resolution Δp_norm", "Image resolution against range", path,
    )  # fmt: skip


def range_histogram(res: CharacterisationResult, path: Path) -> Path:
    """Fig. 6.10: distribution of range readings at 1 m with the equivalent Gaussian."""
    x = res.histogram_samples_m
    fig, ax = plt.subplots(figsize=(5.6, 4.2))
    mean, sd = float(np.mean(x)), float(np.std(x, ddof=1))
    counts, edges = np.histogram(x, bins=30)
    centres = 0.5 * (edges[1:] + edges[:-1])
    ax.plot(1e3 * (centres - res.histogram_range_m), counts, "x", label=f"{x.size} readings")
    grid = np.linspace(edges[0], edges[-1], 200)
    gauss = (
        x.size
        * (edges[1] - edges[0])
        / (sd * math.sqrt(2 * math.pi))
        * np.exp(-0.5 * ((grid - mean) / sd) ** 2)
    )
    ax.plot(
        1e3 * (grid - res.histogram_range_m),
        gauss,
        "-",
        label=f"Gaussian: mean {1e3 * (mean - 1):+.2f} mm, σ {1e3 * sd:.2f} mm",
    )
    ax.set_xlabel(f"range − {res.histogram_range_m:g} m (mm)")
    ax.set_ylabel("frequency")
    ax.set_title(f"Distribution of range readings at {res.histogram_range_m:g} m")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def sigma_vs_range(res: CharacterisationResult, path: Path) -> Path:
    """Fig. 6.11: predicted SD of range (measured and theoretical noise density) and actual."""
    fig, ax = plt.subplots(figsize=(5.6, 4.2))
    r = np.linspace(0.5, 2.6, 100)
    ax.plot(
        r,
        100 * res.predicted_sd_m(r, res.measured_density_A_per_rtHz),
        "-",
        label=f"predicted, measured density {1e12 * res.measured_density_A_per_rtHz:.2f} pA/√Hz",
    )
    ax.plot(
        r,
        100 * res.predicted_sd_m(r, res.theoretical_density_A_per_rtHz),
        "--",
        label=f"predicted, theoretical density "
        f"{1e12 * res.theoretical_density_A_per_rtHz:.3f} pA/√Hz",
    )
    ax.plot(res.ranges_m, 100 * res.range_sd_m, "x", ms=8, label="simulated measurements")
    table = res.table()
    ax.plot(
        [row["range_m"] for row in table],
        [row["paper_sd_cm"] for row in table],
        "o",
        mfc="none",
        label="chapter's Table 1",
    )
    ax.set_xlabel("range z (m)")
    ax.set_ylabel("SD of range (cm)")
    ax.set_title("Predicted and actual SD of range")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _save(fig, path)


@dataclass(frozen=True)
class TopDown:
    """What the top-down view of a scan draws: the filtered scan and its features.

    ``filtered`` and ``features`` are in the vehicle frame at the scan's reference time;
    ``to_world`` maps (k, 2) points of that frame to the world frame.
    """

    filtered: FilteredScan
    features: Sequence[Feature]
    to_world: Callable[[FloatArray], FloatArray]


# Sample colours by filter flag in the top-down view (no-reading samples have no point).
_FLAG_COLOURS = {
    SampleFlag.VALID: "tab:blue",
    SampleFlag.LOW_SNR: "tab:orange",
    SampleFlag.OUT_OF_RANGE: "tab:purple",
    SampleFlag.MIXED: "tab:red",
    SampleFlag.ISOLATED: "tab:olive",
}
_FEATURE_COLOUR = "black"
_CYLINDER_COLOUR = "tab:green"


def _top_down(ax: Axes, view: TopDown) -> None:
    """World-frame x-y view: points by flag, beam origin, and the features drawn over them."""
    f = view.filtered
    points = view.to_world(f.points_xy)
    origins = view.to_world(f.origin_xy)
    has_point = np.all(np.isfinite(points), axis=1)
    for flag, colour in _FLAG_COLOURS.items():
        sel = has_point & (f.flag == flag)
        if sel.any():
            ax.plot(*points[sel].T, ".", ms=2.5, color=colour, label=f"{flag.name.lower()}")
    ax.plot(*origins.T, "-", color="0.3", lw=2)  # moves only while driving
    ax.plot(*origins[-1], "*", ms=10, color="0.3", label="beam origin")
    seen: set[str] = set()
    # Keep the view on the scene (noise-only samples may read anywhere).
    extent = [points[has_point & (f.flag == SampleFlag.VALID)], origins]
    for feat in view.features:
        first = feat.kind not in seen
        seen.add(feat.kind)
        if feat.kind == "segment" and feat.endpoints is not None:
            ends = view.to_world(feat.endpoints)
            ax.plot(*ends.T, "-", lw=3.5, color=_FEATURE_COLOUR, alpha=0.6,
                    solid_capstyle="butt", label="segment" if first else None)  # fmt: skip
            extent.append(ends)
        elif feat.kind in ("corner", "edge") and feat.point is not None:
            pt = view.to_world(feat.point.reshape(1, 2))
            marker = "s" if feat.kind == "corner" else "^"
            ax.plot(*pt.T, marker, ms=9, mfc="none", mew=1.8, color=_FEATURE_COLOUR,
                    label=feat.kind if first else None)  # fmt: skip
            extent.append(pt)
        elif feat.kind == "cylinder" and feat.center is not None and feat.radius is not None:
            centre = view.to_world(feat.center.reshape(1, 2))[0]
            ax.add_patch(Circle((float(centre[0]), float(centre[1])), feat.radius, fill=False,
                                lw=2.5, color=_CYLINDER_COLOUR,
                                label="cylinder" if first else None))  # fmt: skip
            ax.plot(*centre, "+", ms=8, color=_CYLINDER_COLOUR)
            extent.append(centre + np.array([[-1.0, -1.0], [1.0, 1.0]]) * feat.radius)
    box = np.concatenate(extent)
    lo, hi = box.min(axis=0), box.max(axis=0)
    pad = 0.08 * float(max(hi - lo)) + 0.05
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("world x (m)")
    ax.set_ylabel("world y (m)")
    ax.set_title("top-down, world frame: samples by flag, features")
    ax.legend(fontsize=7, loc="best", markerscale=1.5)
    ax.grid(alpha=0.3)


def scan_images(
    scan: CalibratedScan | CalibratedScanMessage,
    truth_range_m: np.ndarray,
    title: str,
    path: Path,
    *,
    top_down: TopDown | None = None,
) -> Path:
    """Figs. 6.12-6.13: range image above intensity image, against scan angle.

    With ``top_down``, a world-frame x-y view of the filtered samples and the features
    sits to the right of the two images.
    """
    if top_down is None:
        fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(6.4, 5.6))
    else:
        fig = plt.figure(figsize=(12.8, 5.6))
        grid = fig.add_gridspec(2, 2, width_ratios=(1.0, 1.0))
        top = fig.add_subplot(grid[0, 0])
        bottom = fig.add_subplot(grid[1, 0], sharex=top)
        top.tick_params(labelbottom=False)
        _top_down(fig.add_subplot(grid[:, 1]), top_down)
    deg = np.degrees(scan.scan_angle_rad)
    top.plot(deg, truth_range_m, "-", color="0.75", lw=1, label="truth")
    # Noise-only samples (missing parts) read anywhere with σ of metres: show them as points
    # only, and keep the axis on the scene.
    sharp = scan.sigma_m < 0.1
    top.errorbar(
        deg[sharp],
        scan.range_m[sharp],
        yerr=scan.sigma_m[sharp],
        fmt=".",
        ms=3,
        lw=0.6,
        label="calibrated range ± σ",
    )
    top.plot(
        deg[~sharp],
        scan.range_m[~sharp],
        "x",
        ms=3,
        color="tab:red",
        label="σ > 0.1 m (noise only)",
    )
    finite = truth_range_m[np.isfinite(truth_range_m)]
    top.set_ylim(0.0, 1.25 * float(finite.max()) if finite.size else 3.0)
    top.set_ylabel("range (m)")
    top.set_title(title)
    top.legend(fontsize=8)
    top.grid(alpha=0.3)
    bottom.plot(deg, 1e9 * scan.intensity_A, ".-", ms=3, lw=0.6)
    bottom.set_ylabel("intensity I_s (nA)")
    bottom.set_xlabel("scan angle (deg)")
    bottom.grid(alpha=0.3)
    return _save(fig, path)


@dataclass
class EnvironmentSnapshot:
    """One environment vector drawn in the world frame: the centre of scanning, the free
    space around it (bearings in the world frame, distances), the confirmed obstacles."""

    t_s: float
    centre_xy: FloatArray
    bearing_rad: FloatArray
    free_m: FloatArray
    obstacle_xy: FloatArray  # (k, 2)
    obstacle_cov: FloatArray  # (k, 2, 2)
    obstacle_kind: FloatArray  # (k,)


def environment_over_run(
    segments: tuple[FloatArray, FloatArray],
    circles: tuple[FloatArray, FloatArray],
    true_xy: FloatArray,
    mover_tracks: list[FloatArray],
    snapshots: Sequence[EnvironmentSnapshot],
    path: Path,
    title: str,
) -> Path:
    """Top-down view of one run: the true world (grey), the movers' true paths (dotted), the
    vehicle's true path, and at a few instants the environment vector mapped into the world
    through the odometry's error at that instant: its free space (green) and its obstacles
    (each with its 3-sigma ellipse, coloured by time)."""
    fig, ax = plt.subplots(figsize=(7.2, 6.4))
    starts, ends = segments
    for a, b in zip(starts, ends, strict=True):
        ax.plot([a[0], b[0]], [a[1], b[1]], color="0.55", lw=1.5)
    for c, r in zip(*circles, strict=True):
        ax.add_patch(Circle((float(c[0]), float(c[1])), float(r), color="0.7"))
    for xy in mover_tracks:
        ax.plot(xy[:, 0], xy[:, 1], ":", color="tab:purple", lw=1)
    ax.plot(true_xy[:, 0], true_xy[:, 1], "-", color="k", lw=1, label="vehicle (true path)")
    colours = plt.cm.viridis(np.linspace(0.0, 0.9, max(1, len(snapshots))))
    for snap, colour in zip(snapshots, colours, strict=False):
        known = snap.free_m > 0
        if known.any():
            ends_xy = snap.centre_xy + snap.free_m[:, None] * np.stack(
                [np.cos(snap.bearing_rad), np.sin(snap.bearing_rad)], axis=1
            )
            for lo, hi in _runs(known):
                poly = np.vstack([snap.centre_xy, ends_xy[lo:hi], snap.centre_xy])
                ax.fill(poly[:, 0], poly[:, 1], color="tab:green", alpha=0.12, lw=0)
        for xy, cov in zip(snap.obstacle_xy, snap.obstacle_cov, strict=True):
            _ellipse(ax, xy, cov, colour)
            ax.plot(xy[0], xy[1], ".", color=colour, ms=4)
        ax.plot(*snap.centre_xy, "^", color=colour, ms=6)
    ax.plot([], [], color="tab:green", alpha=0.4, lw=6, label="free space claimed")
    ax.plot([], [], ".", color=colours[0], label="obstacles, 3σ (colour: time)")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m), world")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper right", fontsize=7)
    return _save(fig, path)


def _runs(mask: FloatArray) -> list[tuple[int, int]]:
    """[lo, hi) index ranges where ``mask`` is true."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _ellipse(ax: Axes, xy: FloatArray, cov: FloatArray, colour: object) -> None:
    values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
    values = np.sqrt(np.clip(values, 0.0, None)) * 3.0
    angle = np.linspace(0.0, 2.0 * math.pi, 40)
    pts = xy + (vectors @ (values[:, None] * np.stack([np.cos(angle), np.sin(angle)]))).T
    ax.plot(pts[:, 0], pts[:, 1], "-", color=colour, lw=0.8)
