"""Command line: JAX-free import, argparse wiring, SIGKILL mid-scan and re-run, the emulator CLI."""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from difflattice.capture.cli import main, read_metadata_file, register
from difflattice.capture.emulator import EmulatorHandle, make_config
from difflattice.capture.files import load_capture

from .helpers import META, TIMEOUT_S, assert_exact


def _records(path: Path) -> list[str]:
    return [line for line in path.read_text().splitlines() if line[:1].isdigit()]


def test_capture_imports_no_jax() -> None:
    code = (
        "import difflattice.capture.host, difflattice.capture.cli, difflattice.capture.emulator, "
        "difflattice.capture.files, difflattice.capture.groundtruth, sys; assert 'jax' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_register_adds_the_commands() -> None:
    parser = argparse.ArgumentParser(prog="difflattice")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(
        ["capture", "lobe", "x.csv", "--port", "/dev/null", "--freq-hz", "40000", "--step-deg", "2"]
    )
    assert callable(args.func) and args.step_deg == 2.0 and args.n_avg == 8
    args = parser.parse_args(["capture", "wave", "x.csv", "--port", "p", "--freq-hz", "4e4", "--z-mm", "20"])
    assert callable(args.func) and args.z_mm == 20.0
    args = parser.parse_args(["rig", "emulate", "--reset-at", "3", "80", "--garbage", "0.1"])
    assert callable(args.func)


def test_metadata_file_and_options(tmp_path: Path, start_rig: Callable[..., EmulatorHandle]) -> None:
    meta = tmp_path / "meta.txt"
    meta.write_text("# bench 2\ntemperature_c: 19.5\nrange_m: 1.0\noperator: ann\nmicrophone: 1/4in\n")
    assert read_metadata_file(meta)["microphone"] == "1/4in"
    rig = start_rig()
    out = tmp_path / "lobe.csv"
    argv = ["capture", "lobe", str(out), "--port", str(rig.path), "--freq-hz", "40000", "--start-deg", "-5",
            "--stop-deg", "5", "--meta", str(meta), "--operator", "bob", "--timeout-s", str(TIMEOUT_S),
            "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    cap = load_capture(out)
    assert cap.metadata["operator"] == "bob" and cap.metadata["temperature_c"] == 19.5
    assert main(["capture", "lobe", str(tmp_path / "y.csv"), "--port", str(tmp_path / "no"), "--freq-hz", "4e4",
                 "--meta", str(meta)]) == 3  # fmt: skip


def test_sigkill_mid_scan_then_rerun(start_rig: Callable[..., EmulatorHandle], tmp_path: Path) -> None:
    """Kill -9 mid-scan, tear the last line, re-run the command: nothing lost, nothing duplicated."""
    rig = start_rig(rig={"point_s": 0.01})
    out = tmp_path / "lobe.csv"
    cmd = [sys.executable, "-m", "difflattice.capture.cli", "capture", "lobe", str(out), "--port", str(rig.path),
           "--start-deg", "-50", "--stop-deg", "50", "--freq-hz", "40000", "--temperature-c", "21", "--range-m", "1",
           "--transducer-id", META["transducer_id"], "--operator", META["operator"], "--timeout-s", str(TIMEOUT_S),
           "--no-progress"]  # fmt: skip
    proc = subprocess.Popen(cmd)
    deadline = time.monotonic() + 15
    while not (out.exists() and len(_records(out)) >= 30):
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    before = _records(out)
    assert 30 <= len(before) < 101
    with open(out, "ab") as f:
        f.write(b"57,7000,4")  # a torn last line, as a power cut would leave
    assert subprocess.run(cmd, timeout=60).returncode == 0
    cap = load_capture(out)
    assert_exact(cap, rig)
    after = _records(out)
    assert after[: len(before)] == before and len(after) == 101
    assert any("repaired torn last line" in e for e in cap.events)
    assert any(f"resumed with {len(before)} of 101 points" in e for e in cap.events)


def test_rig_emulate_command(tmp_path: Path) -> None:
    link = tmp_path / "rig"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "difflattice.capture.cli",
            "rig",
            "emulate",
            "--link",
            str(link),
            "--heartbeat-s",
            "0.1",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == str(link.absolute())
        assert link.is_symlink() and link.exists()
    finally:
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        try:
            _, err = proc.communicate(timeout=10)
        finally:
            proc.kill()
    assert proc.returncode == 0 and "capture with --port" in err
    assert not link.exists()


def test_emulator_options_are_checked() -> None:
    with pytest.raises(ValueError, match="unknown fault key"):
        make_config(link_path="/tmp/x", transducer={"kind": "piston", "diameter_m": 0.01}, faults={"nope": 1})
    assert (
        json.loads(make_config(link_path="/tmp/x", transducer={"kind": "piston", "diameter_m": 0.01}).to_json())["rig"][
            "heartbeat_s"
        ]
        == 1.0
    )


def test_metadata_options_are_checked_by_their_declaration(capsys: pytest.CaptureFixture[str]) -> None:
    """The metadata options come from `files.Measurement`: a value outside its declared range is
    refused by argparse (exit 2) with the allowed range, before any rig is contacted."""
    with pytest.raises(SystemExit) as e:
        main(
            [
                "capture",
                "lobe",
                "x.csv",
                "--port",
                "/nonexistent",
                "--freq-hz",
                "40000",
                "--range-m",
                "1",
                "--temperature-c",
                "250",
            ]
        )
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--temperature-c" in err and "250 is out of range; allowed: -40 <= x <= 60 degC" in err
    with pytest.raises(SystemExit):
        main(["capture", "lobe", "--help"])
    out = capsys.readouterr().out
    assert "--humidity-pct NUMBER" in out and "(default: 8)" in out  # --n-avg shows its default
