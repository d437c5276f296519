"""Command line of the capture subsystem.

``difflattice capture lobe OUT.csv ...``, ``difflattice capture wave OUT.csv ...`` and
``difflattice rig emulate ...``. :func:`register` adds them to the main ``difflattice`` parser;
``python -m difflattice.capture.cli ...`` runs them on their own. Exit codes: 0 done, 2 bad
options, 3 rig or link error, 4 capture file error, 130 interrupted (the file can be continued).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from ..config import Parser, add_options, specs
from . import emulator
from .errors import CaptureFileError, RigError
from .files import Measurement, load_capture
from .host import capture_lobe, capture_wave


def read_metadata_file(path: Path) -> dict[str, Any]:
    """Metadata from a JSON object (``.json``) or ``key: value`` lines (``#`` starts a comment)."""
    text = path.read_text()
    if path.suffix == ".json":
        doc = json.loads(text)
        if not isinstance(doc, dict):
            raise ValueError(f"{path}: a metadata file holds one JSON object")
        return doc
    meta: dict[str, Any] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        key, sep, value = line.partition(":")
        if not sep:
            raise ValueError(f"{path}:{lineno}: expected 'key: value', got {line!r}")
        meta[key.strip()] = value.strip()
    return meta


def _metadata(args: argparse.Namespace) -> dict[str, Any]:
    meta = read_metadata_file(args.meta) if args.meta else {}
    for key in (s.name for s in specs(Measurement)):
        if getattr(args, key) is not None:
            meta[key] = getattr(args, key)
    return meta


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("out", type=Path, help="capture file to write or continue (.csv; raw log .log beside it)")
    port = os.environ.get("DIFFLATTICE_PORT")
    p.add_argument(
        "--port",
        default=port,
        required=port is None,
        help="stable serial path of the rig, e.g. /dev/serial/by-id/... (default: $DIFFLATTICE_PORT)",
    )
    p.add_argument("--n-avg", type=int, default=8, help="bursts averaged per point")
    p.add_argument("--cycles", type=int, default=16, help="burst length [cycles]")
    p.add_argument("--freq-hz", type=float, required=True, help="drive frequency [Hz] (sent as an integer)")
    meta = p.add_argument_group("measurement metadata (options override --meta; none by default)")
    meta.add_argument("--meta", type=Path, help="metadata file: JSON object or 'key: value' lines (default: none)")
    add_options(meta, Measurement)
    p.add_argument("--timeout-s", type=float, default=3.0, help="silence that means the link is down [s]")
    p.add_argument("--reconnect-s", type=float, default=30.0, help="how long to wait for a lost link [s]")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _run_capture(args: argparse.Namespace, scan: dict[str, Any]) -> int:
    function = capture_lobe if args.capture_kind == "lobe" else capture_wave
    try:
        path = function(
            args.port,
            args.out,
            **scan,
            n_avg=args.n_avg,
            cycles=args.cycles,
            freq_hz=args.freq_hz,
            metadata=_metadata(args),
            progress=not args.no_progress,
            timeout_s=args.timeout_s,
            reconnect_s=args.reconnect_s,
        )
        capture = load_capture(path)
    except KeyboardInterrupt:
        print(
            f"\ninterrupted: {args.out} keeps every point so far; re-run the same command to continue", file=sys.stderr
        )
        return 130
    except RigError as exc:
        print(f"difflattice capture: error: {exc}", file=sys.stderr)
        return 3
    except CaptureFileError as exc:
        print(f"difflattice capture: error: {exc}", file=sys.stderr)
        return 4
    except (ValueError, OSError) as exc:
        print(f"difflattice capture: error: {exc}", file=sys.stderr)
        return 2
    print(f"{path}: complete, {capture.metadata['n_points']} points, {len(capture.events)} events")
    return 0


def _capture_lobe(args: argparse.Namespace) -> int:
    return _run_capture(args, {"start_deg": args.start_deg, "stop_deg": args.stop_deg, "step_deg": args.step_deg})


def _capture_wave(args: argparse.Namespace) -> int:
    mm = {"x0_m": args.x0_mm, "x1_m": args.x1_mm, "dx_m": args.dx_mm, "z_m": args.z_mm}
    return _run_capture(args, {k: v / 1000 for k, v in mm.items()})


def _emulate(args: argparse.Namespace) -> int:
    try:
        cfg = emulator.config_from_args(args)
    except (ValueError, OSError) as exc:
        print(f"difflattice rig emulate: error: {exc}", file=sys.stderr)
        return 2
    print(
        f"rig emulator {cfg.rig.rig_id} ({cfg.transducer}); capture with --port {cfg.link_path}; Ctrl-C stops it",
        file=sys.stderr,
    )
    emulator.serve(cfg)
    return 0


def register(subparsers: Any) -> None:
    """Add ``capture {lobe,wave}`` and ``rig emulate`` to an argparse ``subparsers`` object."""
    capture = subparsers.add_parser("capture", help="capture a scan from the measurement rig over serial")
    kinds = capture.add_subparsers(dest="capture_kind", required=True, metavar="{lobe,wave}")
    lobe = kinds.add_parser(
        "lobe",
        help="lobe pattern: amplitude vs turntable angle",
        description="Capture a lobe pattern; re-running the same command on an unfinished file continues it.",
    )
    _add_common(lobe)
    lobe.add_argument("--start-deg", type=float, default=-90.0, help="first angle [deg]")
    lobe.add_argument("--stop-deg", type=float, default=90.0, help="last angle [deg]")
    lobe.add_argument("--step-deg", type=float, default=1.0, help="angle step [deg]")
    lobe.set_defaults(func=_capture_lobe)
    wave = kinds.add_parser(
        "wave",
        help="wavefront: arrival time, phase and amplitude along x at distance z",
        description="Capture a wavefront scan; re-running the same command on an unfinished file continues it.",
    )
    _add_common(wave)
    wave.add_argument("--x0-mm", type=float, default=-30.0, help="first x [mm]")
    wave.add_argument("--x1-mm", type=float, default=30.0, help="last x [mm]")
    wave.add_argument("--dx-mm", type=float, default=0.5, help="x step [mm]")
    wave.add_argument("--z-mm", type=float, default=16.5, help="distance from the face [mm]")
    wave.set_defaults(func=_capture_wave)

    rig = subparsers.add_parser("rig", help="rig tools")
    tools = rig.add_subparsers(dest="rig_tool", required=True, metavar="{emulate}")
    emulate = tools.add_parser(
        "emulate",
        help="run a rig emulator on a pseudo-terminal",
        description="Run a rig emulator; it prints the stable path to capture from, and runs until Ctrl-C.",
    )
    emulator.add_arguments(emulate)
    emulate.set_defaults(func=_emulate)


def main(argv: list[str] | None = None) -> int:
    """``python -m difflattice.capture.cli``: the capture commands on their own."""
    parser = Parser(prog="difflattice")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
