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

import functools
import json
from pathlib import Path

from make_samples import META, RIG, capture_sample, truth_table  # the shared pieces (same folder)

from difflattice.capture.groundtruth import Piston
from difflattice.capture.host import capture_lobe, capture_wave

HERE = Path(__file__).resolve().parent / "piston_disc"
TRUTH = {"kind": "piston", "diameter_m": 0.0384, "sensitivity_uV": 50_000.0}
FREQ_HZ = 50_000
DISC_META = META | {
    "operator": "make_disc_samples.py",
    "note": "EMULATED data from the difflattice rig emulator (Rayleigh-integral piston), not a measurement",
}
LOBE = dict(start_deg=-90.0, stop_deg=90.0, step_deg=1.0, n_avg=8, cycles=16, freq_hz=FREQ_HZ)
WAVE = dict(x0_m=-0.024, x1_m=0.024, dx_m=0.001, z_m=0.0165, n_avg=8, cycles=16, freq_hz=FREQ_HZ)


def write_truth() -> None:
    """The noise-free ground truth at 21 degC as a transducer table: the lobe at the rig's range
    (referred to 1 m: the pressure at 1 m times 1 m) and the wavefront at z = 16.5 mm."""
    piston = Piston(TRUTH["diameter_m"], TRUTH["sensitivity_uV"])
    path = truth_table(piston, freq_hz=FREQ_HZ, z_m=WAVE["z_m"], lobe_at_range=True).save(HERE / "truth.json")
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
    sample = functools.partial(capture_sample, transducer=TRUTH, meta=DISC_META)
    sample(HERE / "lobe.csv", capture_lobe, LOBE, seed=11)
    sample(HERE / "wave.csv", capture_wave, WAVE, seed=12)
    write_truth()


if __name__ == "__main__":
    main()
