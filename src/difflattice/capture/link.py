"""The rig's serial link: exclusive open, raw reads through a line buffer, a raw log of every
line, and the host's timing. :class:`difflattice.capture.host.RigHost` speaks the protocol over
it. Nothing here imports JAX."""

from __future__ import annotations

import errno
import time
from dataclasses import dataclass
from pathlib import Path

import serial

from . import protocol as P
from .errors import PortBusy, PortNotFound, RigError
from .files import utc_now

BAUD = 115_200


@dataclass(frozen=True)
class Timeouts:
    """Host timing [s].

    ``link_down_s``: total silence that means the link is down (protocol: 3 s). ``reply_s``: wait
    for the reply to a command before sending it again. ``retries``: HELLOs sent when first
    connecting, and sends of any command the rig does not acknowledge. ``reconnect_s``: how long
    to try to get a lost link back. ``home_s``: homing time limit. ``point_s``: longest wait for
    the next point while the rig reports that it is scanning. ``poll_s``: read granularity.
    """

    link_down_s: float = 3.0
    reply_s: float = 1.0
    retries: int = 3
    reconnect_s: float = 30.0
    home_s: float = 60.0
    point_s: float = 60.0
    poll_s: float = 0.02

    @classmethod
    def scaled(cls, timeout_s: float = 3.0, reconnect_s: float = 30.0) -> Timeouts:
        """Timeouts derived from the link-down silence ``timeout_s`` (the defaults at 3 s)."""
        return cls(
            link_down_s=timeout_s,
            reply_s=timeout_s / 3,
            reconnect_s=reconnect_s,
            home_s=20 * timeout_s,
            point_s=20 * timeout_s,
            poll_s=min(0.02, timeout_s / 30),
        )


@dataclass
class LinkStats:
    """Counters of a capture session."""

    points: int = 0
    rerequested: int = 0
    bad_lines: int = 0
    junk: int = 0
    duplicates: int = 0
    resets: int = 0
    reconnects: int = 0

    @property
    def link_events(self) -> int:
        return self.resets + self.reconnects


class LinkDown(Exception):
    """The link failed (serial error or silence); the host reopens the port."""


class RigReset(Exception):
    """The rig was reset or lost its home; the host handshakes and re-homes."""


class RawLog:
    """A timestamped log of every line sent (``>``) and received (``<``; bad ones ``<!``) and of
    link events (``**``); bytes that are not printable ASCII are written as ``\\xNN``."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._f = open(self.path, "a", encoding="ascii", buffering=1)

    @staticmethod
    def _escape(raw: bytes) -> str:
        return "".join(chr(b) if 32 <= b < 127 and b != 92 else f"\\x{b:02x}" for b in raw)

    def write(self, tag: str, raw: bytes) -> None:
        """Log one line (its final newline left out)."""
        text = self._escape(raw[:-1] if raw.endswith(b"\n") else raw)
        self._f.write(f"{utc_now()} {tag} {text}\n")

    def note(self, text: str) -> None:
        self._f.write(f"{utc_now()} ** {text}\n")

    def close(self) -> None:
        self._f.close()


class SerialLink:
    """The serial port: exclusive open, raw reads through a :class:`protocol.LineBuffer`."""

    def __init__(self, port: str, timeouts: Timeouts, log: RawLog | None) -> None:
        self.port = port
        self.t = timeouts
        self.log = log
        self.ser: serial.Serial | None = None
        self.buffer = P.LineBuffer()
        self.last_rx = time.monotonic()
        self.rx_bytes = 0

    def open(self) -> None:
        port = self.port
        try:
            self.ser = serial.Serial(
                port, BAUD, timeout=self.t.poll_s, write_timeout=self.t.link_down_s, exclusive=True
            )
        except serial.SerialException as exc:
            if exc.errno == errno.ENOENT:
                raise PortNotFound(
                    f"{port}: no such serial port. Is the rig plugged in and powered (or "
                    f"'difflattice rig emulate' running)? Use its stable path, e.g. under /dev/serial/by-id/."
                ) from None
            if exc.errno in (errno.EAGAIN, errno.EBUSY):
                raise PortBusy(
                    f"{port}: the port is in use by another process (another capture or a serial "
                    f"monitor); close it first ('fuser {port}' shows which)."
                ) from None
            if exc.errno == errno.EACCES:
                raise RigError(f"{port}: permission denied; add yourself to the 'dialout' group") from None
            raise RigError(f"{port}: cannot open the port: {exc}") from None
        self.buffer = P.LineBuffer()
        self.last_rx = time.monotonic()

    def close(self) -> None:
        if self.ser is not None:
            try:
                self.ser.close()
            except OSError:
                pass
            self.ser = None

    def send(self, msg: P.Message) -> None:
        line = P.encode(msg)
        if self.log:
            self.log.write(">", line)
        try:
            assert self.ser is not None
            self.ser.write(line)
        except (OSError, serial.SerialException) as exc:
            raise LinkDown(f"write failed: {exc}") from None

    def read(self) -> list[P.Frame | P.BadLine]:
        """Whatever arrives within ``poll_s``, as frames and bad lines."""
        try:
            assert self.ser is not None
            data = self.ser.read(self.ser.in_waiting or 1)
        except (OSError, serial.SerialException) as exc:
            raise LinkDown(f"read failed: {exc}") from None
        if not data:
            return []
        self.last_rx = time.monotonic()
        self.rx_bytes += len(data)
        items = self.buffer.feed(data)
        if self.log:
            for item in items:
                self.log.write("<" if isinstance(item, P.Frame) else f"<! {item.reason}", item.raw)
        return items
