"""Capture files: append-only CSV with a commented header, a completion trailer and a loader.

A capture file holds one scan. It is human-readable CSV that ``pandas.read_csv(path,
comment="#")`` loads as is::

    # format: difflattice-capture/1
    # kind: lobe
    # ... one "# key: value" line per header key (see ScanHeader, Measurement) ...
    seq,angle_mdeg,amp_uV,amp_sd_uV,tof_ns,temp_cC,t_unix_s
    0,-90000,61,33,2906203,2149,1732245600.123
    # event: 2025-11-22T03:00:01.5Z reset: boot_id 13903 -> 20441, re-homed
    ...
    # complete: n_points=181 crc32=1A2B3C4D

Records hold the rig's integers exactly as received (units in the column names) and the host
time of reception; they are in arrival order, each ``seq`` exactly once. Every record is one
``write`` followed by ``fsync``, so a crash loses no acknowledged point; a torn last line is
dropped when the scan is resumed. The trailer's ``crc32`` (CRC-32 of all record lines, in file
order, with their newlines) marks the scan complete. ``# event:`` lines record link events.

Header keys are declared once (:class:`ScanHeader`, :class:`Measurement`; the docs table and the
capture command's options are generated from them). ``phase_mdeg`` is the rig's lag of the
received carrier behind the drive in [0, 360000) (rig protocol, "Field conventions"); the loader
refuses other values rather than guess a convention. :func:`load_lobe_table` reads a plain
two-column lobe table whose header names the units (angle_deg | angle_rad, level_db |
level_linear | level_pa | level_v), e.g. a digitised datasheet pattern.
"""

from __future__ import annotations

import fcntl
import os
import re
import warnings
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from ..config import REQUIRED as CONFIG_REQUIRED
from ..config import Section, Spec, setting, specs
from .errors import CaptureFileError

FORMAT = "difflattice-capture/1"

COLUMNS: dict[str, tuple[str, ...]] = {
    "lobe": ("seq", "angle_mdeg", "amp_uV", "amp_sd_uV", "tof_ns", "temp_cC", "t_unix_s"),
    "wave": ("seq", "x_um", "z_um", "tof_ns", "phase_mdeg", "amp_uV", "temp_cC", "t_unix_s"),
}
"""Record columns by scan kind: the protocol's integers (units in the names), then host time."""

PHASE_PERIOD_MDEG = 360_000
"""`phase_mdeg` is the carrier's lag behind the drive reduced to [0, 360000) (rig protocol, "Field
conventions"); the loader refuses other values."""


@dataclass(frozen=True)
class ScanHeader(Section):
    """Header keys the capture writes itself, from the rig's `IDN` and the scan command."""

    SECTION: ClassVar[str] = "capture header"
    format: str = setting(kind="str", doc=f"file format, `{FORMAT}`")
    kind: str = setting(kind="str", choices=("lobe", "wave"), doc="scan kind")
    created_utc: str = setting(kind="str", doc="when the file was started, ISO 8601 UTC")
    protocol: int = setting(kind="int", ge=1, doc="rig protocol version")
    rig_id: str = setting(kind="str", doc="rig identity from IDN (a file is only continued on the same rig)")
    fw_version: str = setting(kind="str", doc="rig firmware version from IDN")
    boot_id: int = setting(kind="int", doc="rig boot id when the file was started (later ones: events)")
    scan_id: int = setting(kind="int", doc="scan number used on the wire for this file")
    n_points: int = setting(kind="int", ge=1, doc="points in the scan, seq 0..n_points-1")
    start_mdeg: int | None = setting(None, kind="int", unit="mdeg", doc="lobe: angle of seq 0 (lobe: required)")
    step_mdeg: int | None = setting(None, kind="int", unit="mdeg", doc="lobe: angle step (lobe: required)")
    x0_um: int | None = setting(None, kind="int", unit="um", doc="wave: x of seq 0 (wave: required)")
    dx_um: int | None = setting(None, kind="int", unit="um", doc="wave: x step (wave: required)")
    z_um: int | None = setting(
        None, kind="int", unit="um", doc="wave: distance of the scan line from the face (wave: required)"
    )
    n_avg: int = setting(kind="int", ge=1, doc="bursts averaged per point")
    cycles: int = setting(kind="int", ge=1, unit="cycles", doc="burst length")
    freq_hz: int = setting(
        kind="int", ge=1, unit="Hz", doc="drive frequency sent to the rig and used (the requested one rounded)"
    )
    speed_of_sound_m_s: float = setting(
        kind="number", gt=0, unit="m/s", doc="speed of sound used, 331.3 sqrt(1 + temperature_c/273.15), 3 decimals"
    )


