"""Board emulators on a CAN FD bus (python-can), speaking the protocol like boards on the bench.

:class:`CanBoardEmulator` listens on a bus (python-can's ``virtual`` interface by default, so tests
need no hardware) as one or several nodes sharing one structure, each driving its group of the
actuators (``nodes = {node: (channels, sensors)}``; the sensors on one node). Messages travel in
CAN FD frames (:func:`modalctl.io.protocol.segments`); what the boards answer is
:class:`~modalctl.hil.emulator.BoardEmulator`'s. In phasor mode each board keeps the last commands
it received and all apply them on SYNC (0x080): the structure plays the next period under every
board's outputs and the sensing board answers its envelopes.

Each board follows CANopen's NMT state machine: it boots (a boot-up heartbeat), waits
pre-operational (identification, configuration, uploads, captures and scans allowed), plays shots
only once the host has sent NMT start (operational), ramps its outputs to zero when sent back to
pre-operational or stopped (stopped: it ignores everything but NMT), and starts over on NMT reset.
It sends its state as a heartbeat on 0x700 + n every ``heartbeat`` seconds and at once when the
state changes. Faults as the base class's (``drop`` loses every n-th frame sent: CAN's CRC turns a
corrupted frame into a lost one; a ``silent_after`` board sends no heartbeat either), plus
``bus_off`` after n periods (the boards leave the bus) and ``reset_after`` n periods (the sensing
board resets, as after a brown-out: boot-up, pre-operational, the shot lost).
"""

from __future__ import annotations

import threading

import numpy as np

from modalctl.io import protocol as p
from modalctl.loops.onboard import TABLE_VALUES
from modalctl.model.modes import ModalModel

from .emulator import ERRORS, BoardEmulator
from .scenario import Perturbation

__all__ = ["CanBoardEmulator"]
BOOT_UP, STOPPED, OPERATIONAL, PRE_OPERATIONAL = 0x00, 0x04, 0x05, 0x7F  # CANopen's NMT states


