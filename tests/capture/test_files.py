"""Capture files: writer, loader, pandas, malformed and incomplete files, torn tails, locking."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from difflattice.capture.errors import CaptureFileError
from difflattice.capture.files import COLUMNS, CaptureWriter, is_capture_file, load_capture, load_lobe_table

LOBE_HEADER = {
    "kind": "lobe",
    "created_utc": "2025-01-01T00:00:00.000Z",
    "protocol": 1,
    "rig_id": "EMU-0001",
    "fw_version": "0.3.1-emu",
    "boot_id": 13903,
    "scan_id": 7,
    "n_points": 5,
    "start_mdeg": -2000,
    "step_mdeg": 1000,
    "n_avg": 8,
    "cycles": 16,
    "freq_hz": 40000,
    "range_m": 1.0,
    "temperature_c": 21.5,
    "speed_of_sound_m_s": 344.1,
    "operator": "007",
}
WAVE_HEADER = {**LOBE_HEADER, "kind": "wave", "n_points": 3, "x0_um": -500, "dx_um": 500, "z_um": 16500}
for key in ("start_mdeg", "step_mdeg", "range_m"):
    del WAVE_HEADER[key]


def lobe_row(seq: int) -> tuple[int, ...]:
    return (seq, -2000 + 1000 * seq, 1000 + seq, 10, 2906203, 2149)


def write_lobe(path: Path, seqs: list[int], *, finish: bool) -> Path:
    with CaptureWriter.create(path, LOBE_HEADER) as w:
        for s in seqs:
            w.append(lobe_row(s), 1700000000.0 + s)
        w.event("rig reset: boot_id 1 -> 2")
        if finish:
            w.finish()
    return path


def test_lobe_round_trip_and_pandas(tmp_path: Path) -> None:
    path = write_lobe(tmp_path / "lobe.csv", [3, 0, 1, 4, 2], finish=True)
    cap = load_capture(path)
    assert cap.kind == "lobe" and cap.complete and cap.missing == ()
    np.testing.assert_array_equal(cap.seq, range(5))
    np.testing.assert_allclose(cap.angle_deg, [-2, -1, 0, 1, 2])
    np.testing.assert_allclose(cap.amp_uV, [1000, 1001, 1002, 1003, 1004])
    np.testing.assert_allclose(cap.tof_s, 2906203e-9)
    np.testing.assert_allclose(cap.temp_c, 21.49)
    assert cap.metadata["operator"] == "007" and cap.metadata["temperature_c"] == 21.5
    assert cap.metadata["stop_deg"] == 2.0 and cap.events[0].endswith("rig reset: boot_id 1 -> 2")
    frame = pd.read_csv(path, comment="#")
    assert list(frame.columns) == list(COLUMNS["lobe"]) and len(frame) == 5


def test_wave_round_trip(tmp_path: Path) -> None:
    with CaptureWriter.create(tmp_path / "w.csv", WAVE_HEADER) as w:
        for s in range(3):
            w.append((s, -500 + 500 * s, 16500, 48000, (0, 359_999, 270_000)[s], 60000, 2100), 1.0)
        w.finish()
    cap = load_capture(tmp_path / "w.csv")
    np.testing.assert_allclose(cap.x_m, [-5e-4, 0, 5e-4])
    np.testing.assert_allclose(cap.z_m, 0.0165)
    np.testing.assert_allclose(cap.phase_deg, [0, 359.999, 270])  # the rig's lag, [0, 360) deg
    assert cap.metadata["z_m"] == pytest.approx(0.0165)


@pytest.mark.parametrize("phase_mdeg", [-1, -90_000, 360_000])
def test_phase_outside_one_period_is_refused(tmp_path: Path, phase_mdeg: int) -> None:
    """phase_mdeg is the lag in [0, 360000) (rig protocol, "Field conventions"): a file with
    other values (e.g. the emulator's -arg p in [-180, 180) deg before 2026-11-23) is refused,
    not silently read with the wrong sign."""
    with CaptureWriter.create(tmp_path / "w.csv", WAVE_HEADER) as w:
        for s in range(3):
            w.append((s, -500 + 500 * s, 16500, 48000, phase_mdeg if s == 1 else 1000, 60000, 2100), 1.0)
        w.finish()
    with pytest.raises(CaptureFileError, match=rf"w.csv:\d+: phase_mdeg {phase_mdeg} outside \[0, 360000\)"):
        load_capture(tmp_path / "w.csv")


def test_plain_lobe_table(tmp_path: Path) -> None:
    """A digitised datasheet pattern: optional header (either column order), comments, any of
    comma/semicolon/tab/space; errors name file and line."""
    path = tmp_path / "sheet.csv"
    path.write_text("# digitised from a datasheet\nlevel_db;angle_deg\n0;0\n-3.5;10\n\n-12\t20\n")
    t = load_lobe_table(path)
    np.testing.assert_allclose(t.angle_deg, [0, 10, 20])
    np.testing.assert_allclose(t.level_db, [0, -3.5, -12])
    assert not is_capture_file(path) and is_capture_file(write_lobe(tmp_path / "c.csv", [0], finish=False))
    path.write_text("angle_deg,level_db\n0,0\n10,-3\n200,-9\n")  # issue 27: the header names the units
    with pytest.raises(CaptureFileError, match=r"sheet.csv:4: angle 200 deg outside \[-180, 180\]"):
        load_lobe_table(path)
    path.write_text("angle_deg,level_db\n0,0\n10,-3\n")
    with pytest.raises(CaptureFileError, match="at least 3 rows"):
        load_lobe_table(path)


def test_incomplete_file(tmp_path: Path) -> None:
    path = write_lobe(tmp_path / "lobe.csv", [0, 1, 3], finish=False)
    with pytest.raises(CaptureFileError, match=r"lobe.csv: incomplete: 3 of 5 points, seq 2, 4 missing"):
        load_capture(path)
    with pytest.warns(UserWarning, match="seq 2, 4 missing"):
        cap = load_capture(path, allow_incomplete=True)
    assert not cap.complete and cap.missing == (2, 4)


def test_resume_repairs_torn_tail(tmp_path: Path) -> None:
    path = write_lobe(tmp_path / "lobe.csv", [0, 1], finish=False)
    with open(path, "ab") as f:
        f.write(b"2,0,10")
    with pytest.raises(CaptureFileError, match=r"lobe.csv:\d+: torn last line"):
        load_capture(path)
    writer, cap = CaptureWriter.resume(path)
    with writer:
        assert cap.missing == (2, 3, 4)
        for s in (2, 3, 4):
            writer.append(lobe_row(s), 1.0)
        writer.finish()
    cap = load_capture(path)
    assert cap.complete and "repaired torn last line" in cap.events[-1]


def test_writer_locks_and_never_clobbers(tmp_path: Path) -> None:
    path = write_lobe(tmp_path / "lobe.csv", [0], finish=False)
    with pytest.raises(CaptureFileError, match="exists already"):
        CaptureWriter.create(path, LOBE_HEADER)
    writer, _ = CaptureWriter.resume(path)
    with writer, pytest.raises(CaptureFileError, match="another capture is writing"):
        CaptureWriter.resume(path)


def _corrupt(tmp_path: Path, old: str, new: str) -> Path:
    path = write_lobe(tmp_path / "lobe.csv", [0, 1, 2, 3, 4], finish=True)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    ("old", "new", "problem"),
    [
        ("# format: difflattice-capture/1", "# format: other", r":1: not a capture file"),
        ("# boot_id: 13903\n", "", r":\d+: header lacks boot_id"),
        ("# n_avg: 8", "# n_avg: eight", r":\d+: header 'n_avg' must be int"),
        ("seq,angle_mdeg", "seq,angle_deg", r":\d+: expected the column line"),
        ("1,-1000,1001", "0,-2000,1001", r":\d+: duplicate seq 0 \(first at line \d+\)"),
        ("1,-1000,1001", "1,-1500,1001", r":\d+: seq 1: angle_mdeg should be \(-1000,\)"),
        ("1,-1000,1001,10", "1,-1000,1001", r":\d+: expected 7 fields"),
        ("1,-1000,1001", "1,-1000,1x01", r":\d+: fields must be integers"),
        ("1,-1000,1001", "1,-1000,1011", r":\d+: records do not match the trailer's crc32"),
        ("1,-1000,1001,10,2906203,2149,1700000001.000\n", "", r":\d+: trailer says complete but seq 1 missing"),
        ("# complete: n_points=5", "# complete: n_points=6", r":\d+: trailer says complete"),
    ],
)
def test_malformed_files_name_file_line_and_problem(tmp_path: Path, old: str, new: str, problem: str) -> None:
    path = _corrupt(tmp_path, old, new)
    with pytest.raises(CaptureFileError, match=r"lobe\.csv" + problem):
        load_capture(path, allow_incomplete=True)


def test_text_after_trailer(tmp_path: Path) -> None:
    path = write_lobe(tmp_path / "lobe.csv", [0, 1, 2, 3, 4], finish=True)
    with open(path, "a") as f:
        f.write("5,3000,1,1,1,1,1.000\n")
    with pytest.raises(CaptureFileError, match=r"lobe\.csv:\d+: text after the '# complete:' trailer"):
        load_capture(path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(CaptureFileError, match="nope.csv: cannot read"):
        load_capture(tmp_path / "nope.csv")