@dataclass(frozen=True)
class Measurement(Section):
    """Measurement metadata the operator gives (`difflattice capture` options or `--meta`); any
    other `lower_snake_case` key is kept as text (e.g. `note`)."""

    SECTION: ClassVar[str] = "metadata"
    range_m: float | None = setting(
        None,
        kind="number",
        gt=0,
        le=100,
        unit="m",
        doc="microphone range from the centre of the face (lobe: required)",
        fix="measure it from the centre of the face to the microphone",
    )
    temperature_c: float = setting(
        kind="number",
        ge=-40,
        le=60,
        unit="degC",
        doc="air temperature (required)",
        fix="give the air temperature in degrees Celsius",
    )
    humidity_pct: float | None = setting(None, kind="number", ge=0, le=100, unit="%", doc="relative humidity")
    pressure_hpa: float | None = setting(None, kind="number", ge=300, le=1200, unit="hPa", doc="air pressure")
    transducer_id: str | None = setting(None, kind="str", doc="transducer under test")
    microphone: str | None = setting(None, kind="str", doc="measurement microphone")
    operator: str | None = setting(None, kind="str", doc="who measured")


_PY_TYPES = {"int": int, "number": float, "str": str, "bool": bool}
HEADER_SPECS: dict[str, Spec] = {s.name: s for cls in (ScanHeader, Measurement) for s in specs(cls)}
"""Every known header key's declaration (kind, unit, meaning); other keys are kept as text."""
HEADER_KEYS: dict[str, tuple[type, str]] = {
    k: (_PY_TYPES[s.kind], s.doc + (f" [{s.unit}]" if s.unit else "")) for k, s in HEADER_SPECS.items()
}
"""Known header keys: Python type and meaning (with unit), derived from `ScanHeader` and `Measurement`."""

REQUIRED: dict[str, tuple[str, ...]] = {
    "lobe": ("start_mdeg", "step_mdeg", "range_m"),
    "wave": ("x0_um", "dx_um", "z_um"),
}
COMMON_REQUIRED = tuple(s.name for cls in (ScanHeader, Measurement) for s in specs(cls) if s.default is CONFIG_REQUIRED)

_PHASE = COLUMNS["wave"].index("phase_mdeg")
HEADER_KEY = re.compile(r"[a-z][a-z0-9_]*\Z")
"""What a header key looks like (lower_snake_case)."""
_INT = re.compile(r"-?[0-9]+\Z")
_TIME = re.compile(r"[0-9]+\.[0-9]{3}\Z")
_TRAILER = re.compile(r"# complete: n_points=([0-9]+) crc32=([0-9A-F]{8})\Z")


def utc_now() -> str:
    """The current UTC time, ISO 8601 with milliseconds."""
    return datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def format_header(header: dict[str, Any]) -> bytes:
    """The header lines and the column line for ``header`` (``format`` and ``kind`` first)."""
    kind = header.get("kind")
    if kind not in COLUMNS:
        raise ValueError(f"header kind must be 'lobe' or 'wave', got {kind!r}")
    lines = []
    for key, value in {"format": FORMAT, **header}.items():
        text = str(value)
        if not HEADER_KEY.match(key) or "\n" in text or "\r" in text:
            raise ValueError(f"header key {key!r} must be lower_snake_case and its value one line")
        lines.append(f"# {key}: {text}\n")
    return ("".join(lines) + ",".join(COLUMNS[kind]) + "\n").encode()


