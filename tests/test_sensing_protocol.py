"""The line protocol: hand-checked examples and property-based fuzzing of the parser."""

from functools import reduce

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shelljax.sensing import (
    MAX_LINE_BYTES,
    Hello,
    MalformedLine,
    RawSample,
    StreamParser,
    format_hello,
    format_sample,
    parse_line,
)

FUZZ = settings(max_examples=200, deadline=None)

samples = st.builds(
    RawSample,
    t_ms=st.integers(0, 2**32 - 1),
    raw=st.lists(st.integers(0, 2**16 - 1), min_size=1, max_size=2).map(tuple),
)


def test_checksum_by_hand():
    # 'S'^','^'1'^','^'2' = 0x53^0x2C^0x31^0x2C^0x32 = 0x50, worked out on paper.
    assert format_sample(1, (2,)) == b"S,1,2*50\n"
    assert parse_line(b"S,1,2*50\n") == RawSample(1, (2,))
    assert parse_line(b"S,1,2*50\r\n") == RawSample(1, (2,))


def test_hello_round_trip_and_values():
    hello = Hello("shelljax-fsr", "1.0.0", 100.0, 10, 2)
    line = format_hello(hello)
    body = line[: line.index(b"*")]
    assert line.endswith(b"*%02X\n" % reduce(lambda a, b: a ^ b, body, 0))
    assert parse_line(line) == hello


@pytest.mark.parametrize(
    "line, reason",
    [
        (b"S,1,2\n", "no checksum"),
        (b"S,1,2*51\n", "checksum mismatch"),
        (b"S,1,2*5\n", "checksum is not two uppercase hex digits"),
        (b"S,1,2*50x\n", "checksum is not two uppercase hex digits"),
        (b"S,01,2*" + b"%02X" % reduce(lambda a, b: a ^ b, b"S,01,2", 0) + b"\n", "bad sample fields"),
        (b"S,1,2,3,4*" + b"%02X" % reduce(lambda a, b: a ^ b, b"S,1,2,3,4", 0) + b"\n", "bad sample fields"),
        (b"S,1,65536*" + b"%02X" % reduce(lambda a, b: a ^ b, b"S,1,65536", 0) + b"\n", "sample value out of range"),
        (
            b"S,4294967296,1*" + b"%02X" % reduce(lambda a, b: a ^ b, b"S,4294967296,1", 0) + b"\n",
            "sample value out of range",
        ),
        (b"S," + b"1" * MAX_LINE_BYTES + b"*00\n", "line too long"),
    ],
)
def test_rejected_lines(line, reason):
    with pytest.raises(MalformedLine) as info:
        parse_line(line)
    assert info.value.reason == reason


def test_lowercase_checksum_rejected():
    # Strict uppercase: a case flip in the checksum is a corrupted byte, not an equivalent line.
    line = next(
        format_sample(t, (1,)) for t in range(100) if any(c in b"ABCDEF" for c in format_sample(t, (1,))[-3:-1])
    )
    with pytest.raises(MalformedLine):
        parse_line(line[:-3] + line[-3:-1].lower() + b"\n")


@FUZZ
@given(samples)
def test_sample_round_trip(sample):
    assert parse_line(format_sample(sample.t_ms, sample.raw)) == sample


@FUZZ
@given(st.binary(max_size=400), st.lists(st.integers(1, 50), max_size=20))
def test_arbitrary_bytes_never_raise(data, cuts):
    parser = StreamParser()
    frames, errors = [], []
    pos = 0
    for cut in cuts + [len(data)]:
        f, e = parser.feed(data[pos : pos + cut])
        frames += f
        errors += e
        pos += cut
    parser.feed(data[pos:])
    parser.drop_partial()
    # Every returned frame is a well-formed record: formatting it again gives a line that parses.
    for frame in frames:
        if isinstance(frame, RawSample):
            assert parse_line(format_sample(frame.t_ms, frame.raw)) == frame
    assert parser.n_malformed >= len(errors)
    assert parser.n_frames == len(frames)


@FUZZ
@given(st.lists(samples, min_size=1, max_size=30), st.data())
def test_chunking_does_not_matter(stream, data):
    blob = b"".join(format_sample(s.t_ms, s.raw) for s in stream)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(blob)), max_size=15)))
    parser = StreamParser()
    frames = []
    for a, b in zip([0] + cuts, cuts + [len(blob)]):
        frames += parser.feed(blob[a:b])[0]
    assert frames == stream
    assert parser.n_malformed == 0


@FUZZ
@given(st.lists(samples, min_size=1, max_size=20), st.lists(st.binary(max_size=60), max_size=10), st.data())
def test_garbage_lines_between_records_lose_nothing(stream, junk, data):
    lines = [format_sample(s.t_ms, s.raw) for s in stream]
    for chunk in junk:
        lines.insert(data.draw(st.integers(0, len(lines))), chunk.replace(b"\n", b"") + b"\n")
    frames, _ = StreamParser().feed(b"".join(lines))
    got = [f for f in frames if isinstance(f, RawSample)]
    # The original records come out in order; junk may only add records if it happens to be a
    # well-formed checksummed line itself.
    it = iter(got)
    assert all(any(g == s for g in it) for s in stream)


@FUZZ
@given(st.lists(samples, min_size=1, max_size=10), st.data())
def test_single_corrupted_byte_never_yields_a_wrong_record(stream, data):
    blob = bytearray(b"".join(format_sample(s.t_ms, s.raw) for s in stream))
    i = data.draw(st.integers(0, len(blob) - 1))
    new = data.draw(st.integers(0, 255).filter(lambda b: b != blob[i]))
    blob[i] = new
    parser = StreamParser()
    frames, _ = parser.feed(bytes(blob))
    parser.drop_partial()
    assert set(frames) <= set(stream)  # XOR checksum: any one substituted byte is detected
    assert len(frames) < len(stream)
    assert parser.n_malformed >= 1


def test_overlong_garbage_is_not_buffered():
    parser = StreamParser()
    for _ in range(1000):
        parser.feed(b"x" * 1000)
    assert len(parser._buffer) < MAX_LINE_BYTES
    frames, errors = parser.feed(b"tail\n" + format_sample(7, (1, 2)))
    assert frames == [RawSample(7, (1, 2))]
    assert [e.reason for e in errors] == ["line too long"]


def test_partial_line_at_disconnect_is_counted():
    parser = StreamParser()
    line = format_sample(123, (456,))
    assert parser.feed(line[:5]) == ([], [])
    assert parser.drop_partial() is not None
    assert parser.n_malformed == 1
    assert parser.feed(line)[0] == [RawSample(123, (456,))]
