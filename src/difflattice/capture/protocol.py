"""Rig serial protocol v1: framing, CRC, messages and a resynchronising line buffer.

A line is ``$<BODY>*<CRC>\\n`` with ``BODY = TYPE{,field}``; ``CRC`` is CRC-16/CCITT-FALSE
(poly 0x1021, init 0xFFFF, no reflection, no final xor) over the bytes of BODY, written as four
upper-case hex digits. A ``\\r`` before the ``\\n`` is tolerated. A whole line (``$`` to ``\\n``)
is at most :data:`MAX_LINE_BYTES` bytes. Numbers are decimal integers in fixed units: millidegrees
(``mdeg``), micrometres (``um``), nanoseconds (``ns``), microvolts (``uV``), hundredths of a degree
Celsius (``cC``) and hertz (``hz``).

Every message type of the protocol is a frozen dataclass below whose fields, in order, are the
fields of the line; :func:`encode` and :func:`parse` convert between them and bytes, strictly
(canonical decimal integers only, exact field counts, known enumerations), so that a line is
accepted only if re-encoding it gives back the same bytes.

This module is pure Python and imports neither numpy nor pyserial.
"""

from __future__ import annotations

import binascii
import dataclasses
import re
from dataclasses import dataclass
from typing import ClassVar, Literal, get_args, get_origin, get_type_hints

PROTOCOL_VERSION = 1
MAX_LINE_BYTES = 120
"""Longest line, ``$`` to ``\\n`` inclusive (an optional ``\\r`` before ``\\n`` is not counted)."""

_INT = re.compile(rb"-?(?:0|[1-9][0-9]*)\Z")
_TEXT = re.compile(rb"[\x20-\x7e]+\Z")
_HEX4 = re.compile(rb"[0-9A-F]{4}\Z")
_FORBIDDEN = frozenset(b"$*,")