def _fsync_dir(path: Path) -> None:
    fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class CaptureWriter:
    """Append records to a capture file, one ``write`` + ``fsync`` each, under an exclusive lock."""

    def __init__(self, path: Path, fd: int, kind: str, n_points: int, crc: int) -> None:
        self.path = path
        self.kind = kind
        self.n_points = n_points
        self._fd = fd
        self._crc = crc

    @staticmethod
    def _open_locked(path: Path) -> int:
        fd = os.open(path, os.O_RDWR | os.O_APPEND)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise CaptureFileError(
                f"{path}: another capture is writing this file; wait for it or use another path"
            ) from None
        return fd

    @classmethod
    def create(cls, path: str | Path, header: dict[str, Any]) -> CaptureWriter:
        """Create ``path`` with ``header`` atomically (the header is complete or absent)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as f:
            f.write(format_header(header))
            f.flush()
            os.fsync(f.fileno())
        try:
            os.link(tmp, path)  # fails if the file exists: never clobber a capture
        except FileExistsError:
            raise CaptureFileError(f"{path}: exists already; resume it or choose another path") from None
        finally:
            tmp.unlink()
        _fsync_dir(path)
        return cls(path, cls._open_locked(path), header["kind"], int(header["n_points"]), 0)

    @classmethod
    def resume(cls, path: str | Path) -> tuple[CaptureWriter, Capture]:
        """Open an existing capture for appending: drop a torn last line, return what it holds."""
        path = Path(path)
        fd = cls._open_locked(path)
        try:
            size = os.fstat(fd).st_size
            data = os.pread(fd, size, 0)
            keep = data.rfind(b"\n") + 1
            if keep < size:
                os.ftruncate(fd, keep)
                os.fsync(fd)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                capture = load_capture(path, allow_incomplete=True)
        except BaseException:
            os.close(fd)
            raise
        writer = cls(path, fd, capture.kind, int(capture.metadata["n_points"]), capture.records_crc32)
        if keep < size:
            writer.event(f"repaired torn last line: dropped {size - keep} bytes {data[keep:][:60]!r}")
        return writer, capture

    def _write(self, line: str) -> None:
        os.write(self._fd, line.encode())
        os.fsync(self._fd)

    def append(self, values: tuple[int, ...], t_unix_s: float) -> None:
        """Append one record (the integers of ``COLUMNS[kind]`` but the time) and fsync."""
        line = ",".join(map(str, values)) + f",{t_unix_s:.3f}\n"
        self._crc = zlib.crc32(line.encode(), self._crc)
        self._write(line)

    def event(self, text: str) -> None:
        """Record a link or rig event as a comment line."""
        self._write(f"# event: {utc_now()} {' '.join(text.split())}\n")

    def finish(self) -> None:
        """Write the trailer that marks the scan complete."""
        self._write(f"# complete: n_points={self.n_points} crc32={self._crc:08X}\n")

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> CaptureWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Capture:
    """A loaded capture file; arrays are sorted by ``seq``.

    ``metadata``: the typed header, plus derived values in SI units (lobe: ``start_deg``,
    ``step_deg``, ``stop_deg``; wave: ``x0_m``, ``dx_m``, ``x1_m``, ``z_m``). ``columns``: the raw
    record columns (file names and units). ``missing``: the seqs absent (empty when complete).
    ``events``: the ``# event:`` lines. ``records_crc32``: CRC-32 of the record lines so far.
    """

    path: Path
    kind: str
    metadata: dict[str, Any]
    columns: dict[str, NDArray[Any]]
    complete: bool
    missing: tuple[int, ...]
    events: tuple[str, ...]
    seq: NDArray[np.int64]
    t_unix_s: NDArray[np.float64]
    records_crc32: int


@dataclass(frozen=True)
class LobeCapture(Capture):
    """A lobe scan: angle [deg], amplitude and its sd [uV], time of flight [s], temperature [degC]."""

    angle_deg: NDArray[np.float64]
    amp_uV: NDArray[np.float64]
    amp_sd_uV: NDArray[np.float64]
    tof_s: NDArray[np.float64]
    temp_c: NDArray[np.float64]


@dataclass(frozen=True)
class WaveCapture(Capture):
    """A wavefront scan: position [m], arrival time [s], carrier phase [deg], amplitude [uV], temperature."""

    x_m: NDArray[np.float64]
    z_m: NDArray[np.float64]
    tof_s: NDArray[np.float64]
    phase_deg: NDArray[np.float64]
    amp_uV: NDArray[np.float64]
    temp_c: NDArray[np.float64]


def describe_seqs(seqs: list[int] | tuple[int, ...]) -> str:
    """Compact ranges of sequence numbers, e.g. ``"3, 7-9"``."""
    runs: list[list[int]] = []
    for s in sorted(seqs):
        if runs and s == runs[-1][1] + 1:
            runs[-1][1] = s
        else:
            runs.append([s, s])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def _parse_value(key: str, text: str, where: str) -> Any:
    kind = HEADER_KEYS.get(key, (str, ""))[0]
    try:
        return kind(text)
    except ValueError:
        raise CaptureFileError(f"{where}: header {key!r} must be {kind.__name__}, got {text!r}") from None


def load_capture(path: str | Path, *, allow_incomplete: bool = False) -> LobeCapture | WaveCapture:
    """Load and check a capture file.

    Raises :class:`CaptureFileError` naming the file, line and problem for a malformed file, and
    for an incomplete one unless ``allow_incomplete`` (then a warning says what is missing).
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise CaptureFileError(f"{path}: cannot read: {exc.strerror}") from None
    torn = b""
    if data and not data.endswith(b"\n"):
        cut = data.rfind(b"\n") + 1
        data, torn = data[:cut], data[cut:]
    try:
        lines = data.decode("ascii").split("\n")[:-1]
    except UnicodeDecodeError as exc:
        bad_line = data[: exc.start].count(b"\n") + 1
        raise CaptureFileError(f"{path}:{bad_line}: non-ASCII byte") from None

    def fail(lineno: int, problem: str) -> CaptureFileError:
        return CaptureFileError(f"{path}:{lineno}: {problem}")

    if not lines or lines[0] != f"# format: {FORMAT}":
        raise fail(1, f"not a capture file (the first line must be '# format: {FORMAT}')")
    meta: dict[str, Any] = {}
    i = 0
    while i < len(lines) and lines[i].startswith("#"):
        key, sep, value = lines[i][2:].partition(": ")
        if not (lines[i].startswith("# ") and sep and HEADER_KEY.match(key)):
            raise fail(i + 1, f"header lines are '# key: value', got {lines[i]!r}")
        if key in meta:
            raise fail(i + 1, f"header key {key!r} given twice")
        meta[key] = _parse_value(key, value, f"{path}:{i + 1}")
        i += 1
    kind = meta.get("kind")
    if kind not in COLUMNS:
        raise fail(i, f"header 'kind' must be lobe or wave, got {kind!r}")
    absent = [k for k in COMMON_REQUIRED + REQUIRED[kind] if k not in meta]
    if absent:
        raise fail(i + 1, f"header lacks {', '.join(absent)}")
    columns = COLUMNS[kind]
    if i >= len(lines) or lines[i] != ",".join(columns):
        raise fail(i + 1, f"expected the column line {','.join(columns)!r}")
    n_points = meta["n_points"]
    rows: dict[int, list[int]] = {}
    first_line: dict[int, int] = {}
    times: dict[int, float] = {}
    events: list[str] = []
    crc = 0
    trailer: tuple[int, str] | None = None
    for lineno, line in enumerate(lines[i + 1 :], start=i + 2):
        if trailer is not None:
            raise fail(lineno, "text after the '# complete:' trailer")
        if line.startswith("# event: "):
            events.append(line[len("# event: ") :])
            continue
        if line.startswith("# complete:"):
            trailer = (lineno, line)
            continue
        fields = line.split(",")
        if len(fields) != len(columns):
            raise fail(lineno, f"expected {len(columns)} fields ({','.join(columns)}), got {len(fields)}: {line!r}")
        if not all(_INT.match(f) for f in fields[:-1]) or not _TIME.match(fields[-1]):
            raise fail(lineno, f"fields must be integers and a time with 3 decimals: {line!r}")
        values = [int(f) for f in fields[:-1]]
        seq = values[0]
        if not 0 <= seq < n_points:
            raise fail(lineno, f"seq {seq} outside 0..{n_points - 1}")
        if seq in rows:
            raise fail(lineno, f"duplicate seq {seq} (first at line {first_line[seq]})")
        expected = _position(meta, kind, seq)
        if tuple(values[1 : 1 + len(expected)]) != expected:
            names = ",".join(columns[1 : 1 + len(expected)])
            raise fail(lineno, f"seq {seq}: {names} should be {expected}, got {tuple(values[1 : 1 + len(expected)])}")
        if kind == "wave" and not 0 <= values[_PHASE] < PHASE_PERIOD_MDEG:
            raise fail(
                lineno,
                f"phase_mdeg {values[_PHASE]} outside [0, {PHASE_PERIOD_MDEG}): the rig reports the "
                "carrier's lag behind the drive reduced to one period (rig protocol, Field conventions); "
                "files with negative phases come from the emulator before 2026-11-23 and have the opposite "
                "sign: capture them again",
            )
        rows[seq], first_line[seq], times[seq] = values, lineno, float(fields[-1])
        crc = zlib.crc32((line + "\n").encode(), crc)
    missing = tuple(s for s in range(n_points) if s not in rows)
    if trailer is not None:
        lineno, line = trailer
        m = _TRAILER.match(line)
        if not m:
            raise fail(lineno, f"trailer must be '# complete: n_points=N crc32=XXXXXXXX', got {line!r}")
        if int(m.group(1)) != n_points or missing:
            raise fail(lineno, f"trailer says complete but seq {describe_seqs(missing)} missing")
        if int(m.group(2), 16) != crc:
            raise fail(lineno, f"records do not match the trailer's crc32 (file edited or corrupted): {crc:08X}")
    if torn:
        problem = f"torn last line {torn[:40]!r} (an interrupted write)"
        if not allow_incomplete or trailer is not None:
            raise fail(len(lines) + 1, problem + "; re-run the capture command to repair and continue it")
        warnings.warn(f"{path}:{len(lines) + 1}: {problem} ignored", stacklevel=2)
    if trailer is None:
        problem = f"incomplete: {len(rows)} of {n_points} points, seq {describe_seqs(missing)} missing"
        if not allow_incomplete:
            raise CaptureFileError(
                f"{path}: {problem}; re-run the capture command to continue it, or load with allow_incomplete=True"
            )
        warnings.warn(f"{path}: {problem}", stacklevel=2)
    return _build(path, kind, meta, rows, times, trailer is not None, missing, events, crc)


