"""Optimise a parabolic reflector for on-axis gain at 1 m (re the bare transducer), starting from
the paper's Fig. 10 mirror (focal length 50 mm, aperture 190 mm, 3 mm wall) with the Polaroid-like
35.7 mm line at the focus. One command:

    .venv/bin/python designs/design_reflector.py --out out/design/reflector [--cells-per-wavelength 8] [--steps 15]

(the same as `difflattice design reflector`). Free: focal length (25-80 mm) and aperture
(100-220 mm); the wall stays 3 mm. Writes report.json/.md, PNGs and the start and optimised
designs as scene files.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from difflattice.design.presets import design_reflector, one_line  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("out/design/reflector"))
    ap.add_argument("--cells-per-wavelength", type=float, default=8.0)
    ap.add_argument(
        "--wall", default="soft", help="soft (the paper's speed-zero walls, default), rigid or a fluid material name"
    )
    ap.add_argument("--steps", type=int, default=15)
    ap.add_argument("--no-gradient-check", action="store_true")
    a = ap.parse_args(argv)
    s = design_reflector(
        a.out,
        cells_per_wavelength=a.cells_per_wavelength,
        wall=a.wall,
        steps=a.steps,
        check_gradients=not a.no_gradient_check,
    )
    print(f"{one_line(s)}; wrote {a.out}/report.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
