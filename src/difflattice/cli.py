"""The `difflattice` command line: thin handlers over the library.

Heavy imports (JAX, matplotlib) happen inside the handlers, so `difflattice capture --help` starts
fast and without JAX.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _simulate(args) -> int:
    from .runner import run_scene, write_outputs
    from .scene import load_scene

    scene = load_scene(args.scene)
    sr = run_scene(scene, progress=not args.quiet)
    files = write_outputs(sr, args.out, animate=not args.no_animation)
    s = sr.summary
    print(f"{scene.path}: {s['run']['n_steps']} steps on {s['grid']['shape'][0]} x {s['grid']['shape'][1]} cells "
          f"in {s['run']['wall_time_s']:.2f} s ({s['run']['mlups']:.0f} MLUPS); "
          f"expected phase error {s['accuracy']['expected_phase_error_periods']:.3f} periods")
    if "farfield" in s:
        f = s["farfield"]
        print(f"lobe at {f['range_m']} m: -6 dB width {f['width_6db_deg']} deg, first null {f.get('first_null_deg')} deg, "
              f"first side lobe {f.get('first_sidelobe_db')} dB")
    print(f"wrote {files['summary']}")
    return 0


def _gallery(args) -> int:
    from .gallery import render_gallery

    render_gallery(args.out, scale=args.scale, names=args.only or None, progress=not args.quiet)
    return 0


def _demo(args) -> int:
    from .demo import run_demo

    return run_demo(args.out, quick=args.quick)


def _fit(args) -> int:
    from .fit.config import run_fit_config

    return run_fit_config(args.config, out=args.out, quick=args.quick)


def _accuracy(args) -> int:
    from .accuracy import sweep, write

    res = sweep(tuple(args.cells_per_wavelength), tuple(args.dtype), repeats=args.repeats)
    write(res, args.out)
    print(f"wrote {args.out}/accuracy.json, accuracy_table.md, accuracy.png")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="difflattice", description="Differentiable lattice-gas ultrasound simulator")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="simulate a scene file and write sensor data, images and a summary")
    s.add_argument("scene", type=Path, help="scene file (TOML, see docs/scene-files.md)")
    s.add_argument("--out", type=Path, required=True, help="output directory")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.add_argument("--no-animation", action="store_true", help="do not write animation.gif")
    s.set_defaults(func=_simulate)

    g = sub.add_parser("gallery", help="render the paper's figures (data/scenes/*.toml)")
    g.add_argument("--out", type=Path, default=Path("out/gallery"))
    g.add_argument("--scale", type=float, default=1.0, help="grid scale (e.g. 0.5 for a quick look)")
    g.add_argument("--only", nargs="*", help="scene names to render")
    g.add_argument("--quiet", action="store_true")
    g.set_defaults(func=_gallery)

    d = sub.add_parser("demo", help="main job: emulated rig -> capture -> fit -> report")
    d.add_argument("--out", type=Path, default=Path("out/demo"))
    d.add_argument("--quick", action="store_true", help="smaller scans (for tests)")
    d.set_defaults(func=_demo)

    f = sub.add_parser("fit", help="fit a transducer model to captured data (config file)")
    f.add_argument("config", type=Path, help="fit config (TOML, see docs/fitting.md)")
    f.add_argument("--out", type=Path, default=None, help="report directory (default: from the config)")
    f.add_argument("--quick", action="store_true", help="coarse settings (for tests)")
    f.set_defaults(func=_fit)

    a = sub.add_parser("accuracy", help="error against run time over a resolution sweep (built-in Polaroid line case)")
    a.add_argument("--cells-per-wavelength", type=float, nargs="+", default=[6, 8, 10, 14, 20, 28, 40])
    a.add_argument("--dtype", nargs="+", default=["float32", "float64"], choices=["float32", "float64"])
    a.add_argument("--repeats", type=int, default=3, help="timed repeats after a compiling run (median)")
    a.add_argument("--out", type=Path, default=Path("out/accuracy"))
    a.set_defaults(func=_accuracy)

    try:
        from .capture.cli import register
    except ImportError:  # pragma: no cover - capture is part of the package
        register = None
    if register is not None:
        register(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command in ("simulate", "gallery", "demo", "fit", "accuracy"):
        from .jaxconfig import configure

        configure()
    from .schema import ConfigError

    try:
        return int(args.func(args) or 0)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except FileNotFoundError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
