"""``sim://``: the HIL board. It runs the exact plant on the perturbed truth behind the device interface:
drifted and erred modes, a finger resting on the surface, resonances moving during the shot."""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.fft
from tqdm.auto import tqdm

from modalctl.errors import InputError
from modalctl.io.device import Capabilities, Capture, Device, DeviceContext, DeviceError, url_options
from modalctl.loops.onboard import TABLE_VALUES
from modalctl.model.modes import ModalModel, ModelError
from modalctl.model.noise_stream import NoiseStream
from modalctl.model.scenes import SCENES, continued, load_scene
from modalctl.model.shape import ParamError

from .finger import FingerPlant
from .plant import HOLDS, Plant, truncation
from .scenario import Perturbation, perturb
from .vibrometer import scan_field, scan_modes, scan_noise_stream, scan_spectrum

__all__ = ["SimDevice"]

CHUNK = 8192  # samples per plant step (one progress-bar tick)
SPECTRUM_KEY = 1  # in the key of the noise of a shot's spectrum (scan_spectrum)
DRIFT_STEP = 50e-6  # s: resonances moving during a shot are retuned this often (the loops' period at 20 kHz)


class SimDevice(Device):
    """A simulated amplifier board on a simulated structure, with a scanning vibrometer.

    Parameters
    ----------
    model : ModalModel
        The structure as built (every mode known); the truth is ``perturb(model, perturbation)``.
    perturbation : Perturbation
    hold : {"zoh", "foh"}
        DAC output between samples.
    tol : float
        Modes whose bound on the velocity they add is below ``tol`` times the largest are left out
        of the simulation; the sum of their bounds is reported in ``info``.
    url : str
    """

    max_sample_rate = 10e6

    def __init__(self, model: ModalModel, perturbation: Perturbation = Perturbation(), hold: str = "zoh",
                 tol: float = 1e-4, url: str = "sim://"):
        if hold not in HOLDS:
            raise InputError(f"{url}: hold must be one of {HOLDS}, got {hold!r}")
        super().__init__(url)
        self.model, self.perturbation, self.hold, self.tol = model, perturbation, hold, tol
        self.truth = perturb(model, perturbation)
        self.finger = _finger(model, perturbation, url)  # a Touch, a TouchPath or None
        self.sample_rate = None
        self.info["truth"] = perturbation.describe()
        if perturbation.finger:  # where the report draws it
            self.info["finger_at_m"] = [float(x) for x in perturbation.finger_at]
        self._noise_sigma = None
        self._voltages = self._modal = self._board = None
        self._spectra = {}  # the last shot's modal spectra by band (scan_spectrum)
        self._last_drive, self._pending, self._played = None, False, None  # the last drive played (_replay)
        self._unit_bounds = None  # (waveform's digest, its modes' bounds with unit gains): _truncation
        self._boards = 0  # phasor boards made so far
        self._shots = 0  # open-loop shots triggered so far (each its own scan noise)
        self._kept = np.arange(model.n_modes)
        self._rng = np.random.default_rng(perturbation.seed + 1)

    @classmethod
    def from_url(cls, url: str, context: DeviceContext) -> "SimDevice":
        """``sim://?hold=zoh&tol=1e-4``. The structure is the context's model, or the scene its
        ``truth`` option names (the same actuators and sensors, other modes); the other options
        (those of :func:`modalctl.hil.transport.modalctl_add_options`) make its perturbation."""
        query = url_options(url, {"hold", "tol"})  # the URL is the user's: InputError (exit 2)
        try:
            tol = float(query.get("tol", 1e-4))
        except ValueError:
            raise InputError(f"{url}: tol must be a number, got {query['tol']!r}") from None
        if not 0 < tol < 1:
            raise InputError(f"{url}: tol must lie in (0, 1), got {tol:g}")
        structure = _structure(context)
        # the target lies on the model's grid: its peak is placed by position, whatever the truth's grid
        perturbation = Perturbation.from_options(context.options, context.model or structure, context.target)
        device = cls(structure, perturbation, query.get("hold", "zoh"), tol, url)
        if structure is not context.model:  # say which structure stands for the truth
            named = context.options.get("truth") or structure.meta.get("name", "the model")
            device.info["truth"] = f"{named}, {structure.n_modes} modes; {device.info['truth']}"
        return device

    def configure(self, sample_rate: float) -> Capabilities:
        """Set the DAC/ADC rate (Hz) and report what the board can do."""
        if not 0 < sample_rate <= self.max_sample_rate:
            raise DeviceError(f"{self.url}: sample rate {sample_rate:g} Hz outside (0, {self.max_sample_rate:g}]")
        self.sample_rate, self.state, self._last_drive, self._unit_bounds = float(sample_rate), "inactive", None, None
        self.capabilities = Capabilities("modalctl HIL board", self.model.actuator_gains.shape[1],
                                         self.model.sensor_gains.shape[1], self.max_sample_rate,
                                         self.perturbation.voltage_limit, True, self.model.grid.points,
                                         phasor_mode=True, table_values=TABLE_VALUES)
        return self.capabilities

    def upload(self, voltages: np.ndarray) -> None:
        """Load one shot of waveforms, shape (channels, n), in volts."""
        u = np.atleast_2d(np.asarray(voltages, float))
        channels = self.model.actuator_gains.shape[1]
        if u.shape[0] != channels:
            raise DeviceError(f"{self.url}: {u.shape[0]} waveforms for {channels} channels")
        if not np.all(np.isfinite(u)):
            raise DeviceError(f"{self.url}: waveform contains non-finite samples")
        self._voltages, self._pending, self._board = u, True, None

    def trigger(self, progress: bool = False) -> Capture:
        """Play the uploaded waveforms and record the sensors (the plant from rest)."""
        if self.state != "active":
            raise DeviceError(f"{self.url}: trigger needs an active device (state: {self.state})")
        if self._voltages is None:
            raise DeviceError(f"{self.url}: nothing uploaded")
        u, p = self._voltages, self.perturbation
        if self._pending:  # the structure answers a repeated drive identically; only noise differs
            self._replay(u, progress)
            self._pending = False
        self._shots += 1  # every shot its own vibrometer noise (a repeated one too: averages average)
        times, sigma, applied = self._record  # the same for every repeat of the drive
        sensors = self._played + sigma * self._rng.standard_normal(self._played.shape)
        return Capture(times, sensors, applied)

    def _replay(self, u: np.ndarray, progress: bool) -> None:
        """The structure's answer to the drive ``u``: played, or kept from the shot before when that
        played the same drive (an FRF survey's sparse sweep of an actuator, then its full scan)."""
        key = hashlib.blake2b(u.tobytes(), digest_size=16).digest() + repr(u.shape).encode()
        if key != self._last_drive:
            p = self.perturbation
            self._play(u, progress)
            peak = np.abs(self._played).max(initial=0.0)  # no sensors (an identified model's truth): none
            self._record = np.arange(u.shape[1]) / self.sample_rate, self._sigma(peak), \
                np.clip(u, -p.voltage_limit, p.voltage_limit) if p.voltage_limit else u
            self._last_drive = key

    def _play(self, u: np.ndarray, progress: bool) -> None:
        p = self.perturbation
        if self.finger is None:
            kept, dropped = self._truncation(u)
            plant = Plant(self.truth.select(kept), self.sample_rate, self.hold, p.amplifier_bandwidth,
                          p.voltage_limit)
        else:  # the finger couples every mode to every other: all are simulated
            kept, dropped = np.arange(self.truth.n_modes), 0.0
            plant = FingerPlant(self.truth, self.finger, self.sample_rate, p.voltage_limit, self.hold)
        self._kept = kept
        self.info.update({"modes_simulated": int(kept.size), "modes_available": int(self.truth.n_modes),
                          "truncation_bound_m_s": dropped, "truncation_tol": self.tol})
        chunk = max(1, int(round(DRIFT_STEP * self.sample_rate))) if p.moving or p.touch_moves else CHUNK
        chunks = range(0, u.shape[1], chunk)
        bar = tqdm(chunks, desc="HIL shot", unit="chunk", disable=not progress or len(chunks) < 4, leave=False)
        base = plant.model.frequencies.copy()
        played = []
        for i in bar:
            if p.moving:
                plant.retune(base * (1 + p.shift((i + chunk / 2) / self.sample_rate)))  # the chunk's middle
            played.append(plant.step(u[:, i:i + chunk]))
        self._modal = np.hstack(played)
        self._spectra = {}  # the modes' spectra of this shot, by band (scan_spectrum)
        self.info["clipped_samples"] = plant.clipped
        self._noise_sigma = self._sigma(self._field_peak()) / np.sqrt(self.perturbation.scan_repeats)
        self._played = plant.sensors(self._modal)

    def _truncation(self, u: np.ndarray) -> tuple[np.ndarray, float]:
        """:func:`~modalctl.hil.plant.truncation`'s modes kept and dropped bound for the drive ``u``.
        A drive on one channel is a waveform times that channel's gains: the waveform's bounds with
        unit gains (its spectrum's integrals, the cost) are made once and scaled for each channel."""
        active = np.flatnonzero(np.any(u != 0, axis=1))
        if active.size != 1:
            return truncation(self.truth, u, self.sample_rate, self.tol)[::2]
        key = hashlib.blake2b(u[active[0]].tobytes(), digest_size=16).digest()
        if self._unit_bounds is None or self._unit_bounds[0] != key:
            unit = replace(self.truth, actuator_gains=np.ones((self.truth.n_modes, 1)))
            self._unit_bounds = key, truncation(unit, u[active], self.sample_rate, self.tol)[1]
        bounds = np.abs(self.truth.actuator_gains[:, active[0]]) * self._unit_bounds[1]
        kept = np.flatnonzero(bounds >= self.tol * bounds.max())
        return kept, float(np.delete(bounds, kept).sum())

    def phasor_board(self, level: float, control_rate: float, latency: int = 0):
        """The board in phasor mode (closed loop) on the same truth, for a shot whose field peaks
        near ``level`` (m/s): sensor and vibrometer noise ``snr_db`` below it (the vibrometer's
        averaged over ``scan_repeats``), the same rails and amplifier, the resonances moving as the
        perturbation says. Returns an :class:`~modalctl.hil.phasor_board.HILBoard` at the
        configured sample rate."""
        from .phasor_board import BoardSetup, HILBoard

        if self.sample_rate is None:
            raise DeviceError(f"{self.url}: configure before asking for the phasor mode")
        p = self.perturbation
        sigma = self._sigma(level)
        truth = self.truth if self.finger is None else FingerPlant(self.truth, self.finger, self.sample_rate,
                                                                   p.voltage_limit)
        self._boards += 1  # each shot its own noise
        self._board = HILBoard(truth, self.sample_rate, BoardSetup(
            noise=sigma, voltage_limit=p.voltage_limit, latency=latency, drift=p.schedule(),
            amplifier_bandwidth=p.amplifier_bandwidth, scan_noise=sigma / np.sqrt(p.scan_repeats),
            seed=p.seed + self._boards))
        return self._board

    def scan(self, times: np.ndarray, points=None) -> np.ndarray:
        """Velocity (n_points, nt) at the samples nearest to ``times`` of the last shot (m/s, float32:
        :func:`~modalctl.hil.vibrometer.scan_field`, the modes' velocities there times their shapes,
        with the vibrometer's noise).

        ``points``: grid indices to measure (default all), like moving the vibrometer's spot.
        """
        if self._board is not None:  # the last shot ran in phasor mode
            return self._board.scan(times, points)
        idx = self._samples(times)
        field = scan_field(self.truth.shapes[self._kept], self._modal[:, idx], idx, points)
        noise = self.scan_noise_stream(times, points)  # one description of the noise, added and recorded
        if noise is not None:
            noise.add_to(field)
        return field

    def scan_spectrum(self, bins: slice, points=None) -> np.ndarray:
        """The ``rfft`` at ``bins`` of the last shot's whole scan at ``points`` (default all):
        ``rfft(scan(capture.times, points))[:, bins]`` (len(points), nb), complex (m/s), made from
        the modes' spectra (once a shot, shared by all points: the structure is linear) as one
        product, its noise drawn in the frequency domain
        (:func:`~modalctl.hil.vibrometer.scan_spectrum`): no per-point record nor FFT. The FRF
        survey's fast path (:func:`~modalctl.identify.acquire.measure_frf`)."""
        if self._board is not None:
            raise DeviceError(f"{self.url}: the scan's spectrum is of open-loop shots only")
        if self._modal is None:
            raise DeviceError(f"{self.url}: no shot to scan")
        n = self._modal.shape[1]
        index = np.arange(n // 2 + 1)[bins]
        band = (int(index[0]), int(index[-1]) + 1) if index.size else (0, 0)
        if band not in self._spectra:  # one band a shot kept (in place: a replayed drive keeps it too)
            self._spectra.clear()
            self._spectra[band] = scipy.fft.rfft(self._modal, axis=-1)[:, bins]  # one thread: see identify.frf.H1.add
        return scan_spectrum(self.truth.shapes[self._kept], self._spectra[band], index, n, points,
                             self._noise_sigma or 0.0, (self.perturbation.seed, self._shots, SPECTRUM_KEY))

    def scan_noise_stream(self, times: np.ndarray, points=None) -> NoiseStream | None:
        """The vibrometer's noise in ``scan(times, points)`` (its stream's key, sigma, samples and
        points), None without noise."""
        if self._board is not None:
            return self._board.scan_noise_stream(times, points)
        return scan_noise_stream((self.perturbation.seed, self._shots), self._samples(times),
                                 self.truth.shapes.shape[1], self._noise_sigma or 0.0, points)

    def scan_modes(self, times: np.ndarray, points=None) -> tuple[np.ndarray, np.ndarray]:
        """The simulated modes' shapes on the points ``scan(times, points)`` reads (n, k) and their
        velocities then (k, nt): the scan less its noise, as made."""
        if self._board is not None:
            return self._board.scan_modes(times, points)
        return scan_modes(self.truth.shapes[self._kept], self._modal[:, self._samples(times)], points)

    def _samples(self, times: np.ndarray) -> np.ndarray:
        """The last open-loop shot's sample indices nearest to ``times``."""
        if self._modal is None:
            raise DeviceError(f"{self.url}: no shot to scan")
        return np.clip(np.round(np.asarray(times) * self.sample_rate).astype(int), 0, self._modal.shape[1] - 1)

    def modal_truth(self) -> tuple[np.ndarray, np.ndarray]:
        """Simulation-only: the simulated modes (positional in the model) and their velocities (k, n)."""
        return self._kept, self._modal

    def _field_peak(self, points: int = 64) -> float:
        """Peak |velocity| of the last shot over time and over about ``points`` evenly spread grid points (m/s)."""
        shapes = self.truth.shapes[self._kept]
        stride = max(1, shapes.shape[1] // points)
        return float(np.max(np.abs(shapes[:, ::stride].T @ self._modal)))

    def _sigma(self, peak: float) -> float:
        """Noise standard deviation for a signal of this peak (0 without noise)."""
        snr = self.perturbation.snr_db
        return 0.0 if snr is None else peak / 10 ** (snr / 20)


def _finger(model: ModalModel, p: Perturbation, url: str):
    """The perturbation's finger on the grid point nearest to where it rests (a
    :class:`~modalctl.model.touch.Touch`), where it is at each time when it moves (a
    :data:`~modalctl.hil.finger.TouchPath`), or None."""
    try:
        return p.touch_path(model)
    except ModelError as exc:
        raise ParamError(f"{url}: the finger: {exc}") from None


def _structure(context: DeviceContext) -> ModalModel:
    """The structure to simulate: the scene or model file of the ``truth`` option, or the model
    planned on; continued to ``truth_modes`` modes when asked (:func:`~modalctl.model.scenes.continued`)."""
    name, model, modes = context.options.get("truth"), context.model, context.options.get("truth_modes")
    if name is None and model is None:
        raise DeviceError("sim://: the simulator needs the structure's model (a scene, a model file or --truth)")
    truth = model if name is None else _named_truth(str(name))
    if modes is not None:
        truth = continued(truth, int(modes))
    if model is not None and truth is not model:
        _same_structure(model, truth, name or f"{modes} modes")
    return truth


def _named_truth(name: str) -> ModalModel:
    """A scene by name, or a model file (``.npz``) by path: a scene's name is the scene, even where a
    file of that name lies in the working directory."""
    if name in SCENES:
        return load_scene(name)
    if name.endswith(".npz") or Path(name).is_file():
        return ModalModel.load(name)
    return load_scene(name)  # an unknown name: the scenes' own error lists them


def _same_structure(model: ModalModel, truth: ModalModel, name: str) -> None:
    """ModelError unless ``truth`` has ``model``'s actuators and sensors (an identified model's
    sensors are the device's: not compared). Its grid may differ: the vibrometer scans the truth's
    points nearest the model's (:func:`~modalctl.io.device.scan_indices`)."""
    for what in ("actuator", "sensor"):
        ours, theirs = (getattr(m, f"{what}_gains").shape[1] for m in (model, truth))
        if what == "sensor" and ours == 0:  # an identified model: the sensors are the device's, unmodelled
            continue
        if ours != theirs:
            raise ModelError(f"--truth {name} has {theirs} {what}s, the model {ours}: the truth must be the "
                             f"same structure as the one planned on (its modes may differ)")
