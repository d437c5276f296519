"""The `difflattice` command line: thin handlers over the library.

Heavy imports (JAX, matplotlib) happen inside the handlers, so `difflattice capture --help` starts
fast and without JAX.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path


def _simulate(args) -> int:
    from .apps.scene_run import run_scene, write_outputs
    from .apps.scenes3d import load_scene_at

    if args.cells_per_wavelength is not None and not args.cells_per_wavelength > 0:
        print(f"error: --cells-per-wavelength {args.cells_per_wavelength:g}: give a resolution > 0", file=sys.stderr)
        return 2
    scene = load_scene_at(args.scene, args.cells_per_wavelength)
    if scene.grid["kind"] == "3d":
        return _simulate_3d(args, scene)
    if args.render_every is not None:
        scene.output["render_every_cells"] = args.render_every
    sr = run_scene(scene, progress=not args.quiet)
    files = write_outputs(
        sr,
        args.out,
        frames=False if args.no_frames else None,
        animation="none" if args.no_animation else args.animation,
    )
    s = sr.summary
    print(
        f"{scene.path}: {s['run']['n_steps']} steps on {s['grid']['shape'][0]} x {s['grid']['shape'][1]} cells "
        f"in {s['run']['wall_time_s']:.2f} s ({s['run']['mlups']:.0f} MLUPS); "
        f"expected phase error {s['accuracy']['expected_phase_error_periods']:.3f} periods"
    )
    if "farfield" in s:
        f = s["farfield"]
        print(
            f"lobe at {_num(f['range_m'], 'g')} m: -6 dB width {_num(f['width_6db_deg'], '.2f')} deg, "
            f"first null {_num(f.get('first_null_deg'), '.2f')} deg, first side lobe {_num(f.get('first_sidelobe_db'), '.1f')} dB"
        )
    print(f"wrote {files['summary']}")
    return 0


def _simulate_3d(args, scene) -> int:
    """A 3-D scene: estimate (printed, refused if it would not fit), run, A-scans and images."""
    from .apps.scenes3d import run_scene3d, write_outputs3d
    from .solver.estimate import format_bytes

    available = None if args.max_memory_gib is None else int(args.max_memory_gib * 2**30)
    sr = run_scene3d(scene, available_bytes=available, mlups=args.assume_mlups)
    files = write_outputs3d(sr, args.out)
    s = sr.summary
    r, est, mem = s["run"], s["estimate"], s["memory"]
    peak = mem.get("device_peak_bytes", mem["host_peak_rss_bytes"])
    print(
        f"{scene.path}: {r['n_steps']} steps on {' x '.join(map(str, s['grid']['shape']))} cells "
        f"({s['grid']['cells_per_wavelength']:g} cells per wavelength) in {r['wall_time_s']:.2f} s incl. compile "
        f"({r['mlups']:.0f} MLUPS; estimated {est['time_s']:.3g} s); peak memory {format_bytes(peak)} "
        f"(estimated {format_bytes(est['memory_bytes'])} + runtime); expected phase error "
        f"{s['accuracy']['expected_phase_error_periods']:.3f} periods"
    )
    for name, rec in s["receivers"].items():
        print(
            f"A-scan {name!r}: echo peak {rec['echo_peak']:.3g} at {rec['echo_peak_s'] * 1e6:.1f} µs "
            f"(window from {rec['gate_start_s'] * 1e6:.1f} µs; transmit peak {rec['transmit_peak']:.3g})"
        )
    print(f"wrote {files['summary']}")
    return 0


def _num(value, fmt: str) -> str:
    """A number for the console (`fmt`), or "none" when there is none (e.g. no null in range)."""
    return "none" if value is None else format(value, fmt)


def _gallery(args) -> int:
    from .apps.gallery import render_gallery

    render_gallery(args.out, scale=args.scale, names=args.only or None, progress=not args.quiet)
    return 0


def _demo(args) -> int:
    from .apps.demo import run_demo

    return run_demo(args.out, quick=args.quick, model=args.model)


def _fit(args) -> int:
    from .fit.config import run_fit_config

    return run_fit_config(args.config, out=args.out, quick=args.quick)


def _accuracy(args) -> int:
    from .apps import accuracy as acc

    cpw = tuple(args.cells_per_wavelength) if args.cells_per_wavelength else None
    if cpw is not None and min(cpw) < 4:
        print(
            f"error: --cells-per-wavelength {min(cpw):g}: give resolutions >= 4 cells per wavelength", file=sys.stderr
        )
        return 2
    if min(args.thickness_cells) < 1 or args.repeats < 0:
        print("error: --thickness-cells must be >= 1 cell and --repeats >= 0", file=sys.stderr)
        return 2
    if args.case == "polaroid":
        res = acc.sweep(cpw or (6, 8, 10, 14, 20, 28, 40), tuple(args.dtype), repeats=args.repeats)
        acc.write(res, args.out)
        print(f"wrote {args.out}/accuracy.json, accuracy_table.md, accuracy.png")
    elif args.case == "piston":
        res = acc.piston_sweep(cpw or (6, 8, 10, 14, 20, 28, 40), dtype=args.dtype[-1], repeats=args.repeats)
        acc.write_piston(res, args.out)
        print(f"wrote {args.out}/accuracy_piston.json, accuracy_piston_table.md, accuracy_piston.png")
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

    kw = dict(
        cells_per_wavelength=args.cells_per_wavelength,
        wall=args.wall,
        steps=args.steps,
        check_gradients=not args.no_gradient_check,
        progress=not args.quiet,
    )
    if args.what == "horn":
        s = presets.design_horn(args.out, target_deg=args.target_deg, **kw)
    else:
        s = presets.design_reflector(args.out, **kw)
    print(f"{presets.one_line(s)}; wrote {args.out}/report.md")
    return 0


def _bench(args) -> int:  # issue 15: forward speed, interleaved with the reference loops
    from .apps.bench import bench, markdown

    try:
        result = bench(reference=args.reference, rounds=args.rounds, force=args.force, quick=args.quick)
    except RuntimeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.out is not None:
        import json

        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "bench.json").write_text(json.dumps(result, indent=2) + "\n")
        (args.out / "bench.md").write_text(markdown(result))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from .config import Parser  # its help shows every option's default; sub-parsers inherit it

    p = Parser(prog="difflattice", description="Differentiable lattice-gas ultrasound simulator")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="simulate a scene file and write sensor data, images and a summary")
    s.add_argument("scene", type=Path, help="scene file (TOML, see docs/scene-files.md)")
    s.add_argument("--out", type=Path, required=True, help="output directory")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.add_argument("--no-animation", action="store_true", help="do not write an animation (same as --animation none)")
    s.add_argument(
        "--animation",
        choices=["gif", "mp4", "none"],
        default=None,
        help="animation of the snapshots (default: the scene's [output] animation, gif); mp4 needs ffmpeg, else gif",
    )
    s.add_argument("--no-frames", action="store_true", help="do not write a PNG per snapshot (frames/)")
    s.add_argument(
        "--render-every",
        type=int,
        default=None,
        metavar="CELLS",
        help="render every CELLS-th cell in field images (default: 3 at 20 cells per wavelength, "
        "at least 6.7 pixels per wavelength)",
    )
    s.add_argument(
        "--cells-per-wavelength",
        type=float,
        default=None,
        metavar="CPW",
        help="run at this resolution instead of the file's (cell and step counts scale, metres and seconds stay; "
        "e.g. 8 for a quick 3-D look; default: the scene file's [grid] cells_per_wavelength)",
    )
    s.add_argument(
        "--max-memory-gib",
        type=float,
        default=None,
        metavar="GIB",
        help="3-D: refuse a run whose memory estimate exceeds this (default: the memory available here)",
    )
    s.add_argument(
        "--assume-mlups",
        type=float,
        default=None,
        metavar="MLUPS",
        help="3-D: the throughput the time estimate assumes (default: measured once on this machine and cached)",
    )
    s.set_defaults(func=_simulate)

    g = sub.add_parser("gallery", help="render the paper's figures (data/scenes/*.toml)")
    g.add_argument("--out", type=Path, default=Path("out/gallery"), help="output directory")
    g.add_argument("--scale", type=float, default=1.0, help="grid scale (e.g. 0.5 for a quick look)")
    g.add_argument("--only", nargs="*", help="scene names to render (default: all)")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    g.set_defaults(func=_gallery)

    d = sub.add_parser(
        "demo",
        help="main job: emulated rig -> capture -> fit -> report",
        epilog="exit codes: those of the fit (`difflattice fit --help`): 0 converged and consistent with the data, "
        "3 not converged, 4 converged but the model does not describe the data; 2 unusable options",
    )
    d.add_argument(
        "--out",
        type=Path,
        default=Path("out/demo"),
        help="output directory (the capture files it writes in data/ are replaced)",
    )
    d.add_argument("--quick", action="store_true", help="smaller scans (for tests)")
    d.add_argument(
        "--model",
        choices=("disc", "line"),
        default="disc",
        help="the emulated transducer and the model fitted: disc (a circular transducer, the disc model on the "
        "axisymmetric lattice) or line (the paper's Polaroid-like line, the line model) (default: disc)",
    )
    d.set_defaults(func=_demo)

    from .config import keys_help
    from .fit.config import SECTIONS as FIT_SECTIONS
    from .fit.verdict import EXIT_CODES_HELP as FIT_EXIT_CODES

    f = sub.add_parser(
        "fit",
        help="fit a transducer model to captured data (config file)",
        description="Fit a transducer model to captured data, as a TOML config file says. A config "
        "that cannot be used exits with code 2 and one line naming the key; a fit that "
        "did not converge exits with code 3; one that converged but does not describe the data, 4.",
        epilog=FIT_EXIT_CODES
        + "\n\nconfig keys (every unit, allowed range and meaning in docs/fitting.md):\n"
        + keys_help(FIT_SECTIONS, width=96),
    )
    f.add_argument("config", type=Path, help="fit config (TOML, see docs/fitting.md)")
    f.add_argument("--out", type=Path, default=None, help="report directory (default: from the config)")
    f.add_argument("--quick", action="store_true", help="coarse settings (for tests)")
    f.set_defaults(func=_fit)

    a = sub.add_parser(
        "accuracy", help="error against run time over a resolution sweep (built-in cases, analytic references)"
    )
    a.add_argument(
        "--case",
        choices=["polaroid", "piston", "wall", "edges"],
        default="polaroid",
        help="polaroid: the Polaroid line's lobe and wavefront vs the continuous line; piston: a baffled "
        "38.4 mm disc on the axisymmetric lattice (on-axis field, lobe, the z = 16.5 mm line) vs "
        "the exact on-axis formula, 2 J1(x)/x and a Rayleigh-integral quadrature; wall: a point "
        "source's echo from a rigid and a soft wall vs the image-source solution; edges: the "
        "reflection of pml/sponge/mur edges vs a window too large to reach",
    )
    a.add_argument(
        "--cells-per-wavelength",
        type=float,
        nargs="+",
        default=None,
        help="resolutions (default: polaroid and piston 6 8 10 14 20 28 40; wall 6 8 10 14 20 30; edges 10 20)",
    )
    a.add_argument(
        "--thickness-cells",
        type=int,
        nargs="+",
        default=[5, 10, 20, 40],
        help="edges case: pml and sponge thicknesses, cells",
    )
    a.add_argument(
        "--dtype",
        nargs="+",
        default=["float32", "float64"],
        choices=["float32", "float64"],
        help="precisions (the edges case uses the first)",
    )
    a.add_argument(
        "--repeats",
        type=int,
        default=3,
        help="timed repeats after a compiling run (polaroid: their median; wall, edges: the fastest)",
    )
    a.add_argument("--out", type=Path, default=Path("out/accuracy"), help="output directory")
    a.set_defaults(func=_accuracy)

    z = sub.add_parser(
        "design", help="optimise a horn (target beam width) or a reflector (on-axis gain) from the paper's shapes"
    )
    z.add_argument("what", choices=["horn", "reflector"], help="what to design")
    z.add_argument("--out", type=Path, required=True, help="report directory")
    z.add_argument("--cells-per-wavelength", type=float, default=8.0, help="lattice resolution of the design runs")
    z.add_argument("--target-deg", type=float, default=8.0, help="horn: target -6 dB beam width at 1 m, deg")
    z.add_argument("--wall", default="soft", help="soft (the paper's speed-zero walls), rigid or a fluid material")
    z.add_argument("--steps", type=int, default=15, help="BFGS steps")
    z.add_argument("--no-gradient-check", action="store_true", help="skip the finite-difference check of the gradient")
    z.add_argument("--quiet", action="store_true", help="no progress bar")
    z.set_defaults(func=_design)

    b = sub.add_parser(
        "bench", help="forward speed (MLUPS) of the time loop: native, JAX and, with --reference, numba/NumPy"
    )
    b.add_argument(
        "--reference",
        action="store_true",
        help="also run the numba (1 thread, all cores) and NumPy loops of benchmarks/reference_kernels.py "
        "(a source checkout; their own venv .venv-bench), interleaved, and print the ratios",
    )
    b.add_argument("--rounds", type=int, default=2, help="interleaved rounds (each case in its own process per round)")
    b.add_argument(
        "--force", action="store_true", help="run on a busy machine (1-min load > 1): results marked provisional"
    )
    b.add_argument(
        "--out", type=Path, default=None, help="also write bench.json and bench.md here (default: print only)"
    )
    b.add_argument("--quick", action="store_true", help="a tenth of the steps (checks that it runs; not a measurement)")
    b.set_defaults(func=_bench)

    from .capture.cli import register  # capture is part of the package (and imports no JAX)

    register(sub)
    return p


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Configuration warnings as one line on stderr (`warning: ...`); others as Python prints them."""
    from .config import ConfigWarning

    if issubclass(category, ConfigWarning):
        print(f"warning: {' '.join(str(message).split())}", file=sys.stderr)
    else:
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def main(argv: list[str] | None = None) -> int:
    """Run a `difflattice` subcommand. Precision is set here, for the whole process
    (`apps.jaxconfig.configure`: float64 on, compilation cache), never inside the library.
    A configuration error prints one line (`error: ...`) and returns 2."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command in ("simulate", "gallery", "demo", "fit", "accuracy", "design"):
        from .apps.jaxconfig import configure

        configure()
    from .config import ConfigError

    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            return int(args.func(args) or 0)
        except ConfigError as e:
            print(f"error: {' '.join(str(e).split())}", file=sys.stderr)
            return 2
        except FileNotFoundError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2


def entry() -> None:
    """The `difflattice` command: `main`, then the process ends at once. Python's own shutdown
    frees JAX's compiled programs one by one, 0.6-0.8 s after a fit (measured), while every
    output is written and closed when `main` returns; so streams are flushed and `os._exit`
    ends the process. Under a profiler or tracer (cProfile, coverage), or with
    `DIFFLATTICE_FAST_EXIT=0`, the normal shutdown runs (their reports are written at exit)."""
    code = main()
    if (
        os.environ.get("DIFFLATTICE_FAST_EXIT", "1") == "0"
        or sys.getprofile() is not None
        or sys.gettrace() is not None
    ):
        sys.exit(code)
    import logging

    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    entry()
