"""Regenerate the emulated sample captures in this folder (see README.md): EMULATED, not measured.

Run from the repository root: ``.venv/bin/python data/emulated/make_samples.py``. It starts the rig
emulator (its own process, on a pseudo-terminal) with a 38.4 mm piston as ground truth, captures
through the real host code, writes the noise-free ground truth as a table, and prints the scan
times. Noise is seeded, so the values repeat; the host times (t_unix_s, created_utc) do not.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

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
    "humidity_pct": 45.0,
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


def _fresh(name: str) -> Path:
    path = HERE / name
    for p in (path, path.with_suffix(".log")):
        p.unlink(missing_ok=True)
    return path


def _run(tmp: Path, name: str, capture, scan: dict, faults: dict | None = None, seed: int = 1) -> None:
    out = _fresh(name)
    with start_emulator(link_path=tmp / "rig", transducer=PISTON, rig=RIG, faults=faults, seed=seed) as rig:
        t0 = time.perf_counter()
        meta = META | ({"range_m": RIG["range_m"]} if capture is capture_lobe else {})
        capture(str(rig.path), out, **scan, metadata=meta)
        elapsed = time.perf_counter() - t0
    cap = load_capture(out)
    print(f"{name}: {len(cap.seq)} of {cap.metadata['n_points']} points in {elapsed:.2f} s, {len(cap.events)} events")


def write_truth() -> None:
    """The noise-free ground truth at the capture conditions (21 degC), as a transducer table."""
    piston = Piston(PISTON["diameter_m"], PISTON["sensitivity_uV"], lobe="fraunhofer")
    c = speed_of_sound(RIG["temperature_c"])
    angles = np.arange(-90.0, 90.5, 0.5)
    x = np.arange(-0.03, 0.03 + 1e-9, 0.00025)
    TableTransducer(
        lobe_angle_deg=angles,
        lobe=piston.far_field(angles, FREQ_HZ, c),
        near_z_m=0.0165,
        near_x_m=x,
        near=piston.near_field(x, 0.0165, FREQ_HZ, c),
        near_tof_s=piston.arrival_s(x, 0.0165, c),
        freq_hz=FREQ_HZ,
    ).save(HERE / "truth_piston38_40k.json")


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        _run(Path(tmp), "lobe_piston38_40k.csv", capture_lobe, LOBE)
        _run(Path(tmp), "wave_piston38_40k_z16.5mm.csv", capture_wave, WAVE, seed=2)
        _run(Path(tmp), "lobe_piston38_40k_faults.csv", capture_lobe, LOBE, faults=ALL_FAULTS)
    write_truth()


if __name__ == "__main__":
    main()
