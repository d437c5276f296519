"""Regenerate the emulated sample captures in this folder (see README.md): EMULATED, not measured.

Run from the repository root: ``.venv/bin/python data/emulated/make_samples.py``. It starts the rig
emulator (its own process, on a pseudo-terminal) with a 38.4 mm piston as ground truth, captures
through the real host code, writes the noise-free ground truth as a table, and prints the scan
times. Noise is seeded, so the values repeat; the host times (t_unix_s, created_utc) do not.
"""

from __future__ import annotations

import functools
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from difflattice.capture.emulator import start_emulator
from difflattice.capture.files import load_capture
from difflattice.capture.groundtruth import Piston, TableTransducer, speed_of_sound
from difflattice.capture.host import capture_lobe, capture_wave

HERE = Path(__file__).resolve().parent
# "fraunhofer": these files hold the far-field pattern spread as 1/range (the emulator's default is now
# the Rayleigh integral at the range itself: see make_disc_samples.py)
PISTON = {"kind": "piston", "diameter_m": 0.0384, "sensitivity_uV": 50_000.0, "lobe": "fraunhofer"}
RIG = {"rig_id": "EMU-0001", "range_m": 1.0, "temperature_c": 21.0, "drift_c_per_h": 0.5, "wobble_c": 0.05}
FREQ_HZ = 40_000
META = {
    "transducer_id": "EMULATED-piston-38.4mm",
    "microphone": "EMULATED-ideal",
    "temperature_c": 21.0,
    "humidity_pct": 0.0,  # the emulated rig's air is dry (its ground truth has no humidity)
    "pressure_hpa": 1013.25,
    "operator": "make_samples.py",
    "note": "EMULATED data from difflattice rig emulator, not a measurement",
}
LOBE = dict(start_deg=-90.0, stop_deg=90.0, step_deg=1.0, n_avg=8, cycles=16, freq_hz=FREQ_HZ)
WAVE = dict(x0_m=-0.03, x1_m=0.03, dx_m=0.0005, z_m=0.0165, n_avg=8, cycles=16, freq_hz=FREQ_HZ)
ALL_FAULTS = {
    "garbage": 0.03,
    "bad_crc": 0.03,
    "truncate": 0.03,
    "pause_at": [30],
    "pause_s": 4.0,
    "freeze_at": [60],
    "freeze_s": 4.0,
    "reset_at": [90],
    "unplug_at": [120],
    "unplug_s": 1.0,
}


TRUTH_ANGLES_DEG = np.arange(-90.0, 90.5, 0.5)
"""Angles of the ground-truth tables' lobe [deg]."""
TRUTH_X_M = np.arange(-0.03, 0.03 + 1e-9, 0.00025)
"""Lateral offsets of the ground-truth tables' wavefront [m]."""


def capture_sample(
    out: Path,
    capture: Callable[..., Path],
    scan: dict[str, Any],
    *,
    transducer: dict[str, Any],
    meta: dict[str, Any],
    seed: int,
    faults: dict[str, Any] | None = None,
) -> None:
    """Capture one scan into ``out`` (replacing it and its log) from a fresh emulator with
    ``transducer`` as ground truth on ``RIG``, and print how long it took."""
    for p in (out, out.with_suffix(".log")):
        p.unlink(missing_ok=True)
    with (
        tempfile.TemporaryDirectory() as tmp,
        start_emulator(link_path=Path(tmp) / "rig", transducer=transducer, rig=RIG, faults=faults, seed=seed) as rig,
    ):
        t0 = time.perf_counter()
        capture(
            str(rig.path), out, **scan, metadata=meta | ({"range_m": RIG["range_m"]} if capture is capture_lobe else {})
        )
        elapsed = time.perf_counter() - t0
    cap = load_capture(out)
    print(
        f"{out.name}: {len(cap.seq)} of {cap.metadata['n_points']} points in {elapsed:.2f} s, {len(cap.events)} events"
    )


def truth_table(tr: Piston, *, freq_hz: float, z_m: float, lobe_at_range: bool) -> TableTransducer:
    """The noise-free ground truth at the rig's temperature as a transducer table: the wavefront at
    ``z_m`` and the lobe, either the far-field pattern (``lobe_at_range`` False) or the field at
    the rig's range referred to 1 m (the pressure there times the range)."""
    c = float(speed_of_sound(RIG["temperature_c"]))
    angles, x, range_m = TRUTH_ANGLES_DEG, TRUTH_X_M, RIG["range_m"]
    lobe = tr.at_range(angles, range_m, freq_hz, c) * range_m if lobe_at_range else tr.far_field(angles, freq_hz, c)
    return TableTransducer(
        lobe_angle_deg=angles,
        lobe=lobe,
        near_z_m=z_m,
        near_x_m=x,
        near=tr.near_field(x, z_m, freq_hz, c),
        near_tof_s=tr.arrival_s(x, z_m, c),
        freq_hz=freq_hz,
    )


def main() -> None:
    sample = functools.partial(capture_sample, transducer=PISTON, meta=META)
    sample(HERE / "lobe_piston38_40k.csv", capture_lobe, LOBE, seed=1)
    sample(HERE / "wave_piston38_40k_z16.5mm.csv", capture_wave, WAVE, seed=2)
    sample(HERE / "lobe_piston38_40k_faults.csv", capture_lobe, LOBE, seed=1, faults=ALL_FAULTS)
    piston = Piston(PISTON["diameter_m"], PISTON["sensitivity_uV"], lobe="fraunhofer")
    table = truth_table(piston, freq_hz=FREQ_HZ, z_m=0.0165, lobe_at_range=False)
    table.save(HERE / "truth_piston38_40k.json")


if __name__ == "__main__":
    main()
