"""Every parameter of the sensor, head and detection chain, in one typed structure.

Defaults are the chapter's values (sections 6.5-6.7). Two instances matter:

* :func:`nominal_sensor` is the sensor *as drawn*: the triangulation gain constant is the
  product ``f·d`` of the design focal length and baseline, the baseline is constant over the
  scan and the lateral-effect photodiode (LEP) is perfectly linear. Processing code knows only
  these values plus a calibration.
* :func:`simulated_head` is the sensor *as built*, the one the simulator runs. It differs from
  the drawing the way the chapter's head did: the effective gain constant is the characterised
  ``fd = 0.0044 m²`` (section 6.7.2), the detector sits 40 µm from its drawn position, the
  baseline grows towards the scan edges (footnote 2 of section 6.2.2) and the LEP compresses
  positions near its ends. The calibration procedure exists to remove exactly these errors.

Angles are radians, lengths metres, currents amperes, unless a name says otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

# Physical constants for the theoretical noise density (eq. 6.17).
ELEMENTARY_CHARGE_C = 1.602176634e-19
BOLTZMANN_J_PER_K = 1.380649e-23


@dataclass(frozen=True)
class SensorParameters:
    """The synchronised-scanning LEP range sensor and its head.

    Geometry (section 6.5.3, eq. 6.5)
    ---------------------------------
    baseline_m
        Source-detector separation ``d`` (9.5 cm).
    focal_length_m
        Focal length ``f`` of the collecting lens (5 cm).
    detector_length_m
        Active length ``P`` of the LEP (1 cm).
    fd_m2
        Effective triangulation gain constant. Nominal ``f·d = 0.00475 m²``; the chapter's head
        characterised at 0.0044 m² (section 6.7.2).
    detector_centre_m
        Image position ``p`` of the LEP's centre, measured from the optical axis. The detector is
        offset so the 0.4-2.5 m depth of field falls on its length at every scan angle: with
        the characterised ``fd`` that needs a centre between 6.38 and 6.65 mm; 6.5 mm is drawn.
    baseline_edge_growth
        Fractional growth of the baseline at the ±20° scan edges, quadratic in scan angle:
        ``d(θ) = d·(1 + g·(θ/θ_max)²)``. Zero on the drawing.
    lep_edge_compression
        LEP position non-linearity ``β``: a spot at normalised position ``u`` reads as
        ``u − β·u⁵``. Zero on the drawing.

    Signal and noise (section 6.6, eq. 6.10-6.18)
    ---------------------------------------------
    signal_constant_Am2
        ``S`` for off-white cardboard (reflectivity 1.0), eq. 6.12.
    noise_current_A
        ``I_n``, the noise current over the measurement bandwidth, eq. 6.15 (36.5 pA). It is
        the noise of the electrodes' *difference* current, so ``σ(p_norm) = I_n / I_s``.
    common_mode_noise_ratio
        Noise of the electrodes' *sum* current, as a fraction of ``I_n``. The largest term of
        eq. 6.17, thermal noise of the inter-electrode resistance, circulates between the
        electrodes and so is purely differential; dark-current shot noise and preamplifier
        noise reach both. 0.25 keeps ``σ(p_norm)`` within 3 % of ``I_n/I_s`` at the detector's
        ends while giving noise-only samples a noisy (not exactly zero) intensity.
    dark_current_A, shunt_resistance_ohm, temperature_K, preamp_noise_density_A_per_rtHz
        Component values for the theoretical noise density (eq. 6.17, 6.18).

    Detection (section 6.5.2)
    -------------------------
    bandwidth_hz, filter_order
        Fourth-order Bessel low-pass, 3 dB at 1 kHz: the measurement bandwidth.
    oversampling
        Simulation steps per output sample. The continuous signal is simulated at
        ``oversampling × sample rate`` (20.48 kHz, twenty times the bandwidth), filtered, then
        sampled. Not a property of the sensor: a simulation fidelity setting.
    laser_power_W, laser_wavelength_m, modulation_hz
        0.9 mW at 670 nm, square-wave modulated at 10 kHz (informational; the simulation works
        at base band after synchronous detection).
    spot_diameter_m, spot_divergence_rad
        Laser footprint: diameter ``w0 + divergence·range``. The spot's finite size blends two
        surfaces at a range discontinuity (mixed points). Not given in the chapter; 2 mm and
        1 mrad are typical of a collimated laser diode.

    Scanning (section 6.5.3, 6.8.2)
    -------------------------------
    scan_half_angle_rad
        The mirror scans any window within ±20°.
    samples_per_sweep, sweep_period_s
        256 samples over a full 40° sweep in 100 ms: 2.56 kHz, constant angular rate.
    scan_angle_repeatability_rad
        Mirror angle repeatability (0.1 mrad, section 6.6).
    pan_limit_rad, pan_rate_limit_rad_s, pan_acceleration_limit_rad_s2
        The head pans the whole sensor within ±90°. Slew limits are not given in the chapter;
        the defaults are those of a small geared head.
    mount_offset_m
        The centre of scanning sits this far ahead of the vehicle's base origin (REP-103 x);
        pan rotates about it.
    depth_of_field_m
        Rated range interval (0.4 m, 2.5 m), used by validation gates.
    """

    baseline_m: float = 0.095
    focal_length_m: float = 0.05
    detector_length_m: float = 0.01
    fd_m2: float = 0.00475
    detector_centre_m: float = 0.0065
    baseline_edge_growth: float = 0.0
    lep_edge_compression: float = 0.0

    signal_constant_Am2: float = 2.59e-8
    noise_current_A: float = 36.5e-12
    common_mode_noise_ratio: float = 0.25
    dark_current_A: float = 100e-9
    shunt_resistance_ohm: float = 50e3
    temperature_K: float = 298.0
    preamp_noise_density_A_per_rtHz: float = 0.2e-12

    bandwidth_hz: float = 1000.0
    filter_order: int = 4
    oversampling: int = 8
    laser_power_W: float = 0.9e-3
    laser_wavelength_m: float = 670e-9
    modulation_hz: float = 10e3
    spot_diameter_m: float = 2e-3
    spot_divergence_rad: float = 1e-3

    scan_half_angle_rad: float = math.radians(20.0)
    samples_per_sweep: int = 256
    sweep_period_s: float = 0.1
    scan_angle_repeatability_rad: float = 1e-4
    pan_limit_rad: float = math.radians(90.0)
    pan_rate_limit_rad_s: float = math.radians(180.0)
    pan_acceleration_limit_rad_s2: float = math.radians(720.0)
    mount_offset_m: float = 0.30
    depth_of_field_m: tuple[float, float] = (0.4, 2.5)

    def __post_init__(self) -> None:
        positive = (
            "baseline_m", "focal_length_m", "detector_length_m", "fd_m2", "detector_centre_m",
            "signal_constant_Am2", "noise_current_A", "bandwidth_hz", "sweep_period_s",
            "scan_half_angle_rad", "pan_limit_rad", "pan_rate_limit_rad_s",
            "pan_acceleration_limit_rad_s2", "temperature_K", "shunt_resistance_ohm",
        )  # fmt: skip
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"sensor parameter {name} must be a positive number, got {value}")
        for name in (
            "baseline_edge_growth",
            "lep_edge_compression",
            "common_mode_noise_ratio",
            "spot_diameter_m",
            "spot_divergence_rad",
            "scan_angle_repeatability_rad",
            "dark_current_A",
            "preamp_noise_density_A_per_rtHz",
            "mount_offset_m",
        ):
            value = getattr(self, name)
            if not math.isfinite(value) or (name != "mount_offset_m" and value < 0):
                raise ValueError(f"sensor parameter {name} must be finite and >= 0, got {value}")
        if self.filter_order < 1 or self.oversampling < 2 or self.samples_per_sweep < 2:
            raise ValueError("filter_order >= 1, oversampling >= 2 and samples_per_sweep >= 2")
        if self.bandwidth_hz >= self.sample_rate_hz * self.oversampling / 2:
            raise ValueError("bandwidth_hz must lie below the simulation's Nyquist frequency")
        near, far = self.depth_of_field_m
        if not 0 < near < far:
            raise ValueError(
                f"depth_of_field_m must be (near, far) with 0 < near < far, got "
                f"{self.depth_of_field_m}"
            )
        if self.scan_half_angle_rad >= math.pi / 4:
            raise ValueError("scan_half_angle_rad must be below 45 degrees")

    # ----------------------------------------------------------------------------- derived
    @property
    def sample_rate_hz(self) -> float:
        """Output sample rate: 256 samples per 100 ms sweep = 2.56 kHz."""
        return self.samples_per_sweep / self.sweep_period_s

    @property
    def scan_rate_rad_s(self) -> float:
        """Mirror angular rate: 40° per 100 ms, both directions."""
        return 2.0 * self.scan_half_angle_rad / self.sweep_period_s

    @property
    def sample_spacing_rad(self) -> float:
        """Scan angle between consecutive samples (0.156°)."""
        return self.scan_rate_rad_s / self.sample_rate_hz

    @property
    def noise_density_A_per_rtHz(self) -> float:
        """``I_n`` over the square root of the bandwidth, assuming an ideal filter (eq. 6.16)."""
        return self.noise_current_A / math.sqrt(self.bandwidth_hz)

    @property
    def triangulation_constant_T_per_m3(self) -> float:
        """``T = P·I_n / (2·fd·S)`` (eq. 6.20): on-axis range σ is ``T·z⁴``."""
        return (
            self.detector_length_m
            * self.noise_current_A
            / (2.0 * self.fd_m2 * self.signal_constant_Am2)
        )

    def baseline_at(self, scan_angle_rad: float) -> float:
        """Baseline ``d(θ)`` at one scan angle (see ``baseline_edge_growth``)."""
        ratio = scan_angle_rad / self.scan_half_angle_rad
        return self.baseline_m * (1.0 + self.baseline_edge_growth * ratio * ratio)

    def with_changes(self, **changes: object) -> SensorParameters:
        """A copy with some fields replaced (validated like the original)."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise ValueError(f"unknown sensor parameter(s): {', '.join(unknown)}")
        return replace(self, **changes)  # type: ignore[arg-type]


