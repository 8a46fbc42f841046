"""A board emulator on a CAN FD bus (python-can), speaking the protocol like a board on the bench.

:class:`CanBoardEmulator` listens on a bus (python-can's ``virtual`` interface by default, so tests
need no hardware) as node ``node``: messages in CAN FD frames (:func:`modalctl.protocol.segments`),
what it answers is :class:`~modalctl.hil.emulator.BoardEmulator`; in phasor mode it applies the
last commands on SYNC (0x080), plays the period and answers its envelopes. Faults as the base
class's (``drop`` loses every n-th frame sent, as CAN's CRC turns a corrupted frame into a lost
one), plus ``bus_off`` after n periods: the board leaves the bus.
"""

from __future__ import annotations

import threading

from modalctl import protocol as p
from modalctl.model import ModalModel

from .emulator import BoardEmulator
from .scenario import Perturbation

__all__ = ["CanBoardEmulator"]


class CanBoardEmulator(BoardEmulator):
    """The HIL board as CAN FD node ``node`` on ``channel`` (parameters: :class:`~modalctl.hil.emulator.BoardEmulator`).

    ``url`` is what the host opens: ``can://virtual/<channel>?node=<node>``.
    """

    name = "modalctl HIL board on CAN FD"
    field_values = 1800  # a message is at most 127 frames of 61 bytes

    def __init__(self, model: ModalModel, perturbation: Perturbation = Perturbation(), latency: int = 0,
                 faults: dict | None = None, channel: str = "bench0", node: int = 1, interface: str = "virtual"):
        import can

        super().__init__(model, perturbation, latency, faults)
        self.node, self.channel = int(node), channel
        self.url = f"can://{interface}/{channel}?node={self.node}"
        self.bus = can.Bus(interface=interface, channel=channel, fd=True)
        self._can = can
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="CAN board", daemon=True)
        self._pending = None  # commands waiting for SYNC

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.bus.shutdown()

    def _send(self, message: p.Message) -> None:
        for data in p.segments(message):
            data = self._faulty(data)
            if data is not None:
                self.bus.send(self._can.Message(arbitration_id=p.to_host(self.node), data=data, is_fd=True,
                                                bitrate_switch=True, is_extended_id=False))

    def _serve(self) -> None:
        reassembler = p.Reassembler()
        while not self._stop.is_set():
            frame = self.bus.recv(timeout=0.05)
            if frame is None:
                continue
            off = self.faults.get("bus_off")
            if off is not None and self.board is not None and self.board.period >= off:
                continue  # the board has left the bus
            if frame.arbitration_id == p.SYNC_ID:
                self._sync()
            elif frame.arbitration_id == p.to_board(self.node):
                item = reassembler.feed(bytes(frame.data))
                if item is not None:
                    self._receive(item)

    def _on_commands(self, message: p.Commands) -> None:
        self._pending = message  # applied on SYNC, with every other board on the bus

    def _sync(self) -> None:
        if self._pending is not None and self.board is not None:
            message, self._pending = self._pending, None
            super()._on_commands(message)
