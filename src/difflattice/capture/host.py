"""Host side of rig protocol v1 on pyserial, and the capture of whole scans into files.

:class:`RigHost` speaks the protocol (:mod:`difflattice.capture.protocol`): it matches replies
by type, never by order; keeps its own line buffer (pyserial's ``readline`` blocks per byte and
returns partial lines); treats 3 s without a byte as a dead link and reopens the port's stable
path until the rig is back; re-homes a rig that was reset; and resumes an interrupted scan from
the first missing point, re-requesting the points lost to bad lines. :func:`capture_lobe` and
:func:`capture_wave` run one scan into an append-only capture file
(:mod:`difflattice.capture.files`) with a raw log beside it; calling them again on an unfinished
file continues it. Nothing here imports JAX.
"""

from __future__ import annotations

import dataclasses
import random
import sys
import time
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import Any, Required, TypedDict, Unpack

from ..config import ConfigError, specs
from . import protocol as P
from .errors import CaptureFileError, PortBusy, ProtocolVersionError, RigError, RigTimeout
from .files import COLUMNS, HEADER_KEY, HEADER_KEYS, CaptureWriter, Measurement, describe_seqs, utc_now
from .groundtruth import speed_of_sound
from .link import LinkDown, LinkStats, RawLog, RigReset, SerialLink, Timeouts
from .plan import ScanPlan

MAX_REQUESTS_PER_POINT = 25