def _position(meta: dict[str, Any], kind: str, seq: int) -> tuple[int, ...]:
    if kind == "lobe":
        return (meta["start_mdeg"] + seq * meta["step_mdeg"],)
    return (meta["x0_um"] + seq * meta["dx_um"], meta["z_um"])


def _build(
    path: Path,
    kind: str,
    meta: dict[str, Any],
    rows: dict[int, list[int]],
    times: dict[int, float],
    complete: bool,
    missing: tuple[int, ...],
    events: list[str],
    crc: int,
) -> LobeCapture | WaveCapture:
    names = COLUMNS[kind]
    order = sorted(rows)
    table = np.array([rows[s] for s in order], dtype=np.int64).reshape(len(order), len(names) - 1)
    times_s = np.array([times[s] for s in order], dtype=np.float64)
    raw: dict[str, NDArray[Any]] = {name: table[:, j] for j, name in enumerate(names[:-1])}
    raw["t_unix_s"] = times_s
    n = meta["n_points"]
    meta = dict(meta)
    if kind == "lobe":
        meta.update(
            start_deg=meta["start_mdeg"] / 1e3,
            step_deg=meta["step_mdeg"] / 1e3,
            stop_deg=(meta["start_mdeg"] + (n - 1) * meta["step_mdeg"]) / 1e3,
        )
    else:
        meta.update(
            x0_m=meta["x0_um"] * 1e-6,
            dx_m=meta["dx_um"] * 1e-6,
            x1_m=(meta["x0_um"] + (n - 1) * meta["dx_um"]) * 1e-6,
            z_m=meta["z_um"] * 1e-6,
        )
    # the `Capture` fields, in their order (positional, so that mypy checks each one's type)
    common = (path, kind, meta, raw, complete, missing, tuple(events), raw["seq"], times_s, crc)
    temp_c = _f64(raw["temp_cC"] / 100)
    tof_s = _f64(raw["tof_ns"] * 1e-9)
    if kind == "lobe":
        return LobeCapture(
            *common,
            angle_deg=_f64(raw["angle_mdeg"] / 1e3),
            amp_uV=_f64(raw["amp_uV"]),
            amp_sd_uV=_f64(raw["amp_sd_uV"]),
            tof_s=tof_s,
            temp_c=temp_c,
        )
    return WaveCapture(
        *common,
        x_m=_f64(raw["x_um"] * 1e-6),
        z_m=_f64(raw["z_um"] * 1e-6),
        tof_s=tof_s,
        phase_deg=_f64(raw["phase_mdeg"] / 1e3),
        amp_uV=_f64(raw["amp_uV"]),
        temp_c=temp_c,
    )


