"""Regenerate the emulated circular-transducer captures in ``piston_disc/`` (EMULATED, not measured).

Run from the repository root: ``.venv/bin/python data/emulated/make_disc_samples.py``. It starts the
rig emulator (its own process, on a pseudo-terminal) with a 38.4 mm baffled piston as the ground
truth, whose lobe is the Rayleigh integral at the rig's 1 m range (a real near field, not a
far-field pattern), captures a lobe and a wavefront scan through the real host code at 50 kHz, and
writes the noise-free ground truth as a transducer table (``truth.json``, with the transducer's
parameters under ``"ground_truth"``). Noise is seeded, so the values repeat; host times do not.
Fit them with ``difflattice fit fitting/piston_disc.toml``.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from difflattice.capture.emulator import start_emulator
from difflattice.capture.files import load_capture
from difflattice.capture.groundtruth import TableTransducer, make_transducer, speed_of_sound
from difflattice.capture.host import capture_lobe, capture_wave

HERE = Path(__file__).resolve().parent / "piston_disc"
TRUTH = {"kind": "piston", "diameter_m": 0.0384, "sensitivity_uV": 50_000.0}
RIG = {"rig_id": "EMU-0001", "range_m": 1.0, "temperature_c": 21.0, "drift_c_per_h": 0.5, "wobble_c": 0.05}
FREQ_HZ = 50_000
META = {
    "transducer_id": "EMULATED-piston-38.4mm",
    "microphone": "EMULATED-ideal",
    "temperature_c": 21.0,
    "humidity_pct": 45.0,
    "pressure_hpa": 1013.25,
    "operator": "make_disc_samples.py",
    "note": "EMULATED data from the difflattice rig emulator (Rayleigh-integral piston), not a measurement",
}
LOBE = dict(start_deg=-90.0, stop_deg=90.0, step_deg=1.0, n_avg=8, cycles=16, freq_hz=FREQ_HZ)
WAVE = dict(x0_m=-0.024, x1_m=0.024, dx_m=0.001, z_m=0.0165, n_avg=8, cycles=16, freq_hz=FREQ_HZ)


def _capture(tmp: Path, name: str, capture, scan: dict, seed: int) -> None:
    out = HERE / name
    for p in (out, out.with_suffix(".log")):
        p.unlink(missing_ok=True)
    with start_emulator(link_path=tmp / "rig", transducer=TRUTH, rig=RIG, seed=seed) as rig:
        t0 = time.perf_counter()
        meta = META | ({"range_m": RIG["range_m"]} if capture is capture_lobe else {})
        capture(str(rig.path), out, **scan, metadata=meta)
        elapsed = time.perf_counter() - t0
    cap = load_capture(out)
    print(f"{name}: {len(cap.seq)} of {cap.metadata['n_points']} points in {elapsed:.2f} s")


def write_truth() -> None:
    """The noise-free ground truth at 21 degC as a transducer table: the lobe at the rig's range
    (referred to 1 m: the pressure at 1 m times 1 m) and the wavefront at z = 16.5 mm."""
    tr = make_transducer(TRUTH)
    c = speed_of_sound(RIG["temperature_c"])
    angles = np.arange(-90.0, 90.5, 0.5)
    x = np.arange(-0.03, 0.03 + 1e-9, 0.00025)
    table = TableTransducer(
        lobe_angle_deg=angles,
        lobe=tr.at_range(angles, RIG["range_m"], FREQ_HZ, c) * RIG["range_m"],
        near_z_m=WAVE["z_m"],
        near_x_m=x,
        near=tr.near_field(x, WAVE["z_m"], FREQ_HZ, c),
        near_tof_s=tr.arrival_s(x, WAVE["z_m"], c),
        freq_hz=FREQ_HZ,
    )
    path = table.save(HERE / "truth.json")
    doc = json.loads(path.read_text())
    doc["ground_truth"] = {
        **TRUTH,
        "range_m": RIG["range_m"],
        "temperature_c": RIG["temperature_c"],
        "note": "lobe: Rayleigh integral at range_m (referred to 1 m); near: Rayleigh integral",
    }
    path.write_text(json.dumps(doc, indent=1))


def main() -> None:
    HERE.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        _capture(Path(tmp), "lobe.csv", capture_lobe, LOBE, seed=11)
        _capture(Path(tmp), "wave.csv", capture_wave, WAVE, seed=12)
    write_truth()


if __name__ == "__main__":
    main()