class RigHost:
    """A connection to one rig through its stable serial path.

    ``on_event(text)`` is told of link and rig events (resets, reconnects, re-requests).
    """

    def __init__(
        self,
        port: str | Path,
        *,
        timeouts: Timeouts = Timeouts(),
        log: RawLog | None = None,
        on_event: Callable[[str], None] | None = None,
    ) -> None:
        self.port = str(port)
        self.t = timeouts
        self.log = log
        self.on_event = on_event
        self.stats = LinkStats()
        self.info: P.Idn | None = None
        self._link = SerialLink(self.port, timeouts, log)
        self._backlog: deque[P.Frame | P.BadLine] = deque()
        self._plan: ScanPlan | None = None
        self._scan_id = -1
        self._have: set[int] = set()
        self._on_point: Callable[[P.Lob | P.Wav], None] = lambda msg: None
        self._last_point = 0.0

    # connection -----------------------------------------------------------------------------

    def connect(self) -> P.Idn:
        """Open the port and handshake; raises a :class:`RigError` subclass, never hangs."""
        self._link.open()
        try:
            return self._handshake(time.monotonic() + self.t.retries * self.t.reply_s + 0.01, self.t.retries)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        self._link.close()

    def __enter__(self) -> RigHost:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _event(self, text: str) -> None:
        if self.log:
            self.log.note(text)
        if self.on_event:
            self.on_event(text)

    def _handshake(self, deadline: float, tries: int | None = None) -> P.Idn:
        sent = 0
        while tries is None or sent < tries:
            self._link.send(P.Hello(P.PROTOCOL_VERSION))
            sent += 1
            msg = self._wait(
                min(deadline, time.monotonic() + self.t.reply_s),
                lambda m: isinstance(m, P.Idn) or (isinstance(m, P.Err) and m.detail == "HELLO"),
                watch_silence=False,
                boot_resets=False,
            )
            if isinstance(msg, P.Err) and msg.code in ("BADCMD", "BADARG"):
                raise ProtocolVersionError(
                    f"{self.port}: the rig answered HELLO,{P.PROTOCOL_VERSION} with ERR,{msg.code},{msg.detail}: "
                    f"it does not speak protocol {P.PROTOCOL_VERSION}; use matching firmware or host software"
                )
            if isinstance(msg, P.Idn):
                return self._identified(msg)
            if time.monotonic() >= deadline:
                break
        raise RigTimeout(self._silence_diagnosis(sent))

    def _silence_diagnosis(self, sent: int) -> str:
        if self._link.rx_bytes == 0:
            return (
                f"{self.port}: no answer from the rig ({sent} HELLO sent, nothing received). Check that "
                f"the rig is powered and connected and that this is its port."
            )
        return (
            f"{self.port}: no IDN answer to {sent} HELLO ({self._link.rx_bytes} bytes received, "
            f"{self.stats.bad_lines} bad lines): wrong port or baud rate, or firmware that does not speak "
            f"protocol {P.PROTOCOL_VERSION}."
        )

    def _identified(self, idn: P.Idn) -> P.Idn:
        old = self.info
        if old is not None:
            if idn.rig_id != old.rig_id:
                raise RigError(f"{self.port} now leads to rig {idn.rig_id}, not {old.rig_id}: reconnect the right rig")
            if idn.boot_id != old.boot_id:
                self.stats.resets += 1
                self._event(f"rig reset: boot_id {old.boot_id} -> {idn.boot_id}, homed={int(idn.homed)}")
        self.info = idn
        return idn

    def _reconnect(self, reason: str) -> None:
        self.stats.reconnects += 1
        self._event(f"link down ({reason}); reconnecting")
        t0 = time.monotonic()
        deadline = t0 + self.t.reconnect_s
        while True:
            self._link.close()
            self._backlog.clear()
            try:
                self._link.open()
            except PortBusy:
                raise
            except RigError:  # the path is gone or not ready yet: the rig is unplugged
                pass
            else:
                try:
                    self._handshake(deadline)
                    self._event(f"link back after {time.monotonic() - t0:.2f} s")
                    return
                except (RigTimeout, LinkDown):
                    pass
            if time.monotonic() >= deadline:
                raise RigTimeout(
                    f"{self.port}: the link went down ({reason}) and did not come back within "
                    f"{self.t.reconnect_s:g} s. The capture file keeps every point so far: reconnect the "
                    f"rig and re-run the same command to continue."
                )
            time.sleep(min(0.1, self.t.reply_s))

    # reading --------------------------------------------------------------------------------

    def _wait(
        self,
        deadline: float,
        want: Callable[[P.Message], bool],
        *,
        watch_silence: bool = True,
        boot_resets: bool = True,
    ) -> P.Message | None:
        """Handle incoming lines until one satisfies ``want`` (returned) or ``deadline`` (None).

        Points of the current scan are recorded whatever is awaited. Raises :class:`LinkDown` on
        a serial error or (``watch_silence``) silence, :class:`RigReset` on ``BOOT``
        (``boot_resets``), :class:`ProtocolVersionError` on an IDN of another version.
        """
        while True:
            while self._backlog:
                msg = self._dispatch(self._backlog.popleft())
                if msg is None:
                    continue
                if boot_resets and isinstance(msg, P.Boot):
                    raise RigReset(f"BOOT, boot_id {msg.boot_id}, reason {msg.reason}")
                if want(msg):
                    return msg
            now = time.monotonic()
            if now >= deadline:
                return None
            if watch_silence and now - self._link.last_rx > self.t.link_down_s:
                raise LinkDown(f"nothing received for {self.t.link_down_s:g} s")
            self._backlog.extend(self._link.read())

    def _dispatch(self, item: P.Frame | P.BadLine) -> P.Message | None:
        if isinstance(item, P.BadLine):
            if item.reason == "JUNK":
                self.stats.junk += 1
            else:
                self.stats.bad_lines += 1
            return None
        try:
            msg = P.parse_body(item.body)
        except P.FrameError:
            fields = item.body.split(b",")
            if fields[0] == b"IDN" and len(fields) > 1 and fields[1] != str(P.PROTOCOL_VERSION).encode():
                self._version_error(fields[1].decode("ascii", "replace"), "?")
            self.stats.bad_lines += 1
            return None
        if isinstance(msg, P.Idn) and msg.proto != P.PROTOCOL_VERSION:
            self._version_error(str(msg.proto), msg.fw_version)
        if isinstance(msg, (P.Lob, P.Wav)):
            self._point(msg)
        return msg

    def _version_error(self, proto: str, fw: str) -> None:
        raise ProtocolVersionError(
            f"{self.port}: the rig speaks protocol {proto} (firmware {fw}); this host speaks protocol "
            f"{P.PROTOCOL_VERSION}. Use difflattice for protocol {proto}, or firmware for protocol "
            f"{P.PROTOCOL_VERSION}."
        )

    def _point(self, msg: P.Lob | P.Wav) -> None:
        plan = self._plan
        if plan is None or msg.scan != self._scan_id:
            return
        if not (0 <= msg.seq < plan.n and plan.matches(msg)):
            self.stats.bad_lines += 1
            if self.log:
                self.log.note(f"rejected point at the wrong position: {msg}")
            return
        if msg.seq in self._have:
            self.stats.duplicates += 1
            return
        self._on_point(msg)
        self._have.add(msg.seq)
        self.stats.points += 1
        self._last_point = time.monotonic()

    # commands -------------------------------------------------------------------------------

    def _abort_running(self) -> None:
        """Stop whatever scan the rig is running (STAT tells which)."""
        for _ in range(self.t.retries):
            self._link.send(P.Stat())
            hbt = self._wait(time.monotonic() + self.t.reply_s, lambda m: isinstance(m, P.Hbt))
            if isinstance(hbt, P.Hbt) and hbt.state == "IDLE":
                break
            if isinstance(hbt, P.Hbt):
                running = hbt.scan
                self._link.send(P.Abort(running))
                end = self._wait(
                    time.monotonic() + self.t.reply_s,
                    lambda m: (
                        (isinstance(m, P.End) and m.scan == running) or (isinstance(m, P.Hbt) and m.state == "IDLE")  # noqa: B023
                    ),
                )
                if end is not None:
                    self._event(f"aborted the rig's running scan {running}")
                    break
        else:
            raise LinkDown("no answer to STAT/ABORT")
        assert self.info is not None
        self.info = dataclasses.replace(self.info, state="IDLE")

    def _home(self) -> None:
        """Home the axis (``HOME`` until ``ACK,HOME,0``; IDN's homed flag covers a lost ACK)."""
        assert self.info is not None
        deadline = time.monotonic() + self.t.home_s
        self._link.send(P.Home())
        while True:
            msg = self._wait(
                min(deadline, time.monotonic() + self.t.reply_s),
                lambda m: (
                    (isinstance(m, P.Ack) and m.command == "HOME")
                    or (isinstance(m, P.Err) and m.detail in ("HOME", "-"))
                    or isinstance(m, P.Idn)
                ),
            )
            if isinstance(msg, P.Ack) or (isinstance(msg, P.Idn) and msg.homed):
                break
            if isinstance(msg, P.Err):
                if msg.code == "LIMIT":
                    raise RigError(
                        f"{self.port}: homing failed (ERR,LIMIT,HOME): the axis did not find its home switch"
                    )
                if msg.code == "BUSY":
                    self._abort_running()
                self._link.send(P.Home())
            elif time.monotonic() >= deadline:
                raise RigTimeout(f"{self.port}: the rig did not finish homing within {self.t.home_s:g} s")
            elif msg is None:
                self._link.send(P.Hello(P.PROTOCOL_VERSION))  # IDN tells whether homing is done
        self.info = dataclasses.replace(self.info, homed=True)
        self._event("homed")

    def _run_command(self, cmd: P.Lobe | P.Wave) -> None:
        """Send one scan command and take its points until END (or the rig is idle again)."""
        ours = cmd.scan

        def started(m: P.Message) -> bool:
            return (
                (isinstance(m, P.Ack) and m.command == cmd.TYPE and m.arg == ours)
                or (isinstance(m, (P.Lob, P.Wav)) and m.scan == ours)
                or (isinstance(m, P.Hbt) and m.state == "SCAN" and m.scan == ours)
                or (isinstance(m, P.Err) and m.detail in (cmd.TYPE, "-"))
            )

        for _ in range(self.t.retries):
            self._link.send(cmd)
            msg = self._wait(time.monotonic() + self.t.reply_s, started)
            if msg is None or (isinstance(msg, P.Err) and msg.code in ("BADCRC", "MALFORMED", "TOOLONG")):
                continue
            if isinstance(msg, P.Err):
                if msg.code == "BUSY":
                    self._abort_running()
                    continue
                if msg.code == "NOTHOMED":
                    raise RigReset("the rig is not homed")
                raise RigError(
                    f"{self.port}: the rig refused {P.encode(cmd).decode().strip()} with ERR,{msg.code},{msg.detail}"
                    + (": positions outside the axis range" if msg.code == "LIMIT" else ": check the scan options")
                )
            break
        else:
            raise LinkDown(f"no answer to {cmd.TYPE} ({self.t.retries} sent)")
        progress = time.monotonic()
        next_seq = -1
        while True:
            msg = self._wait(
                time.monotonic() + self.t.reply_s,
                lambda m: isinstance(m, P.Hbt) or (isinstance(m, P.End) and m.scan == ours),
            )
            progress = max(progress, self._last_point)
            if isinstance(msg, P.End):
                if msg.status == "FAULT":
                    assert self.info is not None
                    self.info = dataclasses.replace(self.info, homed=False)
                    self._event(f"the rig ended scan {ours} with FAULT; re-homing")
                return
            if isinstance(msg, P.Hbt):
                if msg.state == "IDLE" or msg.scan != ours:
                    return  # END lost, or the rig was reset (BOOT lost)
                if msg.next_seq != next_seq:
                    next_seq, progress = msg.next_seq, time.monotonic()
            if time.monotonic() - progress > self.t.point_s:
                raise RigTimeout(f"{self.port}: the rig reports scanning but sent no point for {self.t.point_s:g} s")

    def run_scan(self, plan: ScanPlan, scan_id: int, have: set[int], on_point: Callable[[P.Lob | P.Wav], None]) -> None:
        """Collect every point of ``plan`` not in ``have`` (updated), calling ``on_point`` for each.

        Interrupted commands are resumed from the first missing point, lost points re-requested,
        a reset rig re-homed and a lost link reopened; a point requested more than
        ``MAX_REQUESTS_PER_POINT`` times is an error.
        """
        if self.info is None:
            raise RigError("connect() first")
        self._plan, self._scan_id, self._have, self._on_point = plan, scan_id, have, on_point
        requests: Counter[int] = Counter()
        sync = False
        try:
            while missing := [s for s in range(plan.n) if s not in have]:
                first, n = plan.next_request(missing)
                todo = [s for s in missing if s < n]
                again = [s for s in todo if requests[s]]
                if again:
                    self._event(f"re-requesting seq {describe_seqs(again)}")
                requests.update(todo)
                self.stats.rerequested = sum(1 for c in requests.values() if c > 1)
                if requests[first] > MAX_REQUESTS_PER_POINT:
                    raise RigError(
                        f"{self.port}: point {first} requested {MAX_REQUESTS_PER_POINT} times without success; "
                        f"the raw log {self.log.path if self.log else ''} shows what the rig answered"
                    )
                try:
                    if sync:
                        self._handshake(time.monotonic() + self.t.reconnect_s)
                        sync = False
                    if self.info.state == "SCAN":
                        self._abort_running()
                    if not self.info.homed:
                        self._home()
                    self._run_command(plan.command(scan_id, first, n))
                except LinkDown as exc:
                    self._reconnect(str(exc))
                except RigReset as exc:
                    self._event(f"rig reset or lost its home ({exc})")
                    sync = True
        finally:
            self._plan = None

    def abort(self, scan_id: int) -> None:
        """Best effort: tell the rig to stop ``scan_id`` (used when the operator interrupts)."""
        try:
            self._link.send(P.Abort(scan_id))
        except LinkDown:
            pass