def _f64(values: NDArray[Any]) -> NDArray[np.float64]:
    """``values`` as float64 (integer columns scaled to SI units are float64 already: no copy)."""
    return np.asarray(values, dtype=np.float64)


# --------------------------------------------------------------------------------------------
# Plain lobe tables (no capture header)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LobeTable:
    """A plain two-column lobe table: angle [deg] and level [dB, any reference], e.g. a digitised
    datasheet beam pattern, converted from the units its header names (`units`: the two column
    names as written, e.g. ``("angle_rad", "level_linear")``). It carries no frequency, range,
    temperature or uncertainty: whoever uses it must state them. Rows in file order."""

    path: Path
    angle_deg: NDArray[np.float64]
    level_db: NDArray[np.float64]
    units: tuple[str, str] = ("angle_deg", "level_db")


ANGLE_UNITS = {"angle_deg": 1.0, "angle_rad": 180.0 / np.pi}
"""Accepted angle columns of a plain lobe table, with their factor to degrees."""
LEVEL_UNITS = ("level_db", "level_linear", "level_pa", "level_v")
"""Accepted level columns: dB (any reference), or an amplitude (dimensionless, Pa or V), read
as 20 log10 |value| (the fit's gain absorbs the reference)."""
LEVEL_FLOOR_REL = 1e-6
"""An amplitude column's zeros (a null of a digitised pattern) become this fraction of its largest
value (-120 dB re the peak: far below the fit's soft floor)."""

