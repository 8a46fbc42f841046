"""The board protocol, version 1: messages, their binary layout, and how they travel on a serial line
and on a CAN FD bus.

Pure encoding and decoding (no ports): the transports (:mod:`modalctl.io.transports`) and the
board emulators (:mod:`modalctl.hil`) share it, so a passing test means the wire format works.
``docs/protocol.md`` is the specification; this module is its implementation.

A message is ``header | body``: the header is ``version (u8) | type (u8) | sequence (u16)``,
little-endian, and the body's layout depends on the type. Arrays are float32 (complex64 for
envelopes and commands). Over a serial line each message is followed by its CRC-32 (ISO-HDLC,
the one of zlib, Ethernet and PNG), the whole COBS-encoded and ended by a zero byte, so a
receiver resynchronizes at the next zero after any corruption (:func:`frame`, :class:`Deframer`).
Over CAN FD a message is cut into segments of 64-byte frames under CANopen's identifiers
(:func:`segments`, :class:`Reassembler`, SYNC, NMT, heartbeats). Every decoding error is a
:class:`ProtocolError`, never another exception.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field, fields

import numpy as np
from cobs import cobs

from modalctl.loops.onboard import BoardLoop

__all__ = ["VERSION", "ProtocolError", "Message", "Hello", "Info", "Configure", "Upload", "Start", "Commands",
           "Envelopes", "Heartbeat", "RampDown", "Stop", "Scan", "Capture", "Program", "Reference", "Field", "Error", "Ack",
           "encode", "decode",
           "frame", "Deframer", "MAX_FRAME", "CAN_DATA", "SYNC_ID", "to_board", "to_host", "segments", "Reassembler",
           "NMT_ID", "NMT_COMMANDS", "NMT_STATES", "heartbeat_id", "nmt",
           "ERRORS", "WARNINGS", "REPLIES", "PROGRAM_ARRAYS", "to_program", "from_program", "references"]

VERSION = 2  # 2: reference tables for the board's loops (Program's body, Reference, Info's table)
MAX_FRAME = 1 << 16  # bytes of one encoded message, at most
_HEADER = struct.Struct("<BBH")


class ProtocolError(ValueError):
    """A frame or message that does not follow the protocol (bad CRC, COBS, type, length...)."""


@dataclass
class Message:
    """Base of every message: ``seq`` counts messages per sender (wraps at 65536); a reply
    (:data:`REPLIES`) carries the sequence of the request it answers instead."""

    TYPE = 0
    seq: int = 0


# -- the message types ---------------------------------------------------------------------------
# Each subclass lists its fields after ``seq``; _LAYOUT says how each field is packed:
# "u8", "u16", "u32", "f32" scalars; "f32[]", "f64[]", "c64[]" arrays (u32 count first); "str" (u16 length, UTF-8).


@dataclass
class Hello(Message):
    """Host -> board: who are you? Answered by :class:`Info`."""

    TYPE = 0x01


@dataclass
class Info(Message):
    """Board -> host: identity and capabilities."""

    TYPE = 0x81
    channels: int = 0
    sensors: int = 0
    max_sample_rate: float = 0.0
    voltage_limit: float = float("nan")  # NaN: no rails reported
    max_modes: int = 0
    scans: int = 0  # grid points a vibrometer on the bench can measure (0: none)
    snr_db: float = float("nan")  # a simulated board's sensor noise below the shot's peak (NaN: a real board)
    table: int = 0  # complex reference values (modes x periods) the board holds for loops it runs (0: none)
    name: str = ""


@dataclass
class Configure(Message):
    """Host -> board: one shot in phasor mode. ``weights`` (a x k) map modal commands to channels,
    ``sensors`` (k x s) combine the sensors per mode before the lock-in (row-major)."""

    TYPE = 0x02
    sample_rate: float = 0.0
    control_rate: float = 0.0
    modes: int = 0
    carriers: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    bandwidths: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    weights: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    sensors: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    samples: int = 0  # feed-forward samples per channel to be uploaded
    level: float = 0.0  # the planned field peak (m/s): a simulated board sets its noise from it


@dataclass
class Upload(Message):
    """Host -> board: feed-forward samples of one channel from ``offset`` (V)."""

    TYPE = 0x03
    channel: int = 0
    offset: int = 0
    samples: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))


@dataclass
class Start(Message):
    """Host -> board: arm and trigger. In phasor mode the board answers the first period's
    :class:`Envelopes`; a shot configured with no modes is played open loop, whole, and acknowledged."""

    TYPE = 0x04


@dataclass
class Commands(Message):
    """Host -> board: per-mode command envelopes (modal forces) for the next period."""

    TYPE = 0x05
    period: int = 0
    commands: np.ndarray = field(default_factory=lambda: np.zeros(0, np.complex64))


@dataclass
class Envelopes(Message):
    """Board -> host: per-mode demodulated envelopes at the end of ``period`` (m/s)."""

    TYPE = 0x85
    period: int = 0
    envelopes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.complex64))


@dataclass
class Heartbeat(Message):
    """Either way: I am alive; ``state`` is the sender's lifecycle state."""

    TYPE = 0x06
    state: int = 0