# --------------------------------------------------------------------------------------------
# Capture into files
# --------------------------------------------------------------------------------------------

_SYSTEM_KEYS = ("format", "kind", "created_utc", "protocol", "rig_id", "fw_version", "boot_id", "scan_id")
_SCAN_KEYS = ("n_points", "start_mdeg", "step_mdeg", "x0_um", "dx_um", "z_um", "n_avg", "cycles", "freq_hz")
_LOADER_KEYS = ("start_deg", "step_deg", "stop_deg", "x0_m", "dx_m", "x1_m", "z_m")  # added by load_capture
_DERIVED_KEYS = ("speed_of_sound_m_s",) + _LOADER_KEYS
_MEASUREMENT_KEYS = tuple(s.name for s in specs(Measurement))


def normalise_metadata(kind: str, metadata: dict[str, Any]) -> dict[str, Any]:
    """Check measurement metadata and give it its header types; adds ``speed_of_sound_m_s``.

    ``temperature_c`` is required, and ``range_m`` for a lobe scan; the keys declared in
    :class:`files.Measurement` get their types and allowed ranges checked, other keys are kept as
    text. Raises ``ValueError`` naming the key, the value and what is allowed.
    """
    meta: dict[str, Any] = {}
    for key, value in metadata.items():
        if value is None:
            continue
        if key in _SYSTEM_KEYS or key in _SCAN_KEYS or key in _DERIVED_KEYS:
            raise ValueError(f"metadata key {key!r} is set by the capture itself")
        if not HEADER_KEY.match(key) or "\n" in str(value) or "\r" in str(value):
            raise ValueError(f"metadata key {key!r} must be lower_snake_case and its value one line")
        kind_of = HEADER_KEYS.get(key, (str, ""))[0]
        try:
            meta[key] = kind_of(value)
        except (TypeError, ValueError):
            raise ValueError(f"metadata {key!r} must be {kind_of.__name__}, got {value!r}") from None
    required = ("temperature_c", "range_m") if kind == "lobe" else ("temperature_c",)
    absent = [k for k in required if k not in meta]
    if absent:
        raise ValueError(f"metadata needs {', '.join(absent)} (see docs/capture.md)")
    declared = {k: meta[k] for k in _MEASUREMENT_KEYS if k in meta}
    try:
        Measurement(**declared)
    except ConfigError as exc:
        raise ValueError(f"metadata {exc}") from None
    meta["speed_of_sound_m_s"] = round(float(speed_of_sound(meta["temperature_c"])), 3)
    return meta