_SPLIT = re.compile(r"[,;\t ]+")


def is_capture_file(path: str | Path) -> bool:
    """True when ``path`` starts like a capture file (``# format: difflattice-capture/1``)."""
    try:
        with open(path, "rb") as f:
            return f.readline().rstrip(b"\r\n") == f"# format: {FORMAT}".encode()
    except OSError as exc:
        raise CaptureFileError(f"{path}: cannot read: {exc.strerror}") from None


def _table_units(
    path: Path, lineno: int, cells: list[str], first: Sequence[str], second: Sequence[str]
) -> tuple[tuple[int, int], tuple[str, str]]:
    """The column order and names of a plain table's header line (one name of `first`, one of
    `second`, either order), or a one-line error listing the accepted names."""
    names = [c.strip().lower() for c in cells]
    a = [i for i, n in enumerate(names) if n in first]
    b = [i for i, n in enumerate(names) if n in second]
    if len(a) != 1 or len(b) != 1:
        raise CaptureFileError(
            f"{path}:{lineno}: header {', '.join(cells)!s} does not name its two columns with their units; "
            f"accepted: {' | '.join(first)} and {' | '.join(second)} (e.g. {first[0]},{second[0]})"
        )
    return (a[0], b[0]), (names[a[0]], names[b[0]])