@dataclass
class RampDown(Message):
    """Host -> board: bring every output to zero within ``seconds`` and hold it."""

    TYPE = 0x07
    seconds: float = 0.0


@dataclass
class Stop(Message):
    """Host -> board: emergency stop, outputs to zero at once."""

    TYPE = 0x08


@dataclass
class Scan(Message):
    """Host -> bench vibrometer: the field of the last shot at ``times`` (s) on grid points ``points``."""

    TYPE = 0x09
    times: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    points: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))


@dataclass
class Capture(Message):
    """Host -> board: the last shot's record, ``what`` = 0 the applied voltages (V), 1 the sensors
    (m/s), one row per channel or sensor, 2 the board's loops (6k rows, one column per period:
    :meth:`modalctl.loops.onboard.BoardLog.rows`); ``rows``: which ones, all when empty; samples
    ``offset`` to ``offset + count``; answered by :class:`Field` blocks."""

    TYPE = 0x0A
    what: int = 0
    rows: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    offset: int = 0  # first sample
    count: int = 0  # samples (0: to the end)


@dataclass
class Program(Message):
    """Host -> board: loops the board closes itself in the configured shot (k modes; see
    :class:`modalctl.loops.onboard.BoardLoop`): PI gains, authority and leak, and the length of
    each mode's reference table (``periods``), which :class:`Reference` messages then fill. The
    next Start runs the whole shot."""

    TYPE = 0x0B
    periods: int = 0
    kp: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    ki: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    limit: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    leak: np.ndarray = field(default_factory=lambda: np.zeros(0, np.complex64))


@dataclass
class Reference(Message):
    """Host -> board: mode ``mode``'s reference table from period ``offset`` (m/s, complex: each
    period's expected reading at its end), after the Program that sized it."""

    TYPE = 0x0C
    mode: int = 0
    offset: int = 0
    values: np.ndarray = field(default_factory=lambda: np.zeros(0, np.complex64))


@dataclass
class Field(Message):
    """Board -> host: one block of a scan or a capture: ``rows`` rows from row ``first`` (counted in
    the request's list of points or rows) and the columns from ``offset`` on, row-major
    (``values.size / rows`` columns)."""

    TYPE = 0x89
    first: int = 0
    rows: int = 0
    offset: int = 0
    values: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))


@dataclass
class Ack(Message):
    """Board -> host: the message of type ``of`` and sequence ``ack_seq`` was accepted."""

    TYPE = 0x8A
    of: int = 0
    ack_seq: int = 0


#: Error codes (docs/protocol.md); ``overrun`` is a warning: the board lost messages but goes on.
ERRORS = {"protocol": 1, "unsupported": 2, "state": 3, "config": 4, "overrun": 5, "internal": 9}
WARNINGS = {ERRORS["overrun"]}


