"""The `difflattice` command line: thin handlers over the library.

Heavy imports (JAX, matplotlib) happen inside the handlers, so `difflattice capture --help` starts
fast and without JAX.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _simulate(args) -> int:
    from .apps.scene_run import run_scene, write_outputs
    from .scene.model import load_scene

    scene = load_scene(args.scene)
    if args.render_every is not None:
        scene.output["render_every_cells"] = args.render_every
    sr = run_scene(scene, progress=not args.quiet)
    files = write_outputs(sr, args.out, frames=False if args.no_frames else None,
                          animation="none" if args.no_animation else args.animation)
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
    from .apps.gallery import render_gallery

    render_gallery(args.out, scale=args.scale, names=args.only or None, progress=not args.quiet)
    return 0


def _demo(args) -> int:
    from .apps.demo import run_demo

    return run_demo(args.out, quick=args.quick)


def _fit(args) -> int:
    from .fit.config import run_fit_config

    return run_fit_config(args.config, out=args.out, quick=args.quick)


def _accuracy(args) -> int:
    from .apps import accuracy as acc

    cpw = tuple(args.cells_per_wavelength) if args.cells_per_wavelength else None
    if cpw is not None and min(cpw) < 4:
        print(f"error: --cells-per-wavelength {min(cpw):g}: give resolutions >= 4 cells per wavelength", file=sys.stderr)
        return 2
    if min(args.thickness_cells) < 1 or args.repeats < 0:
        print("error: --thickness-cells must be >= 1 cell and --repeats >= 0", file=sys.stderr)
        return 2
    if args.case == "polaroid":
        res = acc.sweep(cpw or (6, 8, 10, 14, 20, 28, 40), tuple(args.dtype), repeats=args.repeats)
        acc.write(res, args.out)
        print(f"wrote {args.out}/accuracy.json, accuracy_table.md, accuracy.png")
    elif args.case == "wall":
        res = acc.wall_sweep(cpw or (6, 8, 10, 14, 20, 30), tuple(args.dtype), repeats=args.repeats)
        acc.write_wall(res, args.out)
        print(f"wrote {args.out}/accuracy_wall.json, accuracy_wall_table.md, accuracy_wall.png")
    else:
        res = acc.edge_sweep(cpw or (10, 20), tuple(args.thickness_cells), args.dtype[0], repeats=args.repeats)
        acc.write_edges(res, args.out)
        print(f"wrote {args.out}/accuracy_edges.json, accuracy_edges_table.md, accuracy_edges.png")
    return 0


def _design(args) -> int:
    from .design import presets

    kw = dict(cells_per_wavelength=args.cells_per_wavelength, wall=args.wall, steps=args.steps,
              check_gradients=not args.no_gradient_check, progress=not args.quiet)
    if args.what == "horn":
        s = presets.design_horn(args.out, target_deg=args.target_deg, **kw)
    else:
        s = presets.design_reflector(args.out, **kw)
    print(f"{presets.one_line(s)}; wrote {args.out}/report.md")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="difflattice", description="Differentiable lattice-gas ultrasound simulator")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="simulate a scene file and write sensor data, images and a summary")
    s.add_argument("scene", type=Path, help="scene file (TOML, see docs/scene-files.md)")
    s.add_argument("--out", type=Path, required=True, help="output directory")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.add_argument("--no-animation", action="store_true", help="do not write an animation (same as --animation none)")
    s.add_argument("--animation", choices=["gif", "mp4", "none"], default=None,
                   help="animation of the snapshots (default: the scene's [output] animation, gif); mp4 needs ffmpeg, else gif")
    s.add_argument("--no-frames", action="store_true", help="do not write a PNG per snapshot (frames/)")
    s.add_argument("--render-every", type=int, default=None, metavar="CELLS",
                   help="render every CELLS-th cell in field images (default: 3 at 20 cells per wavelength, "
                        "at least 6.7 pixels per wavelength)")
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

    a = sub.add_parser("accuracy", help="error against run time over a resolution sweep (built-in cases, analytic references)")
    a.add_argument("--case", choices=["polaroid", "wall", "edges"], default="polaroid",
                   help="polaroid: the Polaroid line's lobe and wavefront vs the continuous line; wall: a point "
                        "source's echo from a rigid and a soft wall vs the image-source solution; edges: the "
                        "reflection of pml/sponge/mur edges vs a window too large to reach")
    a.add_argument("--cells-per-wavelength", type=float, nargs="+", default=None,
                   help="resolutions (default: polaroid 6 8 10 14 20 28 40; wall 6 8 10 14 20 30; edges 10 20)")
    a.add_argument("--thickness-cells", type=int, nargs="+", default=[5, 10, 20, 40],
                   help="edges case: pml and sponge thicknesses, cells")
    a.add_argument("--dtype", nargs="+", default=["float32", "float64"], choices=["float32", "float64"],
                   help="precisions (the edges case uses the first)")
    a.add_argument("--repeats", type=int, default=3, help="timed repeats after a compiling run (polaroid: their median; wall, edges: the fastest)")
    a.add_argument("--out", type=Path, default=Path("out/accuracy"))
    a.set_defaults(func=_accuracy)

    z = sub.add_parser("design", help="optimise a horn (target beam width) or a reflector (on-axis gain) from the paper's shapes")
    z.add_argument("what", choices=["horn", "reflector"])
    z.add_argument("--out", type=Path, required=True, help="report directory")
    z.add_argument("--cells-per-wavelength", type=float, default=8.0)
    z.add_argument("--target-deg", type=float, default=8.0, help="horn: target -6 dB beam width at 1 m, deg")
    z.add_argument("--wall", default="soft", help="soft (the paper's speed-zero walls), rigid or a fluid material")
    z.add_argument("--steps", type=int, default=15, help="BFGS steps")
    z.add_argument("--no-gradient-check", action="store_true")
    z.add_argument("--quiet", action="store_true")
    z.set_defaults(func=_design)

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
    if args.command in ("simulate", "gallery", "demo", "fit", "accuracy", "design"):
        from .apps.jaxconfig import configure

        configure()
    from .scene.schema import ConfigError

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
