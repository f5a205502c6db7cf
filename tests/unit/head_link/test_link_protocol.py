"""The head's serial protocol (docs/head-protocol.md): frames, bodies, resynchronisation,
and the parser against random and mutated bytes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from agent.head_link.frames import MAX_BODY, MAX_ENCODED, Frame, FrameDecoder, encode_frame
from agent.head_link.messages import (
    MAX_SAMPLES,
    PAN_STEP_RAD,
    SCAN_STEP_RAD,
    Ack,
    Heartbeat,
    Hello,
    HelloReply,
    Laser,
    Nak,
    Pan,
    ProtocolError,
    Rearm,
    Reason,
    SafetyState,
    Samples,
    Status,
    StatusRequest,
    TimeReply,
    TimeRequest,
    Window,
    decode,
)


def _samples(n: int = 32, seed: int = 0) -> Samples:
    rng = np.random.default_rng(seed)
    return Samples.of(
        1_000_000 + np.arange(n) * 390.625, rng.uniform(-0.35, 0.35, n),
        np.full(n, 0.7), rng.uniform(1e-10, 1e-6, n), rng.uniform(1e-10, 1e-6, n),
    )  # fmt: skip


EXAMPLES = [
    Hello(),
    HelloReply(1, "sim-1.4.2", "LEP-000017", "cal-2026-11-23"),
    Pan(-1.2),
    Window(-0.349, 0.1),
    Laser(True),
    Rearm(),
    Heartbeat(123_456_789),
    StatusRequest(),
    TimeRequest(42),
    Ack(7, Pan.TYPE),
    Nak(8, Window.TYPE, Reason.OUT_OF_RANGE, "window beyond +-20 deg"),
    Status(99, SafetyState.TRIPPED, False, 62.8, 0.5, 0.6, -0.3, 0.3, 1000, 2, 1, 3),
    TimeReply(42, 777),
    _samples(),
]


def _stream(messages: list[object], start_seq: int = 0) -> bytes:
    return b"".join(
        encode_frame(m.TYPE, (start_seq + k) % 0x10000, m.pack())  # type: ignore[attr-defined]
        for k, m in enumerate(messages)
    )


def _same(a: object, b: object) -> bool:
    if isinstance(a, Samples) and isinstance(b, Samples):
        return a.head_time_us == b.head_time_us and all(
            np.array_equal(getattr(a, f), getattr(b, f))
            for f in ("time_us", "scan_rad", "pan_rad", "i1_A", "i2_A")
        )
    return a == b


@pytest.mark.parametrize("message", EXAMPLES, ids=lambda m: type(m).__name__)
def test_every_message_reads_back_as_written(message: object) -> None:
    decoder = FrameDecoder()
    (frame,) = decoder.feed(_stream([message]))
    back = decode(frame)
    if isinstance(message, Pan | Window | Status):  # angles in whole µrad, rates in f32
        assert back == type(message).unpack(message.pack())
        assert all(
            math.isclose(getattr(back, f), getattr(message, f), rel_tol=2**-23, abs_tol=5e-7)
            for f in message.__dataclass_fields__
            if isinstance(getattr(message, f), float)
        )
    else:
        assert _same(back, message)


def test_samples_are_quantised_to_the_wire_steps_and_no_more() -> None:
    rng = np.random.default_rng(1)
    n = MAX_SAMPLES
    t = 5e6 + np.arange(n) * 390.625
    scan, pan = rng.uniform(-0.35, 0.35, n), rng.uniform(-1.57, 1.57, n)
    i1, i2 = rng.uniform(1e-11, 1e-6, (2, n))
    s = Samples.of(t, scan, pan, i1, i2)
    assert np.max(np.abs(s.scan_rad - scan)) <= SCAN_STEP_RAD / 2 + 1e-12
    assert np.max(np.abs(s.pan_rad - pan)) <= PAN_STEP_RAD / 2 + 1e-12
    assert np.max(np.abs(s.time_us - t)) <= 0.5
    np.testing.assert_allclose(s.i1_A, i1, rtol=2**-23)
    assert len(encode_frame(Samples.TYPE, 0, s.pack())) <= MAX_ENCODED + 1


def test_a_stream_cut_anywhere_gives_the_same_frames() -> None:
    data = _stream(EXAMPLES)
    whole = FrameDecoder().feed(data)
    bytewise = FrameDecoder()
    one_by_one = [f for i in range(len(data)) for f in bytewise.feed(data[i : i + 1])]
    assert [(f.type, f.seq, f.body) for f in one_by_one] == [(f.type, f.seq, f.body) for f in whole]
    assert len(whole) == len(EXAMPLES) and bytewise.counters.dropped == 0


def test_a_lost_a_flipped_or_an_extra_byte_costs_only_its_own_frame() -> None:
    frames = [encode_frame(Heartbeat.TYPE, k, Heartbeat(k).pack()) for k in range(10)]
    for damage in ("lose", "flip", "insert"):
        broken = list(frames)
        f = bytearray(broken[4])
        if damage == "lose":
            del f[5]
        elif damage == "flip":
            f[5] ^= 0x10
        else:
            f.insert(5, 0x55)
        broken[4] = bytes(f)
        decoder = FrameDecoder()
        got = decoder.feed(b"".join(broken))
        assert [fr.seq for fr in got] == [0, 1, 2, 3, 5, 6, 7, 8, 9], damage
        assert decoder.counters.dropped == 1 and decoder.counters.seq_gaps == 1, damage


def test_a_truncated_frame_costs_itself_and_the_frame_it_runs_into() -> None:
    # A frame cut short (its delimiter never sent) runs into the next frame's bytes: the two
    # are one chunk, which fails and is counted; the frame after is whole again. At every
    # cut, of a small frame and of a samples frame.
    for message in (Heartbeat(7), _samples()):
        frames = [encode_frame(message.TYPE, k, message.pack()) for k in range(10)]
        for keep in range(1, len(frames[4])):  # 1 to all of its stuffed bytes
            decoder = FrameDecoder()
            got = decoder.feed(b"".join([*frames[:4], frames[4][:keep], *frames[5:]]))
            assert [f.seq for f in got] == [0, 1, 2, 3, 6, 7, 8, 9], keep
            c = decoder.counters
            assert (c.dropped, c.seq_gaps) == (1, 2), keep
            assert c.discarded_bytes == keep + len(frames[5]) - 1, keep


def test_garbage_without_delimiters_is_dropped_and_the_next_frame_read() -> None:
    rng = np.random.default_rng(2)
    junk = rng.integers(1, 256, 3 * MAX_ENCODED, dtype=np.uint8).tobytes()  # no 0x00
    decoder = FrameDecoder()
    got = decoder.feed(junk[:1000]) + decoder.feed(junk[1000:])
    got += decoder.feed(b"\x00" + encode_frame(Ack.TYPE, 3, Ack(1, 2).pack()))
    assert [decode(f) for f in got] == [Ack(1, 2)]
    assert decoder.counters.oversize == 1
    assert decoder.counters.discarded_bytes == len(junk)


def test_bad_values_are_refused_with_one_line() -> None:
    with pytest.raises(ValueError, match="body of 1025 bytes"):
        encode_frame(1, 0, bytes(MAX_BODY + 1))
    with pytest.raises(ProtocolError, match="pan: target nan rad"):
        Pan(math.nan).pack()
    with pytest.raises(ProtocolError, match="laser: on must be 0 or 1"):
        decode(Frame(Laser.TYPE, 0, b"\x02"))
    with pytest.raises(ProtocolError, match="window: body of 3 bytes, expected 8"):
        decode(Frame(Window.TYPE, 0, b"abc"))
    with pytest.raises(ProtocolError, match="frame type 0x7f"):
        decode(Frame(0x7F, 0, b""))
    with pytest.raises(ProtocolError, match="samples: 0 samples"):
        Samples.of(*np.zeros((5, 0)))
    with pytest.raises(ProtocolError, match="heartbeat: "):
        Heartbeat(-1).pack()
    with pytest.raises(ProtocolError, match="hello_reply: firmware must be ASCII"):
        HelloReply(1, "é", "x", "y").pack()


def _read_all(decoder: FrameDecoder, data: bytes) -> tuple[int, int]:
    """Feed, decode every frame; (messages, refused bodies). Anything else raised fails."""
    good = refused = 0
    for frame in decoder.feed(data):
        try:
            decode(frame)
            good += 1
        except ProtocolError:
            refused += 1
    return good, refused


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=4 * MAX_ENCODED))
def test_random_bytes_never_crash_the_parser(data: bytes) -> None:
    decoder = FrameDecoder()
    _read_all(decoder, data)
    c = decoder.counters
    assert c.bytes == len(data) and c.discarded_bytes <= len(data)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.sampled_from(range(len(EXAMPLES))), min_size=1, max_size=8),
    st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255), st.sampled_from("fdi"))),
)
def test_mutated_streams_never_crash_the_parser(picks: list[int], edits: list[tuple]) -> None:
    data = bytearray(_stream([EXAMPLES[k] for k in picks]))
    for where, value, how in edits:
        i = where % (len(data) + 1)
        if how == "f" and i < len(data):
            data[i] = value
        elif how == "d" and i < len(data):
            del data[i]
        else:
            data.insert(i, value)
    decoder = FrameDecoder()
    good, refused = _read_all(decoder, bytes(data))
    # Each edit spoils at most the frame it falls in, and a deleted or inserted delimiter at
    # most two: the rest read back.
    assert good + refused >= len(picks) - 2 * len(edits)


def test_a_hundred_thousand_mutated_frames() -> None:
    # 10⁵ frames of every kind, each with one to four random byte edits (a fixed seed): the
    # parser raises nothing, every frame is either read, refused or counted as dropped, and
    # no damaged frame passes its CRC as something else.
    rng = np.random.default_rng(3)
    clean = [encode_frame(m.TYPE, 1, m.pack()) for m in EXAMPLES]  # type: ignore[attr-defined]
    decoder = FrameDecoder()
    read = refused = 0
    n = 100_000
    for k in range(n):
        f = bytearray(clean[k % len(clean)])
        # Distinct places, never the delimiter (one frame, one chunk), another non-zero byte.
        for i in rng.choice(len(f) - 1, size=int(rng.integers(1, 5)), replace=False):
            f[i] = 1 + (f[i] - 1 + int(rng.integers(1, 255))) % 255
        g, r = _read_all(decoder, bytes(f))
        read += g
        refused += r
    c = decoder.counters
    assert c.frames == read + refused
    assert c.frames + c.dropped == n
    assert c.frames == 0  # a random edit passes a CRC-32 about 2⁻³² of the time


def test_clock_alignment_takes_the_quickest_probe_and_states_its_error() -> None:
    from agent.head_link.clock import ClockAlignment

    # The head's clock runs 5 s ahead. Replies come after 1-3 ms, the head reading its
    # clock anywhere in the round trip; the quickest probe bounds the offset.
    rng = np.random.default_rng(4)
    clock = ClockAlignment()
    assert not clock.known and math.isnan(clock.offset_us)
    for k in range(40):
        sent = 1e6 * k
        trip = float(rng.uniform(1000.0, 3000.0))
        read = sent + float(rng.uniform(0.0, trip))
        clock.add(sent, sent + trip, read + 5e6)
    assert abs(clock.offset_us - 5e6) <= clock.error_us <= 1500.0
    assert abs(clock.to_host_us(5e6 + 123.0) - 123.0) <= clock.error_us
    clock.add(10.0, 5.0, 0.0)  # received before it was sent
    clock.add(math.nan, 5.0, 0.0)
    assert clock.refused == 2
