"""`difflattice design`: its options (a maker's constraints, band, resolution) and its handler.

Kept out of `cli.py` so that the command line stays small; the design library is imported only
when the job runs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_parser(sub) -> argparse.ArgumentParser:
    """Add the `design` subcommand to `sub` (an argparse subparsers object)."""
    z = sub.add_parser(
        "design", help="optimise a horn (target beam width) or a reflector (on-axis gain) from the paper's shapes"
    )
    z.add_argument(
        "what",
        choices=["horn", "reflector", "compare"],
        help="what to design; compare: a horn designed at the carrier beside one designed over the burst's band, "
        "both re-simulated with the burst",
    )
    z.add_argument(
        "--band",
        default=None,
        help="design over a band: 'burst' (the 5-cycle burst's -6 dB band, weighted by its spectrum) or "
        "frequencies in Hz, comma-separated; default: the carrier alone",
    )
    z.add_argument("--out", type=Path, required=True, help="report directory")
    z.add_argument("--cells-per-wavelength", type=float, default=8.0, help="lattice resolution of the design runs")
    z.add_argument(
        "--resolution",
        choices=["fixed", "auto"],
        default="fixed",
        help="auto: the coarsest resolution whose expected phase error is under the trust threshold "
        "(up to --max-cells-per-wavelength; the run says if even that is not enough)",
    )
    z.add_argument(
        "--max-cells-per-wavelength", type=float, default=24.0, help="with --resolution auto: the finest it may choose"
    )
    z.add_argument("--target-deg", type=float, default=8.0, help="horn: target -6 dB beam width at 1 m, deg")
    z.add_argument("--wall", default="soft", help="soft (the paper's speed-zero walls), rigid or a fluid material")
    z.add_argument("--steps", type=int, default=15, help="BFGS steps")
    z.add_argument("--no-gradient-check", action="store_true", help="skip the finite-difference check of the gradient")
    z.add_argument(
        "--lattice", choices=["2d", "rz"], default="2d", help="2d (a slot, extruded) or rz (a body of revolution)"
    )
    z.add_argument(
        "--max-length-mm",
        type=float,
        default=None,
        help="the part's largest extent along the axis, mm (default: horn 166, reflector 60)",
    )
    z.add_argument(
        "--max-mouth-mm",
        type=float,
        default=None,
        help="the part's largest outer mouth diameter, mm (default: horn 98, reflector 228)",
    )
    z.add_argument(
        "--min-wall-mm", type=float, default=None, help="the thinnest wall the printer makes, mm (default: 2)"
    )
    z.add_argument(
        "--can-diameter-mm",
        type=float,
        default=None,
        help="horn: the transducer's can; fixes the throat, mm (default: none, the throat is free)",
    )
    z.add_argument(
        "--can-clearance-mm",
        type=float,
        default=None,
        help="horn: clearance around the can either side, mm (default: 0)",
    )
    z.add_argument(
        "--max-overhang-deg",
        type=float,
        default=None,
        help="steepest printable overhang from vertical (part z up), deg (default: 45)",
    )
    z.set_defaults(func=run)
    return z


def constraints_of(args):
    """The maker constraints of `difflattice design`: the preset's, overridden by the options (mm)."""
    import dataclasses

    from ..design import presets

    c = presets.HORN_CONSTRAINTS if args.what == "horn" else presets.REFLECTOR_CONSTRAINTS
    mm = {
        "max_length_m": args.max_length_mm,
        "max_mouth_diameter_m": args.max_mouth_mm,
        "min_wall_m": args.min_wall_mm,
        "can_diameter_m": args.can_diameter_mm,
        "can_clearance_m": args.can_clearance_mm,
    }
    upd = {k: v * 1e-3 for k, v in mm.items() if v is not None}
    if args.max_overhang_deg is not None:
        upd["max_overhang_deg"] = args.max_overhang_deg
    return dataclasses.replace(c, **upd)


def run(args) -> int:
    """`difflattice design`: a horn, a reflector, or the carrier-vs-band comparison."""
    from ..design import presets
    from ..design.study import trust_line

    try:
        constraints = constraints_of(args)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    kw = dict(
        cells_per_wavelength=args.cells_per_wavelength,
        wall=args.wall,
        steps=args.steps,
        check_gradients=not args.no_gradient_check,
        progress=not args.quiet,
        constraints=constraints,
        lattice=args.lattice,
    )
    if args.resolution == "auto":
        kw["cells_per_wavelength"] = "auto"
        kw["max_cells_per_wavelength"] = args.max_cells_per_wavelength
    band = None
    if args.band is not None:
        band = args.band if args.band == "burst" else [float(f) for f in args.band.split(",")]
    if args.what == "compare":
        from ..design.band import compare_band

        try:
            s = compare_band(
                args.out,
                target_deg=args.target_deg,
                band=band or "burst",
                **{k: v for k, v in kw.items() if k != "check_gradients"},
            )
        except ValueError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        print(f"{s['verdict']}\n{trust_line(s['trust'])}\nwrote {args.out}/compare.md")
        return 0
    kw["band"] = band
    try:
        if args.what == "horn":
            s = presets.design_horn(args.out, target_deg=args.target_deg, **kw)
        else:
            s = presets.design_reflector(args.out, **kw)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{presets.one_line(s)}\nwrote {args.out}/report.md and the part {s['part']['stl']}")
    return 0