def _check_resume(path: Path, existing: dict[str, Any], wanted: dict[str, Any]) -> None:
    keys = (set(existing) | set(wanted)) - set(_SYSTEM_KEYS) - set(_LOADER_KEYS)
    diffs = [
        f"{k}: file {existing.get(k)!r}, now {wanted.get(k)!r}"
        for k in sorted(keys)
        if existing.get(k) != wanted.get(k)
    ]
    if existing["kind"] != wanted["kind"]:
        diffs.insert(0, f"kind: file {existing['kind']!r}, now {wanted['kind']!r}")
    if diffs:
        raise CaptureFileError(
            f"{path}: holds a scan with other parameters ({'; '.join(diffs)}). Re-run with the same options "
            f"to continue it, or capture to another file."
        )


class CaptureOptions(TypedDict, total=False):
    """The keyword options :func:`capture_lobe` and :func:`capture_wave` share.

    ``metadata`` (required): measurement metadata, ``temperature_c`` [degC] always and ``range_m``
    [m] for a lobe scan; optional keys in :class:`files.Measurement`. ``progress``: a progress bar
    on stderr (default False). ``timeout_s``: silence that means the link is down [s] (default 3;
    other timeouts scale with it, :meth:`Timeouts.scaled`). ``reconnect_s``: how long to wait for
    a lost link [s] (default 30).
    """

    metadata: Required[dict[str, Any]]
    progress: bool
    timeout_s: float
    reconnect_s: float


