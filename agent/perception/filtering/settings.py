"""The filter's gates and thresholds."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class FilterSettings:
    """The filter's gates.

    min_snr : signal over noise current, I_s/I_n (20: σ of position ≤ 5 % of the detector).
    depth_of_field_m : accepted beam ranges.
    gate_chi2 : innovation gate, χ² with 1 dof (16: 4σ, a false break in 16,000 samples).
    window : samples on each side used to predict a sample.
    max_incidence_deg : steepest surface accepted; range may change per sample by at most
        ``r·Δθ·tan(max_incidence)``.
    intensity_ratio_gate : largest change of range-corrected intensity between neighbours
        on one surface.
    max_gap : dropped samples a surface may span without a break.
    min_run : shortest run of samples accepted as a surface.
    """

    min_snr: float = 20.0
    depth_of_field_m: tuple[float, float] = (0.4, 2.5)
    gate_chi2: float = 16.0
    window: int = 4
    max_incidence_deg: float = 85.0
    intensity_ratio_gate: float = 1.3
    max_gap: int = 2
    min_run: int = 3
    sample_spacing_rad: float = math.radians(40.0) / 256
