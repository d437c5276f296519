"""The reference rig firmware (firmware/) against the project's own capture host, over a pty.

The firmware's host build (``make -C firmware host``: the board-independent protocol, scan and
lock-in code with simulated steppers, switches and microphone ADC) measures a 38.4 mm circular
piston whose complex pressures come from the project's ground truth (Rayleigh integral,
``capture.groundtruth``). ``difflattice capture`` takes a 181-point lobe scan (the rig resets while
sending point 80; the host is killed with SIGKILL after 120 points and re-run) and a 49-point
wavefront scan (the host killed after 20 points and re-run). Checks: every point exactly once;
the values against the ground truth within the noise the rig reports; the protocol's phase sign;
the fitted diameter (disc model, the project's fit entry) within its quoted uncertainty.
"""

from __future__ import annotations

import importlib.util
import math
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from difflattice.capture import protocol as P
from difflattice.capture.files import Capture, load_capture
from difflattice.capture.groundtruth import Piston, lag_deg, speed_of_sound

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware"
D_M, F_HZ, T_C, N_AVG = 0.0384, 50_000, 21.0, 8
PISTON = {"kind": "piston", "diameter_m": D_M, "sensitivity_uV": 50_000.0}
PHASE_JITTER_DEG = 0.3  # rig-sim's default per-burst phase jitter
RESET_AT, KILL_LOBE_AT, KILL_WAVE_AT = 80, 120, 20


