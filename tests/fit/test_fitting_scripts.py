"""Scripts in fitting/ run (on coarse grids) and their conclusions hold."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _load(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "fitting" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_polaroid_lag_reading_quick():
    r = _load("polaroid_lag_reading").run(quick=True)["readings"]
    none = r["no lag"]
    whole = r["18 steps, quadratic over the whole aperture"]
    ends = r["18 steps on the end cells (outer 10 % each side)"]
    assert abs(none["peak_angle_deg"]) < 0.3
    assert abs(whole["peak_angle_deg"]) > 3  # the beam splits
    assert abs(ends["peak_angle_deg"]) < 0.3
    assert ends["wavefront_spread_us_within_10mm"] < none["wavefront_spread_us_within_10mm"]  # flatter