class CanBoardEmulator(BoardEmulator):
    """The HIL boards on ``channel`` (other parameters: :class:`~modalctl.hil.emulator.BoardEmulator`).

    Parameters
    ----------
    nodes : dict, optional
        ``{node: (channels, sensors)}``: each board's actuator channels and sensors (global
        indices, in node order); one board with everything by default (node 1).

    ``url`` is what the host opens: ``can://virtual/<channel>?nodes=<n1,n2,...>``.
    """

    name = "modalctl HIL board on CAN FD"
    field_values = 1800  # a message is at most 127 frames of 61 bytes

    def __init__(self, model: ModalModel, perturbation: Perturbation = Perturbation(), latency: int = 0,
                 faults: dict | None = None, channel: str = "bench0", nodes: dict | None = None,
                 interface: str = "virtual", heartbeat: float = 0.1):
        import can

        super().__init__(model, perturbation, latency, faults)
        a, s = model.actuator_gains.shape[1], model.sensor_gains.shape[1]
        nodes = nodes or {1: (range(a), range(s))}
        self.layout = {int(n): (np.asarray(list(c), int), np.asarray(list(q), int)) for n, (c, q) in nodes.items()}
        order = np.concatenate([c for c, _ in self.layout.values()])
        if sorted(order.tolist()) != list(range(a)):
            raise ValueError(f"the boards' channels must cover the {a} actuators once each")
        sensing = [n for n, (_, q) in self.layout.items() if q.size]
        if len(sensing) != 1 or self.layout[sensing[0]][1].size != s:
            raise ValueError("one board carries every sensor")
        self.sensing = sensing[0]
        self.channel = channel
        self.url = f"can://{interface}/{channel}?nodes={','.join(str(n) for n in self.layout)}"
        self.bus = can.Bus(interface=interface, channel=channel, fd=True)
        self._can = can
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="CAN boards", daemon=True)
        self.heartbeat = float(heartbeat)
        self._beating = threading.Thread(target=self._beat, name="CAN heartbeats", daemon=True)
        self.states = {node: BOOT_UP for node in self.layout}  # NMT state of each board
        self._node = self.sensing  # who answers the message being handled
        self._configs: dict = {}
        self._started: dict = {}  # node -> the sequence of its Start
        self._commands: dict = {}

    def __enter__(self):
        self._thread.start()
        for node in self.layout:
            self._enter(node, PRE_OPERATIONAL)  # boot-up heartbeat, then pre-operational
        self._beating.start()
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self._beating.join(timeout=2)
        self.bus.shutdown()

    # -- the wire ------------------------------------------------------------------------------
    def _send(self, message: p.Message) -> None:
        for data in p.segments(self._stamp(message)):
            data = self._faulty(data)
            if data is not None:
                self.bus.send(self._can.Message(arbitration_id=p.to_host(self._node), data=data, is_fd=True,
                                                bitrate_switch=True, is_extended_id=False))

    def _gone(self) -> bool:
        """Whether the boards have stopped answering or left the bus (bus-off)."""
        off = self.faults.get("bus_off")
        return self._silent() or (off is not None and getattr(self.board, "period", -1) >= off)

    def _serve(self) -> None:
        reassemblers = {p.to_board(n): (n, p.Reassembler()) for n in self.layout}
        while not self._stop.is_set():
            frame = self.bus.recv(timeout=0.05)
            if frame is None:
                continue
            if self._gone():
                continue  # the boards have left the bus, or hang
            if frame.arbitration_id == p.NMT_ID and len(frame.data) >= 2:
                self._nmt(frame.data[0], frame.data[1])
            elif frame.arbitration_id == p.SYNC_ID:
                if self.states[self.sensing] == OPERATIONAL:
                    self._sync()
            elif frame.arbitration_id in reassemblers:
                node, reassembler = reassemblers[frame.arbitration_id]
                if self.states[node] == STOPPED:
                    continue  # a stopped node hears only NMT
                item = reassembler.feed(bytes(frame.data))
                if item is not None:
                    self._node = node
                    if isinstance(item, (p.Start, p.Commands)) and self.states[node] != OPERATIONAL:
                        self._refuse("state", f"node {node} is {p.NMT_STATES[self.states[node]]}: "
                                              "send NMT start before a shot")
                    else:
                        self._receive(item)

    # -- CANopen: NMT and heartbeat ------------------------------------------------------------
    def _beat(self) -> None:
        while not self._stop.wait(self.heartbeat):
            if not self._gone():
                for node, state in list(self.states.items()):
                    self._heartbeat(node, state)

    def _heartbeat(self, node: int, state: int) -> None:
        self.bus.send(self._can.Message(arbitration_id=p.heartbeat_id(node), data=bytes([state]),
                                        is_extended_id=False))

    def _enter(self, node: int, state: int) -> None:
        """Move ``node`` to an NMT state and say so at once; leaving operational ramps the shot down,
        a reset (boot-up) loses it."""
        if state == BOOT_UP:
            self._heartbeat(node, BOOT_UP)
            self.board, self.config, self.loops = None, None, None
            state = PRE_OPERATIONAL
        elif self.states[node] == OPERATIONAL and state != OPERATIONAL and self.board is not None:
            self.board.ramp_down(1 / self.board.schedule.control_rate)
        self.states[node] = state
        self._heartbeat(node, state)

    def _nmt(self, command: int, target: int) -> None:
        states = {0x01: OPERATIONAL, 0x02: STOPPED, 0x80: PRE_OPERATIONAL, 0x81: BOOT_UP, 0x82: BOOT_UP}
        if command in states:
            for node in self.layout if target == 0 else [target] if target in self.layout else []:
                self._enter(node, states[command])

    # -- each board its share ------------------------------------------------------------------
    def _on_hello(self, message: p.Hello) -> None:
        channels, sensors = self.layout[self._node]
        limit, snr = self.perturbation.voltage_limit, self.perturbation.snr_db
        self._send(p.Info(channels=channels.size, sensors=sensors.size, max_sample_rate=self.MAX_SAMPLE_RATE,
                          voltage_limit=float("nan") if limit is None else limit, max_modes=self.MAX_MODES,
                          scans=self.model.grid.points.shape[0] if self._node == self.sensing else 0,
                          snr_db=float("nan") if snr is None else snr, table=TABLE_VALUES,
                          name=self._named(f", node {self._node}")))

    def _on_configure(self, message: p.Configure) -> None:
        channels, sensors = self.layout[self._node]
        k = message.modes
        if (why := self._invalid(message)) is not None:
            self._refuse("config", f"configure: {why}")
            return
        if message.weights.size != channels.size * k or message.sensors.size != k * sensors.size:
            self._refuse("config", f"configure: node {self._node} has {channels.size} channels and "
                                   f"{sensors.size} sensors")
            return
        self._configs[self._node] = message
        self._started.clear()
        self._send(p.Ack(of=message.TYPE, ack_seq=message.seq))
        if len(self._configs) == len(self.layout):  # the whole shot: every board's share in one
            a, s = self.model.actuator_gains.shape[1], self.model.sensor_gains.shape[1]
            weights, sensing = np.zeros((a, k)), np.zeros((k, s))
            for node, config in self._configs.items():
                rows, cols = self.layout[node]
                weights[rows] = config.weights.reshape(rows.size, k)
                sensing[:, cols] = config.sensors.reshape(k, cols.size)
            self.config = p.Configure(sample_rate=message.sample_rate, control_rate=message.control_rate, modes=k,
                                      carriers=message.carriers, bandwidths=message.bandwidths, weights=weights,
                                      sensors=sensing, samples=message.samples, level=message.level)
            self.feedforward, self.board, self.capture = np.zeros((a, message.samples)), None, None
            self.loops = None
            self._configs = {}

    def _on_upload(self, message: p.Upload) -> None:
        channels = self.layout[self._node][0]
        if self.feedforward is None or message.channel >= channels.size:
            self._refuse("state", f"upload to node {self._node} channel {message.channel} before its configuration")
            return
        super()._on_upload(p.Upload(seq=message.seq, channel=int(channels[message.channel]), offset=message.offset,
                                    samples=message.samples))

    def _on_start(self, message: p.Start) -> None:
        self._started[self._node] = message.seq
        if set(self._started) != set(self.layout):
            return  # the shot starts when every board is armed
        started, self._started = self._started, {}
        self._commands = {}
        open_loop = self.config is not None and self.config.modes == 0
        self._node, self._answering = self.sensing, started[self.sensing]
        super()._on_start(p.Start(seq=started[self.sensing]))
        if open_loop:  # every board reports its part done, answering its own Start
            for node in self.layout:
                if node != self.sensing:
                    self._node, self._answering = node, started[node]
                    self._send(p.Ack(of=message.TYPE, ack_seq=started[node]))

    def _on_commands(self, message: p.Commands) -> None:
        if not self._usable(message):
            return
        self._commands[self._node] = message.commands.astype(complex)  # applied on SYNC

    def _sync(self) -> None:
        if self.board is None or not self._commands:
            return
        received = [self._commands.get(node) for node in self.layout]
        if all(c is not None and np.array_equal(c, received[0]) for c in received):  # every board, the same
            self.board.write(received[0])
        else:  # a board that missed its commands drives nothing
            k = self.config.modes
            rows = np.zeros((self.model.actuator_gains.shape[1], k), complex)
            for node, (channels, _) in self.layout.items():
                rows[channels] = self._commands.get(node, np.zeros(k))
            self.board.write_phasors(self.board.schedule.weights * rows)
        self._node = self.sensing
        reset = self.faults.get("reset_after")
        if reset is not None and self.board.period >= reset:
            self.faults.pop("reset_after")
            self._enter(self.sensing, BOOT_UP)  # a brown-out: the shot is lost
            return
        self._answer_period()

    def _on_program(self, message: p.Program) -> None:
        if len(self.layout) > 1:
            self._refuse("unsupported", "loops on the boards need one board with every channel and sensor")
            return
        super()._on_program(message)

    def _on_capture(self, message: p.Capture) -> None:
        if message.what == 2:  # the loops' record: rows are the log's
            super()._on_capture(message)
            return
        channels, sensors = self.layout[self._node]
        mine = channels if message.what == 0 else sensors
        rows = mine if message.rows.size == 0 else mine[message.rows.astype(int)]
        super()._on_capture(p.Capture(seq=message.seq, what=message.what, rows=rows.astype(np.float32),
                                      offset=message.offset, count=message.count))

    def _on_scan(self, message: p.Scan) -> None:
        if self._node != self.sensing:
            self._send(p.Error(code=ERRORS["unsupported"], text=f"node {self._node} has no vibrometer"))
            return
        super()._on_scan(message)