def _plain_table(
    path: str | Path, first: Sequence[str], second: Sequence[str]
) -> tuple[Path, NDArray[np.float64], tuple[str, str], list[int]]:
    """(path, rows as (n, 2) in the order (first, second), the header's unit names, the rows'
    line numbers) of a plain two-column table: a header line naming the columns with their units,
    then rows of two finite numbers (comma, semicolon, tab or spaces between them); ``#``
    comments and blank lines ignored."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise CaptureFileError(
            f"{path}: cannot read as a text table: {getattr(exc, 'strerror', None) or exc}"
        ) from None
    accepted = f"{' | '.join(first)} and {' | '.join(second)}"
    order: tuple[int, int] | None = None
    units = (first[0], second[0])
    rows: list[tuple[float, float]] = []
    lines: list[int] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        cells = [c for c in _SPLIT.split(line) if c]
        if len(cells) != 2:
            raise CaptureFileError(f"{path}:{lineno}: expected 2 columns ({accepted}), got {len(cells)}: {line!r}")
        try:
            a, b = float(cells[0]), float(cells[1])
        except ValueError:
            if order is not None:
                raise CaptureFileError(f"{path}:{lineno}: expected two numbers, got {line!r}") from None
            order, units = _table_units(path, lineno, cells, first, second)
            continue
        if order is None:
            raise CaptureFileError(
                f"{path}:{lineno}: no header line naming the columns' units before the first row; add one, "
                f"e.g. {first[0]},{second[0]} (accepted: {accepted})"
            )
        if not (np.isfinite(a) and np.isfinite(b)):
            raise CaptureFileError(f"{path}:{lineno}: non-finite value in {line!r}")
        rows.append(((a, b)[order[0]], (a, b)[order[1]]))
        lines.append(lineno)
    if len(rows) < 3:
        raise CaptureFileError(f"{path}: a table needs at least 3 rows of {units[0]}, {units[1]}; found {len(rows)}")
    return path, np.asarray(rows, dtype=float), units, lines


def load_lobe_table(path: str | Path) -> LobeTable:
    """Load a plain lobe table: a header line naming the two columns with their units (in either
    order: ``angle_deg`` or ``angle_rad``; ``level_db`` (any reference) or an amplitude
    ``level_linear``, ``level_pa``, ``level_v``, read as 20 log10 |value|), then rows of two
    numbers (comma, semicolon, tab or spaces between them); ``#`` comments and blank lines
    ignored.

    Raises :class:`CaptureFileError` naming the file and line for a missing header or a column
    name that is not an accepted unit (the accepted ones listed), a row that is not two finite
    numbers, an angle outside [-180, 180] deg, or fewer than 3 rows."""
    path, arr, units, lines = _plain_table(path, tuple(ANGLE_UNITS), LEVEL_UNITS)
    angle = arr[:, 0] * ANGLE_UNITS[units[0]]
    for ang, lineno in zip(angle, lines):
        if not -180.0 <= ang <= 180.0:
            raise CaptureFileError(f"{path}:{lineno}: angle {ang:g} deg outside [-180, 180]")
    level = arr[:, 1]
    if units[1] != "level_db":
        amp = np.abs(level)
        if not amp.max() > 0:
            raise CaptureFileError(f"{path}: the {units[1]} column is all zero: no level to fit")
        level = 20 * np.log10(np.maximum(amp, LEVEL_FLOOR_REL * amp.max()))
    return LobeTable(path=path, angle_deg=angle, level_db=level, units=units)


POSITION_UNITS = {"x_m": 1.0, "x_mm": 1e-3}
"""Accepted position columns of a plain wavefront table, with their factor to metres."""
PHASE_UNITS = ("phase_deg", "phase_mdeg", "delay_us")
"""Accepted phase columns: the LAG of the received carrier behind the drive (as the rig's
``phase_mdeg``: a later arrival has a larger lag) in degrees or millidegrees, or an arrival delay
in microseconds (lag = 360 f delay)."""


@dataclass(frozen=True)
class WaveTable:
    """A plain two-column wavefront table: lateral position x [m] and the carrier's lag behind the
    drive, either in degrees (`lag_deg`) or as a delay [s] (`delay_s`, lag = 360 f delay: the
    frequency comes from the caller); the other is None. `units` as the header names them."""

    path: Path
    x_m: NDArray[np.float64]
    lag_deg: NDArray[np.float64] | None
    delay_s: NDArray[np.float64] | None
    units: tuple[str, str]


def load_wave_table(path: str | Path) -> WaveTable:
    """Load a plain wavefront table: a header naming the columns with their units (``x_m`` or
    ``x_mm``; ``phase_deg``, ``phase_mdeg`` (the lag of the carrier behind the drive) or
    ``delay_us``), then rows of two numbers, as :func:`load_lobe_table`. Raises
    :class:`CaptureFileError` for a missing or unknown unit (the accepted ones listed)."""
    path, arr, units, _ = _plain_table(path, tuple(POSITION_UNITS), PHASE_UNITS)
    x = arr[:, 0] * POSITION_UNITS[units[0]]
    if units[1] == "delay_us":
        return WaveTable(path=path, x_m=x, lag_deg=None, delay_s=arr[:, 1] * 1e-6, units=units)
    lag = arr[:, 1] * (1e-3 if units[1] == "phase_mdeg" else 1.0)
    return WaveTable(path=path, x_m=x, lag_deg=lag, delay_s=None, units=units)