def _capture(
    port: str | Path,
    out_path: str | Path,
    plan: ScanPlan,
    *,
    metadata: dict[str, Any],
    progress: bool = False,
    timeout_s: float = 3.0,
    reconnect_s: float = 30.0,
) -> Path:
    """Capture ``plan`` into ``out_path``, continuing an unfinished file (options: :class:`CaptureOptions`)."""
    timeouts = Timeouts.scaled(timeout_s, reconnect_s)
    path = Path(out_path)
    if path.suffix != ".csv":
        raise ValueError(f"{path}: capture files end in .csv")
    meta = normalise_metadata(plan.kind, metadata)
    wanted = {"kind": plan.kind, **plan.header(), **meta}
    writer: CaptureWriter | None = None
    have: set[int] = set()
    scan_id, rig_id = 0, ""
    if path.exists():
        writer, existing = CaptureWriter.resume(path)
        try:
            _check_resume(path, existing.metadata, wanted)
        except CaptureFileError:
            writer.close()
            raise
        if existing.complete:
            writer.close()
            return path
        have = set(existing.seq.tolist())
        scan_id, rig_id = existing.metadata["scan_id"], existing.metadata["rig_id"]
    log_path = path.with_suffix(".log")
    new_log = not log_path.exists()
    log = RawLog(log_path)
    bar = None
    created = False  # this call created the file (so it may remove it again if it stays empty)
    appended = [0]
    done = False
    try:
        host = RigHost(port, timeouts=timeouts, log=log)
        with host:
            info = host.connect()
            if writer is None:
                scan_id = random.SystemRandom().randrange(1, 65536)
                header = {
                    "kind": plan.kind,
                    "created_utc": utc_now(),
                    "protocol": info.proto,
                    "rig_id": info.rig_id,
                    "fw_version": info.fw_version,
                    "boot_id": info.boot_id,
                    "scan_id": scan_id,
                    **plan.header(),
                    **meta,
                }
                writer = CaptureWriter.create(path, header)
                created = True
            elif info.rig_id != rig_id:
                raise CaptureFileError(f"{path}: was captured on rig {rig_id}, but {port} is rig {info.rig_id}")
            else:
                writer.event(f"resumed with {len(have)} of {plan.n} points; rig boot_id {info.boot_id}")
            if progress:
                from tqdm import tqdm

                bar = tqdm(
                    total=plan.n, initial=len(have), desc=path.name, unit="pt", file=sys.stderr, dynamic_ncols=True
                )
            w = writer

            def on_point(msg: P.Lob | P.Wav) -> None:
                w.append(tuple(getattr(msg, c) for c in COLUMNS[plan.kind][:-1]), time.time())
                appended[0] += 1
                if bar is not None:
                    bar.update(1)
                    s = host.stats
                    bar.set_postfix({"rereq": s.rerequested, "link": s.link_events, "bad": s.bad_lines}, refresh=False)

            host.on_event = writer.event
            try:
                host.run_scan(plan, scan_id, have, on_point)
            except KeyboardInterrupt:
                host.abort(scan_id)
                writer.event("interrupted by the operator")
                raise
            writer.finish()
            s = host.stats
            log.note(
                f"complete: {plan.n} points; {s.rerequested} re-requested, {s.bad_lines} bad lines, {s.junk} junk, "
                f"{s.duplicates} duplicates ignored, {s.resets} resets, {s.reconnects} reconnects"
            )
        done = True
    finally:
        if bar is not None:
            bar.close()
        log.close()
        empty = created and appended[0] == 0 and not done
        if writer is not None:
            writer.close()
            if empty:  # refused or failed before the first point: leave no header-only file behind
                path.unlink(missing_ok=True)
        if (writer is None or empty) and new_log:
            log_path.unlink(missing_ok=True)  # nothing captured: leave no stray log
    return path