def _load_truth_tool():
    spec = importlib.util.spec_from_file_location("truth_table", FIRMWARE / "tools" / "truth_table.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def build() -> Path:
    """``make -C firmware host test``: the host binary and the core's unit tests (which run)."""
    for tool in ("g++", "make"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} is not installed: the firmware's host build needs g++ and make")
    r = subprocess.run(["make", "-s", "-C", str(FIRMWARE), "host", "test"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "0 failed" in r.stdout, r.stdout
    return FIRMWARE / "build" / "rig-sim"


def test_board_build_compiles_for_cortex_m7() -> None:
    """`make -C firmware board-check`: the core, the Teensy 4.1 layer and the sketch compile for
    Cortex-M7 against the Teensyduino declaration shim (skipped where the toolchain is absent: it
    is about 2 GB from Debian, so CI does not install it)."""
    if shutil.which("arm-none-eabi-g++") is None or shutil.which("make") is None:
        pytest.skip("arm-none-eabi-g++ is not installed (Debian: gcc-arm-none-eabi, libnewlib-arm-none-eabi, "
                    "libstdc++-arm-none-eabi-newlib); the board build is not checked here")  # fmt: skip
    r = subprocess.run(["make", "-C", str(FIRMWARE), "board-check"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "warning" not in r.stderr, r.stderr
    assert "teensy41_hal.cpp.o" in r.stdout and "rig_firmware.ino.o" in r.stdout


def _records(path: Path) -> list[str]:
    return [line for line in path.read_text().splitlines() if line[:1].isdigit()] if path.exists() else []


def _capture_cmd(kind: str, out: Path, link: Path) -> list[str]:
    cmd = [sys.executable, "-m", "difflattice.capture.cli", "capture", kind, str(out), "--port", str(link),
           "--freq-hz", str(F_HZ), "--n-avg", str(N_AVG), "--cycles", "16", "--temperature-c", str(T_C),
           "--transducer-id", "piston-38.4", "--operator", "test_firmware", "--no-progress"]  # fmt: skip
    if kind == "lobe":
        return cmd + ["--start-deg", "-90", "--stop-deg", "90", "--step-deg", "1", "--range-m", "1"]
    return cmd + ["--x0-mm", "-24", "--x1-mm", "24", "--dx-mm", "1", "--z-mm", "16.5"]


def _capture_killed_then_resumed(kind: str, out: Path, link: Path, kill_after: int) -> list[str]:
    """Run the capture command, SIGKILL it once the file holds `kill_after` points, re-run it to the end.
    Returns the records present at the kill."""
    cmd = _capture_cmd(kind, out, link)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while len(_records(out)) < kill_after:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the capture made no progress"
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    before = _records(out)
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return before


@pytest.fixture(scope="module")
def captures(build: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    tmp = tmp_path_factory.mktemp("firmware")
    truth = _load_truth_tool().write_truth(tmp / "truth.txt", PISTON, freq_hz=F_HZ, temperature_c=T_C)
    link = tmp / "rig"
    sim = subprocess.Popen(
        [
            str(build),
            "--truth",
            str(truth),
            "--link",
            str(link),
            "--speed",
            "50",
            "--seed",
            "7",
            "--reset-at",
            str(RESET_AT),
        ],  # fmt: skip
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert sim.stdout is not None
        assert sim.stdout.readline().strip() == str(link), sim.communicate()
        lobe_before = _capture_killed_then_resumed("lobe", tmp / "lobe.csv", link, KILL_LOBE_AT)
        wave_before = _capture_killed_then_resumed("wave", tmp / "wave.csv", link, KILL_WAVE_AT)
        yield {
            "dir": tmp,
            "lobe": load_capture(tmp / "lobe.csv"),
            "wave": load_capture(tmp / "wave.csv"),
            "lobe_before": lobe_before,
            "wave_before": wave_before,
        }
    finally:
        sim.terminate()
        _, err = sim.communicate(timeout=10)
    assert sim.returncode == 0 and "warning" not in err, err
    assert not link.exists()


def _exactly_once(cap: Capture, path: Path, before: list[str], n: int) -> None:
    after = _records(path)
    seqs = [int(r.split(",")[0]) for r in after]
    assert len(after) == n and sorted(seqs) == list(range(n)), "points lost or duplicated"
    assert after[: len(before)] == before  # nothing written before the kill was changed
    assert cap.complete and not cap.missing
    np.testing.assert_array_equal(np.sort(cap.seq), np.arange(n))


def test_lobe_scan_with_reset_and_kill_loses_and_duplicates_nothing(captures: dict) -> None:
    cap, path = captures["lobe"], captures["dir"] / "lobe.csv"
    _exactly_once(cap, path, captures["lobe_before"], 181)
    assert len(captures["lobe_before"]) >= KILL_LOBE_AT
    assert any("rig reset" in e for e in cap.events), cap.events  # the firmware's watchdog reset at seq 80
    assert any(f"resumed with {len(captures['lobe_before'])} of 181 points" in e for e in cap.events), cap.events
    log = path.with_suffix(".log").read_text()
    assert "$BOOT,1.0.0-sim," in log and ",WDT*" in log  # BOOT after the reset, reason watchdog
    assert cap.metadata["fw_version"] == "1.0.0-sim" and cap.metadata["rig_id"] == "DL-SIM-0001"


def test_wave_scan_with_kill_loses_and_duplicates_nothing(captures: dict) -> None:
    cap, path = captures["wave"], captures["dir"] / "wave.csv"
    _exactly_once(cap, path, captures["wave_before"], 49)
    assert any("resumed with" in e for e in cap.events), cap.events


def test_readings_match_the_ground_truth(captures: dict) -> None:
    """Amplitudes within 5 of the rig's own standard errors of the truth (points well above the
    noise), and phase_mdeg the LAG of the truth's carrier (protocol "Field conventions") within 5
    standard errors of the per-burst jitter over n_avg bursts."""
    c = float(speed_of_sound(T_C))
    piston = Piston(D_M, PISTON["sensitivity_uV"])
    lobe = captures["lobe"]
    truth = np.abs(piston.at_range(lobe.columns["angle_mdeg"] / 1000, 1.0, F_HZ, c))
    se = lobe.columns["amp_sd_uV"] / math.sqrt(N_AVG)
    strong = truth > 2000.0  # 100 times the noise of one burst's lock-in: the noise is Gaussian there
    assert strong.sum() > 40
    z = (lobe.columns["amp_uV"] - truth)[strong] / np.maximum(se[strong], 1.0)
    assert np.max(np.abs(z)) < 5.0, z
    wave = captures["wave"]
    x_m = wave.columns["x_um"] * 1e-6
    p = piston.near_field(x_m, 0.0165, F_HZ, c)
    d = (wave.columns["phase_mdeg"] / 1000 - lag_deg(p) + 180.0) % 360.0 - 180.0
    assert np.max(np.abs(d)) < 5 * PHASE_JITTER_DEG / math.sqrt(N_AVG), d
    rel = wave.columns["amp_uV"] / np.abs(p) - 1
    assert np.max(np.abs(rel)) < 5 * 0.005 / math.sqrt(N_AVG) + 0.001, rel
    # tof_ns: the half-peak crossing of the envelope, after the first arrival by the rise time
    # (tau ln 2 with tau = 1 period in rig-sim) and no earlier than the arrival itself
    late = wave.columns["tof_ns"] * 1e-9 - piston.arrival_s(x_m, 0.0165, c)
    assert np.all(late > 0) and np.all(late < 2.0 / F_HZ), late


def test_captured_scans_fit_to_the_simulated_diameter(captures: dict) -> None:
    """The project's fit entry (disc model, lobe + wavefront, quick resolution) on the captured
    files: the fitted diameter within its quoted total uncertainty of the simulated 38.4 mm."""
    from difflattice.apps.fitting import run_fit
    from difflattice.fit.config import load_config

    tmp = captures["dir"]
    sigma = PHASE_JITTER_DEG / math.sqrt(N_AVG)
    (tmp / "fit.toml").write_text(
        '[data]\nlobe = "lobe.csv"\nwave = "wave.csv"\n\n'
        '[model]\nmodel = "disc"\nline_length_m = 0.042\ncells_per_wavelength = 20.0\n'
        'weights = "uniform"\nlags = "uniform"\nfit_diameter = true\n\n'
        f'[solver]\nname = "levenberg_marquardt"\nfloor_db = 40.0\nwave_sigma_deg = {sigma:.4f}\n\n'
        "[output]\nfield_image = false\n"
    )
    rep = run_fit(load_config(tmp / "fit.toml"), out=tmp / "fit", quick=True, verbose=False)
    assert rep["fit"]["converged"], rep["fit"]["warnings"]
    d = next(e for e in rep["budget"]["scalars"] if e["name"] == "diameter_mm")
    print(f"fitted D = {d['value']:.4f} mm +- {d['total']:.4f} (stat {d['stat']:.4f}, sys {d['systematic']:.4f})")
    assert d["status"] == "determined" and 0 < d["total"] < 0.1, d
    assert abs(d["value"] - D_M * 1e3) <= d["total"], d


class _Link:
    """The test's own end of the firmware's pty: raw lines out, strictly parsed messages in."""

    def __init__(self, path: Path) -> None:
        import serial

        self.ser = serial.Serial(str(path), 115_200, timeout=0.02, exclusive=True)
        self.buffer = P.LineBuffer()
        self.seen: list[P.Message] = []

    def send(self, line: bytes | P.Message) -> None:
        self.ser.write(line if isinstance(line, bytes) else P.encode(line))

    def expect(self, want, timeout_s: float = 5.0) -> P.Message:
        """The first message satisfying `want`; every line on the way must be a valid, canonical frame."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for item in self.buffer.feed(self.ser.read(self.ser.in_waiting or 1)):
                assert isinstance(item, P.Frame), f"the firmware sent a bad line: {item}"
                msg = P.parse(item.raw)
                assert P.encode(msg) == item.raw  # canonical: re-encoding gives the same bytes
                self.seen.append(msg)
                if want(msg):
                    return msg
        raise AssertionError(f"no matching message within {timeout_s} s; seen: {self.seen[-5:]}")


def _err(code: str, detail: str | None = None):
    return lambda m: isinstance(m, P.Err) and m.code == code and (detail is None or m.detail == detail)


def test_firmware_answers_every_command_and_error_as_the_protocol_says(build: Path, tmp_path: Path) -> None:
    truth = _load_truth_tool().write_truth(tmp_path / "truth.txt", PISTON, freq_hz=F_HZ, temperature_c=T_C)
    link = tmp_path / "rig"
    sim = subprocess.Popen(
        [str(build), "--truth", str(truth), "--link", str(link), "--speed", "20"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert sim.stdout is not None and sim.stdout.readline().strip() == str(link)
        rig = _Link(link)
        rig.send(P.Hello(1))
        idn = rig.expect(lambda m: isinstance(m, P.Idn))
        assert isinstance(idn, P.Idn) and (idn.proto, idn.homed, idn.state) == (1, False, "IDLE")
        lobe = P.Lobe(5, 0, 300, -15_000, 100, 2, 16, F_HZ)  # long enough to act on while it runs
        rig.send(lobe)
        rig.expect(_err("NOTHOMED", "LOBE"))
        rig.send(P.frame(b"STAT")[:-3] + b"00\n")  # bad CRC
        rig.expect(_err("BADCRC"))
        rig.send(b"\x00\xffjunk$STAT*")  # junk, then a truncated line with a whole one glued on
        rig.send(P.encode(P.Stat()))
        rig.expect(lambda m: isinstance(m, P.Hbt) and m.state == "IDLE")
        rig.send(b"$" + b"A" * 130 + b"\n")
        rig.expect(_err("TOOLONG"))
        rig.send(P.frame(b"FROB,1"))
        rig.expect(_err("BADCMD", "FROB"))
        rig.send(P.frame(b"LOBE,5,0,30"))
        rig.expect(_err("BADARG", "LOBE"))
        rig.send(P.frame(b"LOBE,5,00,30,-15000,1000,2,16,50000"))  # not a canonical integer
        rig.expect(_err("BADARG", "LOBE"))
        rig.send(P.Abort(9))  # while idle
        rig.expect(lambda m: isinstance(m, P.End) and (m.scan, m.n_sent, m.status) == (9, 0, "ABORTED"))
        rig.send(P.Home())
        rig.expect(lambda m: isinstance(m, P.Ack) and m.command == "HOME", timeout_s=20)
        rig.send(P.Lobe(5, 0, 30, -15_000, 10_000, 2, 16, F_HZ))  # ends at 275 deg
        rig.expect(_err("LIMIT", "LOBE"))
        rig.send(P.Wave(6, 0, 5, 0, 1000, 600_000, 2, 16, F_HZ))  # z beyond the stage
        rig.expect(_err("LIMIT", "WAVE"))
        rig.send(P.Lobe(5, 0, 30, -15_000, 1000, 2, 16, 200_000))  # carrier above 100 kHz
        rig.expect(_err("BADARG", "LOBE"))
        rig.send(lobe)
        rig.expect(lambda m: isinstance(m, P.Ack) and m.command == "LOBE" and m.arg == 5)
        first = rig.expect(lambda m: isinstance(m, P.Lob))
        assert isinstance(first, P.Lob) and (first.scan, first.seq, first.angle_mdeg) == (5, 0, -15_000)
        rig.send(P.Home())
        rig.expect(_err("BUSY", "HOME"))
        rig.send(P.Wave(6, 0, 5, 0, 1000, 16_500, 2, 16, F_HZ))
        rig.expect(_err("BUSY", "WAVE"))
        rig.send(P.Stat())
        hbt = rig.expect(lambda m: isinstance(m, P.Hbt))
        assert isinstance(hbt, P.Hbt) and hbt.state == "SCAN" and hbt.scan == 5 and hbt.next_seq >= 1
        rig.send(P.Abort(4))  # another scan's id
        rig.expect(_err("BADARG", "ABORT"))
        rig.send(P.Abort(5))
        end = rig.expect(lambda m: isinstance(m, P.End) and m.scan == 5)
        assert isinstance(end, P.End) and end.status == "ABORTED" and 1 <= end.n_sent < 300
        sent = [m for m in rig.seen if isinstance(m, P.Lob)]
        assert [m.seq for m in sent] == list(range(end.n_sent))  # in order, none skipped
        assert all(m.angle_mdeg == -15_000 + 100 * m.seq for m in sent)
        rig.expect(lambda m: isinstance(m, P.Hbt) and m.state == "IDLE" and m.scan == 5, timeout_s=5)
        rig.ser.close()
    finally:
        sim.terminate()
        sim.communicate(timeout=10)
