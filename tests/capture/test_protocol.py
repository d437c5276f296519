"""Codec: framing, CRC, every message type, corruption detection and resynchronisation."""

from __future__ import annotations

import dataclasses
from typing import Literal, get_args, get_origin, get_type_hints

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from difflattice.capture import protocol as P

SPEC_LINES = [  # the example exchange of rig-protocol.md
    b"$LOB,7,79,-11000,35334,300,2906203,2149*C8CA\n",
    b"$BOOT,0.3.1,13903,WDT*C840\n",
    b"$HOME*3DF2\n",
    b"$ACK,HOME,0*5545\n",
    b"$LOBE,7,80,181,-90000,1000,8,16,49400*20EE\n",
    b"$ACK,LOBE,7*F7ED\n",
    b"$LOB,7,80,-10000,58267,300,2906203,2151*06FA\n",
]

TEXT = st.text(
    alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E, exclude_characters="$*,"), min_size=1, max_size=10
)


def _field(kind: object) -> st.SearchStrategy[object]:
    if kind is bool:
        return st.booleans()
    if kind is int:
        return st.integers(-(10**9), 10**9)
    if get_origin(kind) is Literal:
        return st.sampled_from(get_args(kind))
    return TEXT


def _message(cls: type[P.Message]) -> st.SearchStrategy[P.Message]:
    hints = get_type_hints(cls)
    return st.builds(cls, **{f.name: _field(hints[f.name]) for f in dataclasses.fields(cls)})


MESSAGES = st.one_of(*(_message(cls) for cls in P.MESSAGE_TYPES.values()))
EXAMPLES = [P.parse(line) for line in SPEC_LINES] + [
    P.Hello(1),
    P.Stat(),
    P.Wave(3, 0, 121, -30000, 500, 16500, 8, 16, 40000),
    P.Abort(3),
    P.Idn(1, "0.3.1", "RIG-7", 13903, True, "SCAN"),
    P.Hbt(123456, "IDLE", 7, 181),
    P.Wav(3, 120, 30000, 16500, 48123, -179999, 61234, 2149),
    P.End(7, 101, "ABORTED"),
    P.Err("NOTHOMED", "LOBE"),
]


def test_crc_check_value() -> None:
    assert P.crc16(b"123456789") == 0x29B1


@pytest.mark.parametrize("line", SPEC_LINES)
def test_spec_example_lines(line: bytes) -> None:
    assert P.encode(P.parse(line)) == line
    assert P.parse(line.replace(b"\n", b"\r\n")) == P.parse(line)


def test_every_type_is_covered() -> None:
    assert {type(m) for m in EXAMPLES} == set(P.MESSAGE_TYPES.values())


@settings(max_examples=300, deadline=None)
@given(MESSAGES)
def test_round_trip(msg: P.Message) -> None:
    line = P.encode(msg)
    assert len(line) <= P.MAX_LINE_BYTES
    assert P.parse(line) == msg
    assert P.encode(P.parse(line)) == line


def _decoded(stream: bytes) -> list[P.Message]:
    out = []
    for item in P.LineBuffer().feed(stream):
        if isinstance(item, P.Frame):
            try:
                out.append(P.parse_body(item.body))
            except P.FrameError:
                pass
    return out


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: m.TYPE)
def test_every_single_byte_substitution_is_detected(msg: P.Message) -> None:
    """Exhaustive: every position, every other byte value; the next line is still recovered."""
    line, nxt = P.encode(msg), P.encode(P.Stat())
    for i in range(len(line)):
        for b in range(256):
            if b != line[i]:
                bad = line[:i] + bytes([b]) + line[i + 1 :]
                assert _decoded(bad + nxt) == [P.Stat()], (bad, i)


@settings(max_examples=200, deadline=None)
@given(MESSAGES, st.data())
def test_random_corruption_is_detected(msg: P.Message, data: st.DataObject) -> None:
    line = P.encode(msg)
    i = data.draw(st.integers(0, len(line) - 1))
    b = data.draw(st.integers(0, 255).filter(lambda v: v != line[i]))
    assert _decoded(line[:i] + bytes([b]) + line[i + 1 :]) == []


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300), MESSAGES, st.binary(max_size=40), MESSAGES)
def test_resynchronises_after_junk(junk: bytes, first: P.Message, junk2: bytes, second: P.Message) -> None:
    """Junk between lines, or glued to the start of one, never hides a complete line."""
    assert _decoded(junk + P.encode(first) + junk2 + P.encode(second)) == [first, second]


@settings(max_examples=100, deadline=None)
@given(st.lists(MESSAGES, min_size=1, max_size=6), st.binary(max_size=60), st.data())
def test_chunking_does_not_matter(msgs: list[P.Message], junk: bytes, data: st.DataObject) -> None:
    stream = junk + b"\n" + b"".join(P.encode(m) for m in msgs)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    buf, items = P.LineBuffer(), []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        items += buf.feed(stream[a:b])
    assert [P.parse_body(i.body) for i in items if isinstance(i, P.Frame)] == msgs


def test_truncated_line_with_next_glued_on() -> None:
    stream = b"$LOB,7,80,-10000,$BOOT,0.3.1,13903,WDT*C840\n"
    items = P.LineBuffer().feed(stream)
    assert [type(i) for i in items] == [P.BadLine, P.Frame]
    assert P.parse_body(items[1].body) == P.Boot("0.3.1", 13903, "WDT")


def test_long_junk_is_bounded_and_reported() -> None:
    buf = P.LineBuffer()
    items = buf.feed(b"x" * 1000)
    assert items and all(isinstance(i, P.BadLine) for i in items)
    assert buf.feed(P.encode(P.Stat())) == [P.Frame(P.encode(P.Stat()), b"STAT")]


@pytest.mark.parametrize(
    ("line", "code"),
    [
        (b"$LOB,7,79*0000\n", "BADCRC"),
        (b"LOB,7,79*C8CA\n", "MALFORMED"),
        (b"$LOB,7,79\n", "MALFORMED"),
        (b"$LOB,7,79*c8ca\n", "MALFORMED"),
        (P.frame(b"X" * 120), "TOOLONG"),
    ],
)
def test_frame_errors(line: bytes, code: str) -> None:
    with pytest.raises(P.FrameError) as info:
        P.unframe(line)
    assert info.value.code == code


@pytest.mark.parametrize(
    ("body", "code"),
    [
        (b"NOPE,1", "BADCMD"),
        (b"HELLO", "BADARG"),
        (b"HELLO,01", "BADARG"),
        (b"HELLO,+1", "BADARG"),
        (b"HBT,1,BUSY,0,0", "BADARG"),
        (b"IDN,1,fw,rig,1,2,IDLE", "BADARG"),
    ],
)
def test_message_errors(body: bytes, code: str) -> None:
    with pytest.raises(P.FrameError) as info:
        P.parse(P.frame(body))
    assert info.value.code == code


def test_encode_refuses_bad_fields() -> None:
    with pytest.raises(ValueError):
        P.encode(P.Err("BADARG", "a,b"))
    with pytest.raises(ValueError):
        P.encode(P.Idn(1, "x" * 100, "rig", 1, True, "IDLE"))