@dataclass
class Error(Message):
    """Board -> host: a request failed or the board stopped; ``code`` (see docs/protocol.md) and text."""

    TYPE = 0x8F
    code: int = 0
    text: str = ""


#: What a board sends in answer to one request, with that request's ``seq``: a host takes a reply
#: only to the request it made (never one to a previous host's, still in the line).
REPLIES = (Info, Field, Ack, Error)

_TYPES = {cls.TYPE: cls for cls in (Hello, Info, Configure, Upload, Start, Commands, Envelopes, Heartbeat,
                                    RampDown, Stop, Scan, Capture, Program, Reference, Field, Ack, Error)}
_LAYOUT = {
    Info: ("u8", "u8", "f32", "f32", "u8", "u32", "f32", "u32", "str"),
    Configure: ("f32", "f32", "u8", "f32[]", "f32[]", "f32[]", "f32[]", "u32", "f32"),
    Upload: ("u8", "u32", "f32[]"),
    Commands: ("u32", "c64[]"),
    Envelopes: ("u32", "c64[]"),
    Heartbeat: ("u8",),
    RampDown: ("f32",),
    Scan: ("f64[]", "f32[]"),
    Capture: ("u8", "f32[]", "u32", "u32"),
    Program: ("u32", "f32[]", "f32[]", "f32[]", "c64[]"),
    Reference: ("u8", "u32", "c64[]"),
    Field: ("u32", "u32", "u32", "f32[]"),
    Ack: ("u8", "u16"),
    Error: ("u16", "str"),
}
_SCALARS = {"u8": struct.Struct("<B"), "u16": struct.Struct("<H"), "u32": struct.Struct("<I"),
            "f32": struct.Struct("<f")}
_ARRAYS = {"f32[]": np.dtype("<f4"), "f64[]": np.dtype("<f8"), "c64[]": np.dtype("<c8")}


def _body_fields(cls) -> list[str]:
    return [f.name for f in fields(cls) if f.name != "seq"]


def encode(message: Message) -> bytes:
    """The message's bytes (header and body)."""
    cls = type(message)
    out = [_HEADER.pack(VERSION, cls.TYPE, message.seq & 0xFFFF)]
    for name, kind in zip(_body_fields(cls), _LAYOUT.get(cls, ())):
        value = getattr(message, name)
        if kind in _SCALARS:
            out.append(_SCALARS[kind].pack(value))
        elif kind in _ARRAYS:
            array = np.ascontiguousarray(np.ravel(value), _ARRAYS[kind])
            out += [struct.pack("<I", array.size), array.tobytes()]
        else:  # str
            text = value.encode("utf-8")[:0xFFFF]
            out += [struct.pack("<H", len(text)), text]
    data = b"".join(out)
    if len(data) > MAX_FRAME:
        raise ProtocolError(f"{cls.__name__}: {len(data)} bytes, above the {MAX_FRAME}-byte frame limit")
    return data


def decode(data: bytes) -> Message:
    """The message in ``data``; :class:`ProtocolError` for anything that is not a valid message."""
    if len(data) < _HEADER.size:
        raise ProtocolError(f"message of {len(data)} bytes, shorter than its header")
    version, kind, seq = _HEADER.unpack_from(data)
    if version != VERSION:
        raise ProtocolError(f"protocol version {version}, this side speaks {VERSION}")
    cls = _TYPES.get(kind)
    if cls is None:
        raise ProtocolError(f"unknown message type 0x{kind:02x}")
    pos, values = _HEADER.size, {}
    try:
        for name, layout in zip(_body_fields(cls), _LAYOUT.get(cls, ())):
            if layout in _SCALARS:
                (values[name],) = _SCALARS[layout].unpack_from(data, pos)
                pos += _SCALARS[layout].size
            elif layout in _ARRAYS:
                (count,) = struct.unpack_from("<I", data, pos)
                pos += 4
                size = count * _ARRAYS[layout].itemsize
                if pos + size > len(data):
                    raise ProtocolError(f"{cls.__name__}.{name}: {count} values announced, {len(data) - pos} bytes left")
                values[name] = np.frombuffer(data, _ARRAYS[layout], count, pos).copy()
                pos += size
            else:
                (length,) = struct.unpack_from("<H", data, pos)
                pos += 2
                if pos + length > len(data):
                    raise ProtocolError(f"{cls.__name__}.{name}: text runs past the message")
                values[name] = data[pos:pos + length].decode("utf-8", errors="replace")
                pos += length
    except struct.error as exc:
        raise ProtocolError(f"{cls.__name__}: truncated ({exc})") from None
    if pos != len(data):
        raise ProtocolError(f"{cls.__name__}: {len(data) - pos} bytes left over")
    return cls(seq=seq, **values)


