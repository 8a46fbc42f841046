"""The board protocol's codec: round trips, an independent CRC, and random or corrupted frames."""

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from modalctl.io import protocol as p

EXAMPLES = [
    p.Hello(seq=1),
    p.Info(seq=2, channels=8, sensors=4, max_sample_rate=1e6, voltage_limit=150.0, max_modes=32, scans=211,
           table=1 << 18, name="modalctl emulator"),
    p.Configure(seq=3, sample_rate=5e5, control_rate=2e4, modes=2, carriers=np.array([963.0, 2253.0]),
                bandwidths=np.array([400.0, 900.0]), weights=np.arange(16.0), sensors=np.arange(8.0), samples=14500),
    p.Upload(seq=4, channel=3, offset=4096, samples=np.linspace(-1, 1, 1000)),
    p.Start(seq=5),
    p.Commands(seq=6, period=123, commands=np.array([1 + 2j, -3j])),
    p.Envelopes(seq=7, period=124, envelopes=np.array([1e-4 + 1e-5j, 2e-5])),
    p.Heartbeat(seq=8, state=2), p.RampDown(seq=9, seconds=5e-5), p.Stop(seq=10),
    p.Scan(seq=11, times=np.array([0.025, 0.0250021]), points=np.array([0.0, 5.0])),
    p.Field(seq=12, first=0, rows=2, offset=8000, values=np.array([1.0, 2.0])),
    p.Capture(seq=15, what=1, rows=np.array([0.0, 3.0]), offset=8000, count=8000),
    p.Ack(seq=13, of=0x02, ack_seq=3), p.Error(seq=14, code=3, text="watchdog: no command for 3 periods"),
    p.Program(seq=16, periods=580, kp=np.array([30.0, 80.0]), ki=np.array([2e4, 9e4]), limit=np.array([0.5, 0.2]),
              leak=np.array([1e-3 + 2e-3j, -4e-4j])),
    p.Reference(seq=17, mode=1, offset=2000, values=np.array([1e-4 + 2e-5j, -3e-5j, 0.0])),
]


def test_every_message_type_has_an_example():
    """A new message type must be added above, so that every test below covers it."""
    assert {type(m) for m in EXAMPLES} == set(p._TYPES.values())


def _same(a, b):
    assert type(a) is type(b)
    for key, value in vars(a).items():
        other = getattr(b, key)
        if isinstance(value, np.ndarray):
            np.testing.assert_allclose(other, value.astype(other.dtype), rtol=1e-7)
        elif isinstance(value, float) and np.isnan(value):
            assert np.isnan(other)
        else:
            assert other == pytest.approx(value, rel=1e-7) if isinstance(value, float) else other == value


@pytest.mark.parametrize("message", EXAMPLES, ids=lambda m: type(m).__name__)
def test_every_message_survives_encode_frame_deframe_decode(message):
    _same(message, p.decode(p.encode(message)))
    deframer = p.Deframer()
    stream = p.frame(message)
    got = [m for i in range(0, len(stream), 7) for m in deframer.feed(stream[i:i + 7])]  # arrives in pieces
    assert len(got) == 1
    _same(message, got[0])


def test_the_crc_is_crc32_iso_hdlc_as_computed_independently():
    """zlib's CRC on the wire against the `crc` package's table-driven CRC-32 (ISO-HDLC)."""
    from crc import Calculator, Crc32

    calculator = Calculator(Crc32.CRC32)
    for message in EXAMPLES:
        data = p.encode(message)
        raw = __import__("cobs.cobs", fromlist=["cobs"]).decode(p.frame(message)[:-1])
        assert raw[:-4] == data
        assert struct.unpack("<I", raw[-4:])[0] == calculator.checksum(data)


def test_a_corrupted_byte_is_reported_and_the_next_frame_still_arrives():
    good, next_one = p.frame(EXAMPLES[5]), p.frame(EXAMPLES[6])
    bad = bytearray(good)
    bad[5] ^= 0x40
    out = p.Deframer().feed(bytes(bad) + next_one)
    assert isinstance(out[0], p.ProtocolError) and isinstance(out[1], p.Envelopes)


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=600))
def test_random_bytes_give_messages_or_protocol_errors_only(data):
    for item in p.Deframer().feed(data + b"\x00"):
        assert isinstance(item, (p.Message, p.ProtocolError))
    try:
        p.decode(data)
    except p.ProtocolError:
        pass


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(EXAMPLES), st.integers(0, 10_000), st.integers(1, 255), st.integers(0, 40))
def test_corrupted_truncated_frames_never_crash_or_pass_as_good(message, where, flip, cut):
    stream = bytearray(p.frame(message))
    i = where % (len(stream) - 1)
    stream[i] ^= flip
    stream = stream[:max(1, len(stream) - 1 - cut)] + b"\x00"
    for item in p.Deframer().feed(bytes(stream)):
        assert isinstance(item, p.ProtocolError)  # never a message: the CRC catches every change


def test_a_stream_without_delimiters_is_dropped_not_hoarded():
    deframer = p.Deframer()
    out = deframer.feed(b"\x01" * (2 * p.MAX_FRAME + 10))
    assert len(out) == 1 and "delimiter" in str(out[0])
    assert deframer.feed(p.frame(EXAMPLES[0]))[-1] == EXAMPLES[0]


@pytest.mark.parametrize("message", EXAMPLES, ids=lambda m: type(m).__name__)
def test_every_message_survives_can_fd_segmentation(message):
    frames = p.segments(message)
    assert all(len(f) <= p.CAN_DATA for f in frames)
    reassembler = p.Reassembler()
    out = [reassembler.feed(f + b"\x00" * (-len(f) % 4)) for f in frames]  # padded as CAN FD lengths pad
    assert all(o is None for o in out[:-1])
    _same(message, out[-1])


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(min_size=0, max_size=64), max_size=20))
def test_random_can_frames_give_messages_errors_or_nothing(frames):
    reassembler = p.Reassembler()
    for data in frames:
        out = reassembler.feed(data)
        assert out is None or isinstance(out, (p.Message, p.ProtocolError))


def test_a_lost_can_segment_is_reported_not_glued():
    frames = p.segments(EXAMPLES[3])  # an upload: many frames
    reassembler = p.Reassembler()
    results = [reassembler.feed(f) for i, f in enumerate(frames) if i != 2]
    assert any(isinstance(r, p.ProtocolError) for r in results)
    assert not any(isinstance(r, p.Message) for r in results)
    assert isinstance(reassembler.feed(p.segments(EXAMPLES[0])[0]), p.Hello)  # and the next message is fine