def theoretical_noise_density(params: SensorParameters) -> float:
    """Detector-plus-preamplifier current noise density, A/√Hz (eq. 6.17, 6.18).

    Shot noise of the dark current and thermal noise of the inter-electrode resistance,
    ``√(2·e·I_d + 4·k·T/R_s)`` (0.60 pA/√Hz), summed in quadrature with the preamplifier's
    0.2 pA/√Hz: 0.632 pA/√Hz for the chapter's components.
    """
    detector_sq = (
        2.0 * ELEMENTARY_CHARGE_C * params.dark_current_A
        + 4.0 * BOLTZMANN_J_PER_K * params.temperature_K / params.shunt_resistance_ohm
    )
    return math.sqrt(detector_sq + params.preamp_noise_density_A_per_rtHz**2)


def nominal_sensor() -> SensorParameters:
    """The sensor as drawn: ``fd = f·d``, constant baseline, linear LEP."""
    base = SensorParameters()
    return base.with_changes(fd_m2=base.focal_length_m * base.baseline_m)


def simulated_head() -> SensorParameters:
    """The sensor as built: what the simulator runs, and what calibration must discover.

    The effective ``fd`` is the chapter's characterised 0.0044 m² (7 % below ``f·d``); the
    detector sits 40 µm further from the axis than drawn; the baseline is 1 % longer at the
    scan edges; the LEP compresses positions by ``0.5 %·u⁵`` towards its ends.
    """
    return SensorParameters(
        fd_m2=0.0044,
        detector_centre_m=0.0065 + 40e-6,
        baseline_edge_growth=0.01,
        lep_edge_compression=0.005,
    )