def frame(message: Message) -> bytes:
    """Serial framing: COBS(message bytes | CRC-32 little-endian) followed by a zero byte."""
    data = encode(message)
    return cobs.encode(data + struct.pack("<I", zlib.crc32(data))) + b"\x00"


class Deframer:
    """Splits a serial byte stream into messages.

    :meth:`feed` takes whatever bytes arrived and returns the messages completed, each a
    :class:`Message` or, for a corrupted frame, the :class:`ProtocolError` that describes it (the
    stream resynchronizes at the next zero byte; nothing is raised, so one bad frame never stops
    a link). A frame longer than :data:`MAX_FRAME` is dropped as an error.
    """

    def __init__(self):
        self._buffer = bytearray()
        self._overflow = False

    def feed(self, data: bytes) -> list:
        out = []
        self._buffer += data
        while True:
            end = self._buffer.find(b"\x00")
            if end < 0:
                if len(self._buffer) > 2 * MAX_FRAME:  # no delimiter in sight: drop and say so once
                    self._buffer.clear()
                    if not self._overflow:
                        out.append(ProtocolError(f"no frame delimiter in {2 * MAX_FRAME} bytes"))
                    self._overflow = True
                return out
            chunk, self._buffer = bytes(self._buffer[:end]), self._buffer[end + 1:]
            self._overflow = False
            if chunk:
                out.append(self._message(chunk))

    @staticmethod
    def _message(chunk: bytes):
        try:
            raw = cobs.decode(chunk)
        except cobs.DecodeError as exc:
            return ProtocolError(f"bad COBS frame: {exc}")
        if len(raw) < 4:
            return ProtocolError(f"frame of {len(raw)} bytes, too short for its CRC")
        data, (crc,) = raw[:-4], struct.unpack("<I", raw[-4:])
        if zlib.crc32(data) != crc:
            return ProtocolError("CRC mismatch: the frame was corrupted")
        try:
            return decode(data)
        except ProtocolError as exc:
            return exc


# -- over CAN FD -----------------------------------------------------------------------------------
# A message travels in CAN FD frames of up to 64 data bytes: each frame starts with one byte,
# the segment's index (0-126) with the top bit set on the last one; the first segment's data starts
# with the message's length (u16), so padding to a CAN FD length is harmless. CAN's own CRC guards
# each frame. Identifiers follow CANopen's layout: host -> board node n on 0x200 + n, board n ->
# host on 0x180 + n, SYNC (every board applies its last commands at once) on 0x080, NMT commands
# (CiA 301: command specifier, node or 0 for all) on 0x000, each board's heartbeat (its NMT state,
# one byte) on 0x700 + n.

CAN_DATA = 64
SYNC_ID = 0x080
NMT_ID = 0x000
NMT_COMMANDS = {"start": 0x01, "stop": 0x02, "pre-operational": 0x80, "reset": 0x81, "reset communication": 0x82}
NMT_STATES = {0x00: "boot-up", 0x04: "stopped", 0x05: "operational", 0x7F: "pre-operational"}


