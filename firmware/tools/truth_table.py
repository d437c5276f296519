"""Write the ground-truth table the firmware's host build (``rig-sim``) measures.

The table holds complex pressures [uV at the microphone's output] in the ``exp(-i omega t)``
convention of :mod:`difflattice.capture.groundtruth` (the received carrier is
``|p| cos(omega t - arg p)``, so ``arg p`` is the lag the rig reports) and arrival times:

- ``lobe``: at the lobe rig's microphone, ``range_m`` from the face's centre, per turntable angle
  (the Rayleigh integral at that range for a piston or disc, as the emulator's ground truth);
- ``wave``: on the line ``z = z_m`` per lateral offset ``x`` (Rayleigh integral; arrival time from
  the nearest point of the face).

Text format (``#`` starts a comment)::

    freq_hz 50000
    lobe <n>
    <angle_mdeg> <re_uV> <im_uV> <tof_ns>      (n rows, increasing angle)
    wave <z_um> <n>
    <x_um> <re_uV> <im_uV> <tof_ns>            (n rows, increasing x)

Run: ``python firmware/tools/truth_table.py truth.txt --diameter-mm 38.4 --freq-hz 50000``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from difflattice.capture.groundtruth import make_transducer, speed_of_sound


def write_truth(
    path: str | Path,
    transducer: dict[str, Any],
    *,
    freq_hz: float,
    temperature_c: float = 21.0,
    range_m: float = 1.0,
    z_m: float = 0.0165,
    lobe_step_deg: float = 0.5,
    wave_x_max_m: float = 0.030,
    wave_step_m: float = 0.00025,
) -> Path:
    """Tabulate ``transducer`` (a :func:`~difflattice.capture.groundtruth.make_transducer` spec)
    at ``freq_hz`` [Hz] and ``temperature_c`` [degC] into ``path``; returns the path."""
    tr = make_transducer(transducer)
    c = float(speed_of_sound(temperature_c))
    k = 2 * np.pi * freq_hz / c
    angles = np.round(np.arange(-90.0, 90.0 + lobe_step_deg / 2, lobe_step_deg), 9)
    at_range = getattr(tr, "at_range", None)
    if at_range is not None:
        lobe = at_range(angles, range_m, freq_hz, c)
    else:  # a table: its far field referred to 1 m, spread to the range
        lobe = tr.far_field(angles, freq_hz, c) * np.exp(1j * k * range_m) / range_m
    n_x = int(round(wave_x_max_m / wave_step_m))
    xs = np.arange(-n_x, n_x + 1) * wave_step_m
    near = tr.near_field(xs, z_m, freq_hz, c)
    tof = tr.arrival_s(xs, z_m, c)
    lines = [
        f"# difflattice rig-sim ground truth: {transducer}",
        f"# {temperature_c} degC (c = {c:.3f} m/s), lobe range {range_m} m; exp(-i w t): arg p is the lag",
        f"freq_hz {freq_hz:g}",
        f"lobe {len(angles)}",
    ]
    tof_lobe_ns = range_m / c * 1e9
    lines += [
        f"{round(a * 1000)} {p.real:.9g} {p.imag:.9g} {tof_lobe_ns:.3f}" for a, p in zip(angles, lobe, strict=True)
    ]
    lines.append(f"wave {round(z_m * 1e6)} {len(xs)}")
    lines += [
        f"{round(x * 1e6)} {p.real:.9g} {p.imag:.9g} {t * 1e9:.3f}" for x, p, t in zip(xs, near, tof, strict=True)
    ]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="table to write")
    parser.add_argument("--diameter-mm", type=float, default=38.4, help="circular piston diameter [mm]")
    parser.add_argument("--sensitivity-uV", type=float, default=50_000.0, help="on-axis amplitude at 1 m [uV]")
    parser.add_argument("--freq-hz", type=float, default=50_000.0, help="drive frequency [Hz]")
    parser.add_argument("--temperature-c", type=float, default=21.0, help="air temperature [degC]")
    parser.add_argument("--range-m", type=float, default=1.0, help="lobe rig range [m]")
    parser.add_argument("--z-mm", type=float, default=16.5, help="wavefront line distance from the face [mm]")
    a = parser.parse_args(argv)
    spec = {"kind": "piston", "diameter_m": a.diameter_mm / 1000, "sensitivity_uV": a.sensitivity_uV}
    write_truth(a.out, spec, freq_hz=a.freq_hz, temperature_c=a.temperature_c, range_m=a.range_m, z_m=a.z_mm / 1000)
    print(a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