def capture_lobe(
    port: str | Path,
    out_path: str | Path,
    *,
    start_deg: float,
    stop_deg: float,
    step_deg: float,
    n_avg: int,
    cycles: int,
    freq_hz: float,
    **options: Unpack[CaptureOptions],
) -> Path:
    """Capture a lobe pattern into ``out_path`` (``.csv``; raw log ``.log`` beside it).

    Angles [deg] from ``start_deg`` to ``stop_deg`` (inclusive, a whole number of ``step_deg``),
    ``n_avg`` bursts of ``cycles`` cycles at ``freq_hz`` [Hz, rounded to an integer] per point.
    ``options``: ``metadata`` (needs ``temperature_c`` [degC] and ``range_m`` [m]), ``progress``,
    ``timeout_s``, ``reconnect_s`` (:class:`CaptureOptions`). Calling it again on an unfinished
    file continues the scan; on a complete file it does nothing.
    """
    return _capture(port, out_path, ScanPlan.lobe(start_deg, stop_deg, step_deg, n_avg, cycles, freq_hz), **options)


def capture_wave(
    port: str | Path,
    out_path: str | Path,
    *,
    x0_m: float,
    x1_m: float,
    dx_m: float,
    z_m: float,
    n_avg: int,
    cycles: int,
    freq_hz: float,
    **options: Unpack[CaptureOptions],
) -> Path:
    """Capture a wavefront scan along x [m] from ``x0_m`` to ``x1_m`` by ``dx_m`` at distance
    ``z_m`` [m] from the face into ``out_path``; otherwise as :func:`capture_lobe`
    (``metadata`` needs ``temperature_c``)."""
    return _capture(port, out_path, ScanPlan.wave(x0_m, x1_m, dx_m, z_m, n_avg, cycles, freq_hz), **options)