def crc16(body: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``body`` (the check value of ``b"123456789"`` is ``0x29B1``)."""
    return binascii.crc_hqx(body, 0xFFFF)


class FrameError(ValueError):
    """A line that is not a valid v1 frame or message; ``code`` is the rig's ERR code for it."""

    def __init__(self, code: ErrCode, detail: str) -> None:
        super().__init__(f"{code}: {detail}")
        self.code: ErrCode = code
        self.detail = detail


# --------------------------------------------------------------------------------------------
# Messages
# --------------------------------------------------------------------------------------------

State = Literal["IDLE", "SCAN"]
BootReason = Literal["POR", "EXT", "BOR", "WDT", "UNK"]
EndStatus = Literal["OK", "ABORTED", "FAULT"]
ErrCode = Literal["BADCRC", "MALFORMED", "TOOLONG", "BADCMD", "BADARG", "BUSY", "NOTHOMED", "LIMIT"]
BadLineReason = ErrCode | Literal["JUNK"]
"""Why bytes were not a line: the rig's ERR code for a bad line, or ``JUNK`` (bytes outside a line)."""


@dataclass(frozen=True)
class Message:
    """Base class of all protocol messages; ``TYPE`` is the first field of the line body."""

    TYPE: ClassVar[str] = ""


# Host to rig ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Hello(Message):
    """``HELLO,<proto>``: handshake; the rig answers :class:`Idn`."""

    TYPE: ClassVar[str] = "HELLO"
    proto: int


@dataclass(frozen=True)
class Stat(Message):
    """``STAT``: ask for a heartbeat (:class:`Hbt`) now."""

    TYPE: ClassVar[str] = "STAT"


@dataclass(frozen=True)
class Home(Message):
    """``HOME``: home the axis; answered ``ACK,HOME,0`` when done."""

    TYPE: ClassVar[str] = "HOME"


@dataclass(frozen=True)
class Lobe(Message):
    """``LOBE``: lobe scan, points ``first_seq..n-1`` at angle ``start_mdeg + seq*step_mdeg``."""

    TYPE: ClassVar[str] = "LOBE"
    scan: int
    first_seq: int
    n: int
    start_mdeg: int
    step_mdeg: int
    n_avg: int
    cycles: int
    freq_hz: int


@dataclass(frozen=True)
class Wave(Message):
    """``WAVE``: wavefront scan, points ``first_seq..n-1`` at ``x0_um + seq*dx_um``, ``z_um``."""

    TYPE: ClassVar[str] = "WAVE"
    scan: int
    first_seq: int
    n: int
    x0_um: int
    dx_um: int
    z_um: int
    n_avg: int
    cycles: int
    freq_hz: int


@dataclass(frozen=True)
class Abort(Message):
    """``ABORT,<scan>``: stop scan ``scan``; answered ``END,<scan>,<n_sent>,ABORTED``."""

    TYPE: ClassVar[str] = "ABORT"
    scan: int


# Rig to host ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Idn(Message):
    """``IDN``: answer to HELLO: versions, identity, boot id, homed flag and state."""

    TYPE: ClassVar[str] = "IDN"
    proto: int
    fw_version: str
    rig_id: str
    boot_id: int
    homed: bool
    state: State


@dataclass(frozen=True)
class Boot(Message):
    """``BOOT``: sent after every reset (it may be lost)."""

    TYPE: ClassVar[str] = "BOOT"
    fw_version: str
    boot_id: int
    reason: BootReason


@dataclass(frozen=True)
class Hbt(Message):
    """``HBT``: heartbeat, whenever 1 s passed with no other line, and the answer to STAT."""

    TYPE: ClassVar[str] = "HBT"
    uptime_ms: int
    state: State
    scan: int
    next_seq: int


@dataclass(frozen=True)
class Lob(Message):
    """``LOB``: one lobe point (mean and sd of the envelope peak over ``n_avg`` bursts)."""

    TYPE: ClassVar[str] = "LOB"
    scan: int
    seq: int
    angle_mdeg: int
    amp_uV: int
    amp_sd_uV: int
    tof_ns: int
    temp_cC: int


@dataclass(frozen=True)
class Wav(Message):
    """``WAV``: one wavefront point (arrival time, carrier phase, amplitude)."""

    TYPE: ClassVar[str] = "WAV"
    scan: int
    seq: int
    x_um: int
    z_um: int
    tof_ns: int
    phase_mdeg: int
    amp_uV: int
    temp_cC: int


@dataclass(frozen=True)
class End(Message):
    """``END``: end of a scan command, with the number of points it sent."""

    TYPE: ClassVar[str] = "END"
    scan: int
    n_sent: int
    status: EndStatus


@dataclass(frozen=True)
class Err(Message):
    """``ERR,<code>,<detail>``: a refused or unreadable command."""

    TYPE: ClassVar[str] = "ERR"
    code: ErrCode
    detail: str


@dataclass(frozen=True)
class Ack(Message):
    """``ACK,<command>,<arg>``: ``ACK,HOME,0``, ``ACK,LOBE,<scan>`` or ``ACK,WAVE,<scan>``."""

    TYPE: ClassVar[str] = "ACK"
    command: str
    arg: int


MESSAGE_TYPES: dict[str, type[Message]] = {
    cls.TYPE: cls for cls in (Hello, Stat, Home, Lobe, Wave, Abort, Idn, Boot, Hbt, Lob, Wav, End, Err, Ack)
}
"""Every message class of protocol v1, by TYPE."""

AnyMessage = Hello | Stat | Home | Lobe | Wave | Abort | Idn | Boot | Hbt | Lob | Wav | End | Err | Ack

_FIELD_TYPES: dict[type[Message], tuple[tuple[str, object], ...]] = {
    cls: tuple((f.name, get_type_hints(cls)[f.name]) for f in dataclasses.fields(cls)) for cls in MESSAGE_TYPES.values()
}


def _format_field(value: object, kind: object) -> bytes:
    if kind is bool:
        return b"1" if value else b"0"
    if kind is int:
        if not isinstance(value, int) or isinstance(value, bool):
            raise TypeError(f"expected int, got {value!r}")
        return str(value).encode()
    text = str(value).encode("ascii")
    if get_origin(kind) is Literal and value not in get_args(kind):
        raise ValueError(f"{value!r} is not one of {get_args(kind)}")
    if not _TEXT.match(text) or _FORBIDDEN.intersection(text):
        raise ValueError(f"field {value!r} must be non-empty printable ASCII without '$', '*', ','")
    return text


def _parse_field(raw: bytes, kind: object, name: str) -> object:
    if kind is bool:
        if raw not in (b"0", b"1"):
            raise FrameError("BADARG", f"{name} must be 0 or 1, got {raw!r}")
        return raw == b"1"
    if kind is int:
        if not _INT.match(raw) or raw == b"-0":
            raise FrameError("BADARG", f"{name} must be a decimal integer, got {raw!r}")
        return int(raw)
    if not _TEXT.match(raw):
        raise FrameError("BADARG", f"{name} must be printable ASCII, got {raw!r}")
    text = raw.decode("ascii")
    if get_origin(kind) is Literal and text not in get_args(kind):
        raise FrameError("BADARG", f"{name} must be one of {get_args(kind)}, got {text!r}")
    return text


def body_of(msg: Message) -> bytes:
    """The BODY of ``msg``: ``TYPE{,field}``."""
    parts = [msg.TYPE.encode()]
    parts += [_format_field(getattr(msg, name), kind) for name, kind in _FIELD_TYPES[type(msg)]]
    return b",".join(parts)


def frame(body: bytes) -> bytes:
    """Frame a raw BODY as ``$BODY*CRC\\n`` (no validation of the body's fields)."""
    return b"$" + body + b"*" + f"{crc16(body):04X}".encode() + b"\n"


def encode(msg: Message) -> bytes:
    """The complete line for ``msg``; raises ``ValueError`` if it is longer than allowed."""
    line = frame(body_of(msg))
    if len(line) > MAX_LINE_BYTES:
        raise ValueError(f"{msg.TYPE} line is {len(line)} bytes, the protocol allows {MAX_LINE_BYTES}")
    return line


def unframe(line: bytes) -> bytes:
    """Check one line (``$`` .. ``\\n``) and return its BODY; raises :class:`FrameError`."""
    if line.endswith(b"\r\n"):
        line = line[:-2] + b"\n"
    if len(line) > MAX_LINE_BYTES:
        raise FrameError("TOOLONG", f"{len(line)} bytes")
    if not (line.startswith(b"$") and line.endswith(b"\n")):
        raise FrameError("MALFORMED", "a line is '$BODY*CRC\\n'")
    body, star, crc = line[1:-1].rpartition(b"*")
    if not star or not _HEX4.match(crc):
        raise FrameError("MALFORMED", "missing '*' and 4 upper-case hex CRC digits")
    if b"$" in body or b"*" in body:
        raise FrameError("MALFORMED", "'$' or '*' inside the body")
    if int(crc, 16) != crc16(body):
        raise FrameError("BADCRC", f"CRC {crc.decode()} != {crc16(body):04X}")
    return body


def split_body(body: bytes) -> tuple[str, list[bytes]]:
    """Split a BODY into its TYPE and raw fields."""
    kind, *fields = body.split(b",")
    if not re.fullmatch(rb"[A-Z]+", kind):
        raise FrameError("BADCMD", f"type {kind!r}")
    return kind.decode(), fields


def parse_body(body: bytes) -> AnyMessage:
    """Parse a checked BODY into its message; raises :class:`FrameError` (BADCMD or BADARG)."""
    kind, fields = split_body(body)
    cls = MESSAGE_TYPES.get(kind)
    if cls is None:
        raise FrameError("BADCMD", kind)
    spec = _FIELD_TYPES[cls]
    if len(fields) != len(spec):
        raise FrameError("BADARG", f"{kind} takes {len(spec)} fields, got {len(fields)}")
    values = {name: _parse_field(raw, t, name) for raw, (name, t) in zip(fields, spec, strict=True)}
    return cls(**values)  # type: ignore[return-value]


def parse(line: bytes) -> AnyMessage:
    """Decode one complete line into its message; raises :class:`FrameError`."""
    return parse_body(unframe(line))


# --------------------------------------------------------------------------------------------
# Line buffer
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Frame:
    """A line whose framing and CRC are valid: ``raw`` (from ``$``) and its ``body``."""

    raw: bytes
    body: bytes


@dataclass(frozen=True)
class BadLine:
    """Bytes that are not a valid line: junk before a ``$``, or a line failing its checks."""

    raw: bytes
    reason: BadLineReason


class LineBuffer:
    """Split a byte stream into frames, resynchronising on the last ``$`` before each ``\\n``.

    ``feed`` takes any chunk of bytes and returns, in order, every complete :class:`Frame` and
    every :class:`BadLine` (junk, bad CRC, malformed, too long). A truncated line with the next
    line glued on is dropped and the glued line recovered. Nothing is buffered beyond one
    maximum-length line, so a stream of junk without newlines cannot grow memory.
    """

    def __init__(self) -> None:
        self._pending = b""

    def feed(self, data: bytes) -> list[Frame | BadLine]:
        out: list[Frame | BadLine] = []
        buf = self._pending + data
        start = 0
        while (nl := buf.find(b"\n", start)) >= 0:
            self._segment(buf[start : nl + 1], out)
            start = nl + 1
        rest = buf[start:]
        if len(rest) > MAX_LINE_BYTES:
            dollar = rest.rfind(b"$")
            if dollar > 0 and len(rest) - dollar <= MAX_LINE_BYTES:
                out.append(BadLine(rest[:dollar], "JUNK"))
                rest = rest[dollar:]
            else:
                out.append(BadLine(rest, "TOOLONG" if dollar >= 0 else "JUNK"))
                rest = b""
        self._pending = rest
        return out

    @staticmethod
    def _segment(seg: bytes, out: list[Frame | BadLine]) -> None:
        dollar = seg.rfind(b"$")
        if dollar < 0:
            if seg.strip():
                out.append(BadLine(seg, "JUNK"))
            return
        if dollar > 0 and seg[:dollar].strip():
            out.append(BadLine(seg[:dollar], "JUNK"))
        line = seg[dollar:]
        try:
            out.append(Frame(line, unframe(line)))
        except FrameError as exc:
            out.append(BadLine(line, exc.code))
