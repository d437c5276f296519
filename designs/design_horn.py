"""Optimise a horn for a target -6 dB beam width at 1 m, starting from the paper's Fig. 9 cone
(5 degrees, 125 mm, 3 mm walls) on the Polaroid-like 35.7 mm line. One command:

    .venv/bin/python designs/design_horn.py --out out/design/horn [--cells-per-wavelength 8] [--target-deg 8] [--steps 15]

(the same as `difflattice design horn`). Free: mouth width, length and flare (throat and wall
thickness stay at the paper's); limits: mouth <= 90 mm, length 40-160 mm, |flare| <= 4. Writes
report.json/.md, PNGs and the start and optimised designs as scene files.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from difflattice.design.presets import design_horn, one_line  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("out/design/horn"))
    ap.add_argument("--cells-per-wavelength", type=float, default=8.0)
    ap.add_argument("--target-deg", type=float, default=8.0, help="target -6 dB full beam width at 1 m, deg")
    ap.add_argument(
        "--wall", default="soft", help="soft (the paper's speed-zero walls, default), rigid or a fluid material name"
    )
    ap.add_argument("--steps", type=int, default=15)
    ap.add_argument("--no-gradient-check", action="store_true")
    a = ap.parse_args(argv)
    s = design_horn(
        a.out,
        cells_per_wavelength=a.cells_per_wavelength,
        target_deg=a.target_deg,
        wall=a.wall,
        steps=a.steps,
        check_gradients=not a.no_gradient_check,
    )
    print(f"{one_line(s)}; wrote {a.out}/report.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
