"""A board emulator behind a real serial device path: a pseudo-terminal pair speaking the protocol.

:class:`SerialBoardEmulator` opens a pty pair, hands out the device path (``/dev/pts/N``) for
``serial:///dev/pts/N``, and serves the board protocol from a thread (what it answers:
:class:`~modalctl.hil.emulator.BoardEmulator`), the frames COBS-encoded with their CRC. Beside the
base class's faults, ``die_after`` n periods: the board is unplugged (its end of the line closes,
the host's reads and writes fail as on a USB adapter pulled out).
"""

from __future__ import annotations

import os
import select
import threading
import tty

from modalctl.io import protocol as p
from modalctl.model.modes import ModalModel

from .emulator import ERRORS, BoardEmulator
from .scenario import Perturbation

__all__ = ["SerialBoardEmulator", "ERRORS"]


class SerialBoardEmulator(BoardEmulator):
    """The HIL board on a pty (parameters: :class:`~modalctl.hil.emulator.BoardEmulator`)."""

    name = "modalctl HIL board on a pty"

    def __init__(self, model: ModalModel, perturbation: Perturbation = Perturbation(), latency: int = 0,
                 faults: dict | None = None):
        super().__init__(model, perturbation, latency, faults)
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self._slave = slave
        self._fds = (self.master, slave)  # open until unplugged or closed
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="serial board", daemon=True)

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.close()

    def start(self) -> "SerialBoardEmulator":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=2)
        self._unplug()

    def _dead(self) -> bool:
        """Whether the board has been unplugged (the ``die_after`` fault)."""
        die = self.faults.get("die_after")
        return die is not None and getattr(self.board, "period", -1) >= die

    def _unplug(self) -> None:
        """Close the board's end of the line: the host's side hangs up (EIO)."""
        self._stop.set()
        fds, self._fds = self._fds, ()  # once: a closed number may be reused by another file
        for fd in fds:
            os.close(fd)

    def _send(self, message: p.Message) -> None:
        if self._dead():
            self._unplug()
            return
        data = self._faulty(p.frame(self._stamp(message)), b"\x00")
        if data is None:
            return
        view = memoryview(data)
        while view:
            view = view[os.write(self.master, view):]

    def _serve(self) -> None:
        deframer = p.Deframer()
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(self.master, 1 << 16)
            except OSError:
                return
            for item in deframer.feed(data):
                self._receive(item)
