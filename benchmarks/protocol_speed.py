"""The board protocol's speed: encode and decode per message type, and the round trip over a pty.

    python benchmarks/protocol_speed.py   # writes benchmarks/results/protocol_speed.{json,md}

Per message type (the sizes of a 21-mode, 8-channel board): median time to encode and frame
(COBS + CRC-32) and to deframe and decode, beside the bare payload (numpy's ``tobytes`` and
``frombuffer`` of the same arrays, no header, no framing) as the peer in the same run. Then the
round trip of one control period over the emulator's pty and over python-can's virtual CAN FD bus
(with SYNC): Commands down, the emulated board plays one 25-sample period of a 21-mode structure,
Envelopes up; and a Heartbeat ping (the link and the emulator's dispatch alone).
"""

from __future__ import annotations

import time

import numpy as np
from common import command_line, median_seconds, write_json, write_markdown

from modalctl.io import protocol as p

K, A = 21, 8


def messages() -> dict:
    rng = np.random.default_rng(0)
    c = (rng.standard_normal(K) + 1j * rng.standard_normal(K)).astype(np.complex64)
    return {"Commands": p.Commands(period=7, commands=c), "Envelopes": p.Envelopes(period=7, envelopes=c),
            "Upload (4000 samples)": p.Upload(channel=1, offset=0, samples=rng.standard_normal(4000)),
            "Heartbeat": p.Heartbeat(state=2),
            "Field (8000 values)": p.Field(first=0, rows=4, offset=0, values=rng.standard_normal(8000)),
            "Program (21 modes)": p.Program(periods=580, **{f: rng.standard_normal(K) for f in ("kp", "ki", "limit")},
                                            leak=c),
            "Reference (2000 values)": p.Reference(mode=1, offset=0, values=np.resize(c, 2000))}


def payload(message) -> np.ndarray:
    for name in ("commands", "envelopes", "samples", "values"):
        if hasattr(message, name):
            return getattr(message, name)
    return np.zeros(1, np.float32)


def _trips(device, board_period, n: int, k: int) -> dict:
    """Heartbeat pings and control periods (Commands, one emulated period, Envelopes) on ``device``."""
    times = []
    for _ in range(n):
        start = time.perf_counter()
        device.send(p.Heartbeat(state=2))
        device.receive((p.Heartbeat,))
        times.append(time.perf_counter() - start)
    out = {"heartbeat ping": float(np.median(times))}
    periods, d = n + 2, 25
    device.request(p.Configure(sample_rate=500e3, control_rate=20e3, modes=k, carriers=np.linspace(400, 40e3, k),
                               bandwidths=np.full(k, 300.0), weights=np.ones((A, k)) * 1e-3, sensors=np.ones((k, 4)),
                               samples=periods * d, level=1e-3), (p.Ack,))
    device._operational(True)  # CAN: NMT start, and wait for the operational heartbeat
    device.send(p.Start())
    device.receive((p.Envelopes,))
    times = []
    for i in range(n):
        start = time.perf_counter()
        device.send(p.Commands(period=i + 1, commands=np.zeros(k, np.complex64)))
        device.sync()
        device.receive((p.Envelopes,))
        times.append(time.perf_counter() - start)
    out["control period (Commands, one emulated period, Envelopes)"] = float(np.median(times))
    return out


def round_trips(n: int = 400) -> dict:
    from modalctl.hil.can_board import CanBoardEmulator
    from modalctl.hil.scenario import Perturbation
    from modalctl.hil.serial_board import SerialBoardEmulator
    from modalctl.io.transports.can import CanDevice
    from modalctl.io.transports.serial import SerialDevice
    from modalctl.model.scenes import load_scene

    model = load_scene("thesis-al-cc", 105)
    out = {}
    with SerialBoardEmulator(model, Perturbation()) as board:
        device = SerialDevice(f"serial://{board.path}")
        device.configure(500e3)
        out |= {f"pty: {name}": s for name, s in _trips(device, board, n, K).items()}
        device.close()
    with CanBoardEmulator(model, Perturbation(), channel="speed") as board:
        device = CanDevice(board.url)
        device.configure(500e3)
        out |= {f"virtual CAN FD: {name}": s for name, s in _trips(device, board, n, K).items()}
        device.close()
    return out


def main() -> None:
    rows = []
    for name, message in messages().items():
        framed = p.frame(message)
        deframer = p.Deframer()
        raw = payload(message)
        raw_bytes = raw.tobytes()
        enc = median_seconds(lambda: p.frame(message), 2000)
        dec = median_seconds(lambda: deframer.feed(framed), 2000)
        peer_enc = median_seconds(lambda: raw.tobytes(), 2000)
        peer_dec = median_seconds(lambda: np.frombuffer(raw_bytes, raw.dtype).copy(), 2000)
        rows.append({"message": name, "bytes": len(framed), "encode_seconds": enc, "decode_seconds": dec,
                     "peer_encode_seconds": peer_enc, "peer_decode_seconds": peer_dec,
                     "messages_per_second": 1 / (enc + dec)})
    trips = round_trips()
    path = write_json("protocol_speed", {"rows": rows, "round_trips_seconds": trips})
    md = ["# Board protocol: encode, decode and round trip", "",
          "Command: `python benchmarks/protocol_speed.py`. Medians of 2,000 calls; the peer is the bare payload "
          "(numpy `tobytes` / `frombuffer`, no header, no COBS, no CRC).", "",
          "| message | bytes on the wire | encode + frame (us) | deframe + decode (us) | bare payload (us, enc / dec) | "
          "messages/s |", "|---|---|---|---|---|---|"]
    md += [f"| {r['message']} | {r['bytes']} | {1e6 * r['encode_seconds']:.1f} | {1e6 * r['decode_seconds']:.1f} | "
           f"{1e6 * r['peer_encode_seconds']:.2f} / {1e6 * r['peer_decode_seconds']:.2f} | "
           f"{r['messages_per_second']:.0f} |" for r in rows]
    md += ["", "Round trips to the emulators (medians of 400; 21 modes):", ""]
    md += [f"- {name}: {1e6 * s:.0f} us" for name, s in trips.items()]
    md += ["", "A 20 kHz loop has 50 us per period for everything; with the emulated board on the same machine the "
           "exchange alone takes longer, so closed loops over serial or CAN run at the rate the link and the board "
           "sustain (the link budgets; 2 kHz in tests/test_serial.py and tests/test_can.py), or loaded into the "
           "board (`--loop board`, one Program message) at the board's own rate: 20 kHz in link_rates.md.", ""]
    write_markdown("protocol_speed", md, path)


if __name__ == "__main__":
    command_line()
    main()
