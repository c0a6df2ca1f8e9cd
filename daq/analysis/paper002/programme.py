"""Paper 002: one cell's drum-speed programme (``cell_ramp``), the run the campaign records per (P, v0).

Why a sweep and not only the paper's hold: the paper records the pendulum's friction-induced
vibration at a constant drum speed v0 for each (P, v0). A hold alone visits only a band of v
(one point when the sliding is steady: below ~6.6 mm/s and above ~20 mm/s law (3) with D = 1.5
is velocity-strengthening), which cannot identify five parameters. So each cell is: lead-in
0 -> v0, hold at v0 (the paper's run), then a slow sweep of the drum speed v0 -> v_hi -> v_lo
(exponential, so time per decade of v is equal and the hump at a few mm/s is densely sampled)
-> v0. The fit uses every selected sample of the cell (docs/campaign.md).
"""

from __future__ import annotations

import math

from daq.errors import InputError
from daq.ramps import Ramp, Segment

# one cell's programme (times before --time-scale); see cell_ramp
LEAD_IN_S = 2.0
HOLD_S = 10.0
SWEEP_S = 30.0
BAND = (5e-4, 0.06)  # [m/s] the sweep's low and high drum speeds (v_hi at least 2 v0)


def cell_ramp(v0: float, *, hold_s: float = HOLD_S, sweep_s: float = SWEEP_S, band: tuple[float, float] = BAND,
              time_scale: float = 1.0, max_accel: float = 0.2, max_speed: float = 0.2) -> Ramp:
    """The drum-speed programme of one cell (P, v0): lead-in, hold at v0, sweep v0 -> v_hi -> v_lo -> v0.

    ``time_scale`` multiplies every duration (a compressed run), but no segment is made steeper
    than 3/4 of the drive's acceleration limit (the regulator then follows it). The sweep's
    share: 30 % up (linear), 55 % down (exponential towards 0, ending at v_lo: equal time per
    decade of v), 15 % back to v0.
    """
    lo, hi = float(band[0]), max(float(band[1]), 2.0 * v0)
    hi = min(hi, max_speed)
    if not (0 < lo < v0 <= hi):
        raise InputError("--speeds", "v0", f"{v0:g} m/s must lie inside the sweep band ({lo:g}, {hi:g}] m/s")
    a_max = 0.75 * max_accel

    def lin(dur: float, dv: float) -> float:
        return max(dur * time_scale, abs(dv) / a_max)

    down = 0.55 * sweep_s * time_scale
    tau = down / math.log(hi / lo)
    # an exponential from hi towards 0 starts steepest: hi / tau
    if hi / tau > a_max:
        tau = hi / a_max
        down = tau * math.log(hi / lo)
    segs = [Segment(kind="linear", duration_s=lin(LEAD_IN_S, v0), to_m_per_s=v0),
            Segment(kind="hold", duration_s=max(hold_s * time_scale, 1e-3)),
            Segment(kind="linear", duration_s=lin(0.30 * sweep_s, hi - v0), to_m_per_s=hi),
            Segment(kind="exponential", duration_s=down, to_m_per_s=0.0, tau_s=tau),
            Segment(kind="linear", duration_s=lin(0.15 * sweep_s, v0 - lo), to_m_per_s=v0),
            Segment(kind="linear", duration_s=lin(0.5, v0), to_m_per_s=0.0)]
    return Ramp(name=f"paper-002 cell v0={v0:g} m/s (hold {hold_s:g} s, sweep {lo:g}-{hi:g} m/s in {sweep_s:g} s, "
                     f"time scale {time_scale:g})", start_m_per_s=0.0, segment=segs)
