"""Observables derived from sensor data: lobe metrics for reports (NumPy). The fits' differentiable
observables (lobe level, wavefront phase) are in `fit/model.py`."""

from __future__ import annotations

import numpy as np


def lobe_metrics(angles_deg, level_db) -> dict[str, float | None]:
    """Metrics of a lobe pattern in dB re its maximum, on the side of positive angles from the
    peak: -3 dB and -6 dB full widths (deg), first null angle (deg from the peak, the first local
    minimum), first side-lobe level (dB) and its angle."""
    a = np.asarray(angles_deg, float)
    lv = np.asarray(level_db, float)
    lv = lv - lv.max()
    i0 = int(np.argmax(lv))
    out: dict[str, float | None] = {"peak_angle_deg": float(a[i0])}

    def width(th):
        def side(direction):
            i = i0
            while 0 <= i + direction < len(a) and lv[i + direction] > th:
                i += direction
            j = i + direction
            if not (0 <= j < len(a)):
                return None
            # linear interpolation of the crossing
            f = (lv[i] - th) / (lv[i] - lv[j])
            return a[i] + f * (a[j] - a[i])

        lo, hi = side(-1), side(+1)
        return None if lo is None or hi is None else float(hi - lo)

    out["width_3db_deg"] = width(-3.0)
    out["width_6db_deg"] = width(-6.0)
    # first null on the positive side: first local minimum after the peak
    i = i0
    while i + 1 < len(a) and lv[i + 1] <= lv[i]:
        i += 1
    if i + 1 < len(a):
        out["first_null_deg"] = float(a[i] - a[i0])
        out["first_null_level_db"] = float(lv[i])
        j = i
        while j + 1 < len(a) and lv[j + 1] >= lv[j]:
            j += 1
        out["first_sidelobe_db"] = float(lv[j]) if j + 1 < len(a) or j > i else None
        out["first_sidelobe_deg"] = float(a[j] - a[i0])
    else:
        out["first_null_deg"] = None
        out["first_sidelobe_db"] = None
    return out
