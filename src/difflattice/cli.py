"""The `difflattice` command line: thin handlers over the library.

Heavy imports (JAX, matplotlib) happen inside the handlers, so `difflattice capture --help` starts
fast and without JAX. Habits every job shares (set up in `main` and `entry`): `--version`;
`-q/--quiet` and `-v/--verbose`; `--out` checked before any work (an existing file is refused, a
non-empty directory too unless `--overwrite` clears it); Ctrl-C ends with one line and exit code
130, and a run cut short leaves an `INCOMPLETE` file beside its partial outputs; the exit codes
are `EXIT_CODES`.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import os
import sys
import threading
import warnings
from pathlib import Path

EXIT_CODES = """exit codes:
  0    success
  1    an unexpected error (a bug: Python's traceback follows; please report it)
  2    input that cannot be used: command line, scene file, fit config, data file or --out
       (one line on stderr names the problem and the fix)
  3    fit: the solver did not converge (the report is written and says so); capture: the rig
       failed (no answer, a protocol error)
  4    capture: the capture file cannot be used (malformed, locked, or another scan than asked)
  130  interrupted (Ctrl-C): one line on stderr; outputs written so far are kept and marked
       partial by an INCOMPLETE file in the output directory"""

INCOMPLETE = "INCOMPLETE"
"""The file a run cut short leaves in its output directory (what was interrupted, and when)."""

# what an interrupt must know: the job's output directory and whether its outputs are complete
_SESSION: dict = {"out": None, "command": None, "complete": False}
_INTERRUPT_LOCK = threading.Lock()


def _simulate(args) -> int:
    from .apps.scene3d_run import throughput
    from .apps.scene_run import run_scene, write_outputs
    from .apps.scenes3d import load_scene_at

    if args.cells_per_wavelength is not None and not args.cells_per_wavelength > 0:
        print(f"error: --cells-per-wavelength {args.cells_per_wavelength:g}: give a resolution > 0", file=sys.stderr)
        return 2
    scene = load_scene_at(args.scene, args.cells_per_wavelength)
    print(scene.describe_air())
    if args.render_every is not None:
        scene = dataclasses.replace(
            scene, output=dataclasses.replace(scene.output, render_every_cells=args.render_every)
        )
    if args.isolate and scene.kind.ndim == 3:  # a misspelt surface is refused before the run, not after it
        from .apps.echoes_isolated import surface_names

        unknown = sorted(set(args.isolate) - set(surface_names(scene)))
        if unknown:
            print(f"error: --isolate {unknown}: no such surface; give one of {surface_names(scene)}", file=sys.stderr)
            return 2
    available = None if args.max_memory_gib is None else int(args.max_memory_gib * 2**30)
    sr = run_scene(scene, progress=not args.quiet, available_bytes=available, mlups=args.assume_mlups)
    files = write_outputs(
        sr,
        args.out,
        frames=False if args.no_frames else None,
        animation="none" if args.no_animation else args.animation,
        data_format=args.format,
    )
    if scene.kind.ndim == 3:
        if args.isolate_echoes or args.isolate:
            _isolate_echoes(scene, sr, args.out, args.isolate)
        return _report_3d(args, sr, files)
    if args.isolate_echoes or args.isolate:
        print('error: --isolate-echoes is for kind = "3d" pulse-echo scenes', file=sys.stderr)
        return 2
    s = sr.summary
    r = s["run"]
    print(
        f"{scene.path}: {r['n_steps']} steps on {s['grid']['shape'][0]} x {s['grid']['shape'][1]} cells "
        f"in {r['wall_time_s']:.2f} s ({throughput(r)}); "
        f"expected phase error {s['accuracy']['expected_phase_error_periods']:.3f} periods"
    )
    if "farfield" in s:
        f = s["farfield"]
        print(
            f"lobe at {_num(f['range_m'], 'g')} m: -6 dB width {_num(f['width_6db_deg'], '.2f')} deg, "
            f"first null {_num(f.get('first_null_deg'), '.2f')} deg, first side lobe {_num(f.get('first_sidelobe_db'), '.1f')} dB"
        )
    if args.verbose:
        for key, path in files.items():
            print(f"  {key}: {path}")
    print(f"wrote {files['summary']}")
    return 0


def _isolate_echoes(scene, sr, out, only=None) -> None:
    """--isolate-echoes: one more run per surface (apps.echoes_isolated; `only`: those named by
    --isolate), its table on stdout."""
    from .apps.echoes3d import UNDER_RESOLVED
    from .apps.echoes_isolated import isolate_echoes

    doc = isolate_echoes(scene, out, full=sr, only=only, log=lambda m: print(m, file=sys.stderr, flush=True))
    for e in doc["echoes"]:
        print(
            f"isolated echo {e['surface']!r} ({e['first_arrival']}): path {e['path_m']:.4f} m, {e['level_db']:.1f} dB, first "
            f"arrival {e['error_periods']:+.3f} ± {e['sigma_periods']:.3f} periods vs lattice delay "
            f"({'separable' if e['separable'] else 'not separable: ' + e['why']}), {e['error_periods_air']:+.2f} vs air"
            + (f"; {UNDER_RESOLVED}" if e.get("under_resolved") else "")
        )


def _report_3d(args, sr, files: dict) -> int:
    """A 3-D run's console lines (`apps.scene3d_run.report_lines`)."""
    from .apps.scene3d_run import report_lines

    for line in report_lines(sr):
        print(line)
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
    from .apps.fitting import run_fit_config

    return run_fit_config(args.config, out=args.out, quick=args.quick)


def _accuracy(args) -> int:
    from .apps import accuracy as acc
    from .apps import accuracy_piston, accuracy_wall

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
        res = accuracy_piston.piston_sweep(
            cpw or (6, 8, 10, 14, 20, 28, 40), dtype=args.dtype[-1], repeats=args.repeats
        )
        accuracy_piston.write_piston(res, args.out)
        print(f"wrote {args.out}/accuracy_piston.json, accuracy_piston_table.md, accuracy_piston.png")
    elif args.case == "wall":
        res = accuracy_wall.wall_sweep(cpw or (6, 8, 10, 14, 20, 30), tuple(args.dtype), repeats=args.repeats)
        accuracy_wall.write_wall(res, args.out)
        print(f"wrote {args.out}/accuracy_wall.json, accuracy_wall_table.md, accuracy_wall.png")
    elif args.case == "air":
        from .apps import accuracy_air

        rows = accuracy_air.sweep(cpw or accuracy_air.RESOLUTIONS)
        accuracy_air.write(rows, args.out, accuracy_air.point_source())
        print(f"wrote {args.out}/{accuracy_air.FILES}")
    elif args.case == "dispersion3d":
        from .apps import accuracy_dispersion3d

        path = accuracy_dispersion3d.write(
            accuracy_dispersion3d.sweep(cpw or accuracy_dispersion3d.RESOLUTIONS), args.out
        )
        print(f"wrote {path}")
    else:
        res = accuracy_wall.edge_sweep(
            cpw or (10, 20), tuple(args.thickness_cells), args.dtype[0], repeats=args.repeats
        )
        accuracy_wall.write_edges(res, args.out)
        print(f"wrote {args.out}/accuracy_edges.json, accuracy_edges_table.md, accuracy_edges.png")
    return 0


def _bench(args) -> int:  # issue 15: forward speed, interleaved with the reference loops
    from .apps.bench import CPU_CASES_3D, bench, markdown

    cases = {"3d": {"cases": CPU_CASES_3D}}.get(args.cases, {})
    try:
        result = bench(reference=args.reference, rounds=args.rounds, force=args.force, quick=args.quick, **cases)
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
    from . import __version__
    from .config import Parser  # its help shows every option's default; sub-parsers inherit it

    p = Parser(
        prog="difflattice",
        description="Differentiable lattice-gas ultrasound simulator: simulate scenes, fit transducer models to "
        "measurements, design horns and reflectors. `difflattice JOB --help` for a job's options.",
        epilog=EXIT_CODES,
    )
    p.add_argument("--version", action="version", version=f"difflattice {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    _add_simulate(sub)
    _add_gallery_and_demo(sub)
    _add_fit(sub)
    _add_accuracy(sub)
    _add_design_and_bench(sub)

    from .capture.cli import register  # capture is part of the package (and imports no JAX)

    register(sub)
    for leaf in _leaf_parsers(p):
        _add_common(leaf)
    return p


def _add_simulate(sub) -> None:
    """The `simulate` job: a scene file run and written out."""
    s = sub.add_parser("simulate", help="simulate a scene file and write sensor data, images and a summary")
    s.add_argument("scene", type=Path, help="scene file (TOML, see docs/scene-files.md)")
    s.add_argument("--out", type=Path, required=True, help="output directory (new, or empty, or --overwrite)")
    s.add_argument(
        "--format",
        choices=["npz", "netcdf"],
        default="npz",
        help="sensor data file: npz (sensors.npz, NumPy) or netcdf (sensors.nc for xarray / h5py: probe series, "
        "A-scans, peak and RMS fields with coordinates in m and s and units as attributes; needs "
        "pip install 'difflattice[netcdf]'); CSV tables (probes, lobe, A-scans) are written either way",
    )
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
    s.add_argument(
        "--isolate-echoes",
        action="store_true",
        help="3-D pulse-echo: also run the scene once without each surface and write echoes_isolated.json/.png: "
        "each surface's own echo (the difference of the runs), its matched-filter arrival against its "
        "image-source delay on the lattice and in air (one more run per surface)",
    )
    s.add_argument(
        "--isolate",
        action="append",
        default=None,
        metavar="SURFACE",
        help="3-D pulse-echo: --isolate-echoes for this surface only (its name as in echoes.json, e.g. 'post'; "
        "repeat for several; default: none, --isolate-echoes isolates every surface)",
    )
    s.set_defaults(func=_simulate)


def _add_gallery_and_demo(sub) -> None:
    """The `gallery` (the paper's figures) and `demo` (the main job) jobs."""
    g = sub.add_parser("gallery", help="render the paper's figures (data/scenes/*.toml)")
    g.add_argument("--out", type=Path, default=Path("out/gallery"), help="output directory")
    g.add_argument("--scale", type=float, default=1.0, help="grid scale (e.g. 0.5 for a quick look)")
    g.add_argument("--only", nargs="*", help="scene names to render (default: all)")
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


def _add_fit(sub) -> None:
    """The `fit` job: a fit config run, with its keys and exit codes in the help."""
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


def _add_accuracy(sub) -> None:
    """The `accuracy` job: error against run time over a resolution sweep."""
    a = sub.add_parser(
        "accuracy", help="error against run time over a resolution sweep (built-in cases, analytic references)"
    )
    a.add_argument(
        "--case",
        choices=["polaroid", "piston", "wall", "edges", "air", "dispersion3d"],
        default="polaroid",
        help="polaroid: the Polaroid line's lobe and wavefront vs the continuous line; piston: a baffled "
        "38.4 mm disc on the axisymmetric lattice (on-axis field, lobe, the z = 16.5 mm line) vs "
        "the exact on-axis formula, 2 J1(x)/x and a Rayleigh-integral quadrature; wall: a point "
        "source's echo from a rigid and a soft wall vs the image-source solution; edges: the "
        "reflection of pml/sponge/mur edges vs a window too large to reach; air: plane-wave attenuation and "
        "phase speed in humid air (20-200 kHz, 0-40 deg C, 10-90 %% RH) vs ISO 9613-1 and the relaxation model; "
        "dispersion3d: the 3-D stencils' phase speed along axes and face and body diagonals, simulated, vs "
        "their dispersion relations",
    )
    a.add_argument(
        "--cells-per-wavelength",
        type=float,
        nargs="+",
        default=None,
        help="resolutions (default: polaroid and piston 6 8 10 14 20 28 40; wall 6 8 10 14 20 30; edges 10 20; "
        "dispersion3d 6 7 8 12)",
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


def _add_design_and_bench(sub) -> None:
    """The `design` job (its parser lives with it in `apps.design_job`) and `bench`."""
    from .apps.design_job import add_parser as _add_design_parser

    _add_design_parser(sub)

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
    b.add_argument(
        "--cases",
        choices=("2d", "3d"),
        default="2d",
        help="2d: the 2-D and rz cases (840x630, 2048^2; homogeneous and full-featured); 3d: 256^3 homogeneous "
        "(native 1 and 2 threads, JAX; with --reference numba 1 and 2 threads)",
    )
    b.set_defaults(func=_bench)


# the jobs whose --out is a directory this run fills (capture's OUT is a file it may continue)
_OUT_DIR_JOBS = ("simulate", "gallery", "demo", "fit", "accuracy", "design", "bench")


def _leaf_parsers(parser: argparse.ArgumentParser):
    """Every parser that runs a job (no sub-commands of its own), depth first."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield parser
        return
    seen: set[int] = set()
    for action in subs:
        for child in action.choices.values():
            if id(child) not in seen:
                seen.add(id(child))
                yield from _leaf_parsers(child)


def _add_common(leaf: argparse.ArgumentParser) -> None:
    """What every job has: -q/--quiet, -v/--verbose, the exit codes in its help, and for the
    jobs that fill an output directory, --overwrite."""
    group = leaf.add_mutually_exclusive_group()
    group.add_argument(
        "-q", "--quiet", action="store_true", help="no progress bars or messages; errors and warnings still on stderr"
    )
    group.add_argument(
        "-v", "--verbose", action="store_true", help="more detail: timings, every file written, tracebacks of errors"
    )
    if leaf.prog.split()[-1] in _OUT_DIR_JOBS and "--out" in leaf._option_string_actions:
        leaf.add_argument(
            "--overwrite",
            action="store_true",
            help="clear a non-empty --out directory first (without it such a directory is refused, so that no "
            "earlier run's files are mixed with this one's)",
        )
    leaf.epilog = f"{leaf.epilog}\n\n{EXIT_CODES}" if leaf.epilog else EXIT_CODES


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Configuration warnings as one line on stderr (`warning: ...`); others as Python prints them."""
    from .config import ConfigWarning

    if issubclass(category, ConfigWarning):
        print(f"warning: {' '.join(str(message).split())}", file=sys.stderr)
    else:
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def _check_out(args) -> str | None:
    """Check the job's `--out` before any work; returns the error line, or None. An existing file
    is refused; a non-empty directory is refused, or cleared with `--overwrite` (never a directory
    that holds a source checkout, the current directory or a parent of it)."""
    out = getattr(args, "out", None)
    if args.command not in _OUT_DIR_JOBS or out is None:
        return None
    out = Path(out)
    if out.exists() and not out.is_dir():
        return f"--out {out} is an existing file: give a directory (a new one, or an empty one)"
    if not out.is_dir() or not any(out.iterdir()):
        return None
    if not getattr(args, "overwrite", False):
        return (
            f"--out {out} is a directory that is not empty: give a new or empty directory, or add --overwrite "
            "to clear it first"
        )
    here = Path.cwd().resolve()
    target = out.resolve()
    if target == here or target in here.parents or (target / ".git").exists() or (target / "pyproject.toml").exists():
        return (
            f"--overwrite would clear {out}, which holds the current directory or a source checkout: give another --out"
        )
    import shutil

    for child in target.iterdir():
        if child.is_dir() and not child.is_symlink():
            shutil.rmtree(child)
        else:
            child.unlink()
    return None


def _mark_incomplete() -> str:
    """After an interrupt: write `INCOMPLETE` into the job's output directory where it holds
    files and the job had not finished writing; returns the sentence for the one-line message."""
    out = _SESSION.get("out")
    if _SESSION.get("complete"):
        return f"the outputs in {out} are complete" if out else "its outputs were complete"
    if out is None or not Path(out).is_dir() or not any(Path(out).iterdir()):
        return "no output was written"
    import time

    try:
        (Path(out) / INCOMPLETE).write_text(
            f"difflattice {_SESSION.get('command')} was interrupted (Ctrl-C) at "
            f"{time.strftime('%Y-%m-%d %H:%M:%S')}: the files in this directory are partial (some may be "
            "missing or cut short). Run the job again with --overwrite for a complete set.\n"
        )
    except OSError:
        return f"the outputs in {out} are partial"
    return f"the outputs in {out} are partial (marked by {Path(out) / INCOMPLETE})"


def _interrupted_line() -> str:
    return f"interrupted (Ctrl-C): {_mark_incomplete()}"


INTERRUPT_GRACE_S = 2.0
"""After Ctrl-C, how long the main thread has to stop by itself (`KeyboardInterrupt`: `finally`
blocks run, a capture keeps its points, the emulator closes its port) before the process is
ended from the watcher thread (the main thread is waiting in compiled code)."""

_MAIN_DONE = threading.Event()


def _exit_on_interrupt() -> None:
    """The process ends now with one line and exit code 130 (the watcher thread, when the main
    thread did not stop within `INTERRUPT_GRACE_S`)."""
    if not _INTERRUPT_LOCK.acquire(blocking=False):
        return  # the main thread is already reporting the interrupt
    try:
        sys.stdout.flush()
    except Exception:  # noqa: BLE001 (a closed or redirected stream must not stop the exit)
        pass
    sys.stderr.write("\n" + _interrupted_line() + "\n")
    sys.stderr.flush()
    os._exit(130)


def _install_interrupt_handler() -> None:
    """Ctrl-C ends the command within `INTERRUPT_GRACE_S`, even while the main thread waits in
    compiled code (XLA compiling or running a kernel, where Python's own handler runs only when
    that returns): Python's handler raises `KeyboardInterrupt` in the main thread as usual, and
    the C-level handler also writes the signal to a socket (`signal.set_wakeup_fd`); a watcher
    thread wakes on it and, if the main thread has not finished by then, ends the process.
    Installed by `entry` only (in-process callers of `main` get `KeyboardInterrupt` turned into
    code 130 by `main`)."""
    import signal
    import socket

    def on_sigint(signum, frame):
        _SESSION["interrupted"] = True  # seen by `main` even where the KeyboardInterrupt is lost
        raise KeyboardInterrupt

    def unraisable(u) -> None:  # a KeyboardInterrupt raised inside a gc callback or __del__ is
        if isinstance(u.exc_value, KeyboardInterrupt):  # "ignored" by Python: not a traceback here
            return
        sys.__unraisablehook__(u)

    signal.signal(signal.SIGINT, on_sigint)  # also where the shell had ignored it
    sys.unraisablehook = unraisable
    try:
        r, w = socket.socketpair()
        w.setblocking(False)
        signal.set_wakeup_fd(w.fileno(), warn_on_full_buffer=False)
    except (ValueError, OSError):  # not the main thread, or no sockets: Python's handler alone
        return

    def watch() -> None:
        while True:
            data = r.recv(64)
            if not data:
                return
            if signal.SIGINT in data and not _MAIN_DONE.wait(INTERRUPT_GRACE_S):
                _exit_on_interrupt()

    threading.Thread(target=watch, name="difflattice-interrupt", daemon=True).start()
    _SESSION["sockets"] = (r, w)  # kept alive for the life of the process


def main(argv: list[str] | None = None) -> int:
    """Run a `difflattice` subcommand. Precision is set here, for the whole process
    (`apps.jaxconfig.configure`: float64 on, compilation cache), never inside the library.
    `--out` is checked before any work; a configuration error prints one line (`error: ...`)
    and returns 2; Ctrl-C returns 130 (see `EXIT_CODES`)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    problem = _check_out(args)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    _SESSION.update(out=getattr(args, "out", None), command=args.command, complete=False)
    quiet, verbose = getattr(args, "quiet", False), getattr(args, "verbose", False)
    if quiet:
        os.environ["TQDM_DISABLE"] = "1"  # every progress bar, including the library's own
    if verbose:
        import logging

        logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    try:
        if args.command in ("simulate", "gallery", "demo", "fit", "accuracy", "design"):
            from .apps.jaxconfig import configure

            configure()
        code = _run(args, quiet=quiet, verbose=verbose)
        _SESSION["complete"] = True
        if _SESSION.get("interrupted") and _INTERRUPT_LOCK.acquire(blocking=False):
            # Ctrl-C whose KeyboardInterrupt Python dropped (raised inside a gc callback): the job
            # ran to its end, so its outputs are complete; the exit code still says interrupted
            print(f"\n{_interrupted_line()}", file=sys.stderr)
            return 130
        return code
    except KeyboardInterrupt:
        if _INTERRUPT_LOCK.acquire(blocking=False):  # not already reported by the watcher thread
            print(f"\n{_interrupted_line()}", file=sys.stderr)  # on its own line, after a progress bar
        return 130
    except Exception:
        if not _SESSION.get("interrupted"):
            raise
        # Ctrl-C whose KeyboardInterrupt was turned into another error by the code it landed in
        # (seen in CI: inside matplotlib's ft2font import -> "ImportError: initialization failed")
        if _INTERRUPT_LOCK.acquire(blocking=False):
            print(f"\n{_interrupted_line()}", file=sys.stderr)
        return 130


def _run(args, *, quiet: bool, verbose: bool) -> int:
    from .config import ConfigError

    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()) if quiet else contextlib.nullcontext():
        warnings.showwarning = _show_warning
        try:
            return int(args.func(args) or 0)
        except (ConfigError, FileNotFoundError, FileExistsError, NotADirectoryError) as e:
            if verbose:
                import traceback

                traceback.print_exc()
            text = str(e) if isinstance(e, OSError) else " ".join(str(e).split())
            print(f"error: {text}", file=sys.stderr)
            return 2


def entry() -> None:
    """The `difflattice` command: `main`, then the process ends at once. Python's own shutdown
    frees JAX's compiled programs one by one, 0.6-0.8 s after a fit (measured), while every
    output is written and closed when `main` returns; so streams are flushed and `os._exit`
    ends the process. Under a profiler or tracer (cProfile, coverage), or with
    `DIFFLATTICE_FAST_EXIT=0`, the normal shutdown runs (their reports are written at exit).
    Ctrl-C ends it with one line and code 130 (`_install_interrupt_handler`)."""
    _install_interrupt_handler()
    try:
        code = main()
    except KeyboardInterrupt:  # before main's own handling began (parsing the command line)
        print("interrupted (Ctrl-C): no output was written", file=sys.stderr)
        code = 130
    except Exception:  # a bug: its traceback, then the same prompt exit as every other ending (a
        import traceback  # half-imported extension module can crash Python's own shutdown)

        traceback.print_exc()
        code = 1
    _MAIN_DONE.set()
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