def heartbeat_id(node: int) -> int:
    """CAN identifier of board ``node``'s heartbeat (CANopen's 0x700 + n)."""
    return 0x700 + node


def nmt(command: str, node: int = 0) -> bytes:
    """The two data bytes of an NMT command (``NMT_COMMANDS``) to ``node`` (0: every board)."""
    if command not in NMT_COMMANDS:
        raise ValueError(f"NMT command {command!r}; known: {', '.join(NMT_COMMANDS)}")
    return bytes([NMT_COMMANDS[command], node])
_FIRST = struct.Struct("<BH")


def to_board(node: int) -> int:
    """CAN identifier of the host's messages to board ``node`` (1-127)."""
    return 0x200 + node


def to_host(node: int) -> int:
    """CAN identifier of board ``node``'s messages to the host."""
    return 0x180 + node


def segments(message: Message) -> list[bytes]:
    """The message's CAN FD frames' data, each at most :data:`CAN_DATA` bytes."""
    data = encode(message)
    body = struct.pack("<H", len(data)) + data
    chunks = [body[i:i + CAN_DATA - 1] for i in range(0, len(body), CAN_DATA - 1)]
    if len(chunks) > 127:
        raise ProtocolError(f"{type(message).__name__}: {len(data)} bytes need {len(chunks)} CAN frames, at most 127")
    return [bytes([i | (0x80 if i == len(chunks) - 1 else 0)]) + chunk for i, chunk in enumerate(chunks)]


class Reassembler:
    """Rebuilds messages from one sender's CAN FD frames: :meth:`feed` returns a :class:`Message`,
    a :class:`ProtocolError` (a frame out of order, a bad length: the partial message is dropped)
    or None while a message is incomplete."""

    def __init__(self):
        self._parts: list[bytes] = []

    def feed(self, data: bytes):
        if not data:
            return ProtocolError("empty CAN frame")
        index, last, chunk = data[0] & 0x7F, bool(data[0] & 0x80), bytes(data[1:])
        if index == 0:
            self._parts = []  # a new message; an unfinished one before it is lost
        elif index != len(self._parts):
            self._parts = []
            return ProtocolError(f"CAN segment {index} without its predecessors")
        self._parts.append(chunk)
        if not last:
            return None
        body, self._parts = b"".join(self._parts), []
        if len(body) < 2:
            return ProtocolError("CAN message shorter than its length field")
        (length,) = struct.unpack_from("<H", body)
        if length > len(body) - 2:
            return ProtocolError(f"CAN message announces {length} bytes, {len(body) - 2} arrived")
        try:
            return decode(body[2:2 + length])
        except ProtocolError as exc:
            return exc


# -- loops loaded into a board (Program) ------------------------------------------------------------

PROGRAM_ARRAYS = ("kp", "ki", "limit", "leak")


def to_program(loops: BoardLoop) -> Program:
    """The protocol's Program message that loads ``loops`` into a board (their tables follow in
    :func:`references`)."""
    return Program(periods=loops.periods, **{name: np.ravel(getattr(loops, name)) for name in PROGRAM_ARRAYS})


def references(loops: BoardLoop, size: int) -> list[Reference]:
    """The Reference messages that carry ``loops``' tables, ``size`` values each at most."""
    return [Reference(mode=mode, offset=offset, values=row[offset:offset + size])
            for mode, row in enumerate(loops.reference) for offset in range(0, row.size, size)]


def from_program(message: Program) -> BoardLoop:
    """The loops a Program message describes, their tables not yet filled (NaN); ValueError if its
    arrays do not fit one another."""
    k = message.kp.size
    sizes = {name: getattr(message, name).size for name in PROGRAM_ARRAYS}
    if any(size != k for size in sizes.values()):
        raise ValueError(f"program for {k} modes with arrays of sizes {sizes}")
    values = {name: getattr(message, name).astype(complex if name == "leak" else float) for name in PROGRAM_ARRAYS}
    return BoardLoop(np.full((k, int(message.periods)), np.nan + 0j), **values)
