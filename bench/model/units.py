"""Unit constants. Internal quantities are SI; multiply to convert *to* SI.

`x_rad = x_deg * DEG`, `x_deg = x_rad / DEG`.
"""

import math

DEG = math.pi / 180.0
ARCSEC = DEG / 3600.0
HOUR = 3600.0
DEG_PER_HOUR = DEG / HOUR  # rad/s
G0 = 9.80665  # standard gravity, m/s^2: the unit "g" in results and reports
MICRO_G = 1e-6 * G0


def format_hms(seconds: float) -> str:
    """A duration as h:mm:ss, rounded to the second (a negative one as 0:00:00); one that is
    not a finite number (an estimate that overflowed, NaN) as ?:??:??."""
    try:
        total = max(0, int(round(seconds)))
    except (OverflowError, ValueError):  # round(inf), round(nan)
        return "0:00:00" if seconds < 0 else "?:??:??"
    return f"{total // 3600}:{total // 60 % 60:02d}:{total % 60:02d}"
