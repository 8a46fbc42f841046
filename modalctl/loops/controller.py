"""What a per-mode controller is: the contract controller plugins implement, and what they are designed for.

A controller plugin (hook ``modalctl_controllers``) provides a :class:`ControllerFactory`; its
``create(plant: LoopPlant, **options)`` returns a :class:`Controller`, which the runtime
(:mod:`modalctl.loops.runtime`) calls once per control period with each kept mode's envelope
error in its carrier's frame. :class:`LoopDesign` is what the report shows of the design.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
import numpy as np

__all__ = ["Controller", "ControllerFactory", "LoopPlant", "LoopDesign"]


@dataclass(frozen=True)
class LoopPlant:
    """What a per-mode controller is designed for (controller plugins receive it).

    Attributes
    ----------
    frequencies, damping : ndarray, shape (k,)
        The model's modes (Hz, ratios); the carriers sit on them.
    bandwidths : ndarray, shape (k,)
        Lock-in corners (Hz).
    control_rate : float
        Hz.
    latency : float
        Control periods from a measurement to the command's use (1, plus a slow board's).
    noise : ndarray, shape (k,), optional
        Standard deviation of each measured envelope.
    level : ndarray, shape (k,), optional
        Largest planned envelope of each mode (same units).
    drift : float
        Relative resonance error expected.
    detuning : ndarray, shape (k,), optional
        Known offset of each resonance from its carrier (rad/s), e.g. from a tracker.
    schedule : Schedule, optional
        The shot's references, planned drive and planned velocity envelopes per period
        (:class:`~modalctl.loops.schedule.Schedule`), for controllers that plan with them.
    shapes : ndarray, shape (k, n), optional
        The modes' shapes on the grid (1/sqrt(kg)) and ``points`` (n, d) the grid (m): where a
        touch may rest.
    points : ndarray, shape (n, d), optional
    touch_at : int or None
        Grid point where a touch sensor says a finger rests (None: unknown).
    readable : ndarray of bool, shape (k,), optional
        The loops whose readings are trusted (the others rest).
    leaks : ndarray, shape (k,), optional
        How much more each loop's reading sees of the other modes' answer to its drive than of its own
        mode's (:func:`~modalctl.loops.sensing.leak_ratio`).
    model : ModalModel, optional
        The controller's whole model (every mode, its actuator and sensor gains) and ``modes`` (k,) the
        kept modes' positions in it: for controllers that model how the loops read each other
        (:mod:`modalctl.loops.cluster`).
    modes : ndarray of int, shape (k,), optional
    """

    frequencies: np.ndarray
    damping: np.ndarray
    bandwidths: np.ndarray
    control_rate: float
    latency: float = 1.0
    noise: np.ndarray | None = None
    level: np.ndarray | None = None
    drift: float = 0.01
    detuning: np.ndarray | None = None
    schedule: object | None = None
    shapes: np.ndarray | None = None
    points: np.ndarray | None = None
    touch_at: int | None = None
    readable: np.ndarray | None = None
    leaks: np.ndarray | None = None
    model: object | None = None
    modes: np.ndarray | None = None


class Controller(ABC):
    """Per-mode loops in the carriers' frames: what the runtime calls once per control period.

    Subclasses implement :meth:`reset` and :meth:`update` and set ``design`` (a
    :class:`LoopDesign`, for the report; its gains may be NaN where the law has none).
    :meth:`scale` multiplies the feedback (a stability test) and is optional. A controller that
    learns the plant during the shot sets ``observes`` and implements :meth:`observe`, and may say
    what it learned in :meth:`summary`.
    """

    design: LoopDesign
    observes: bool = False

    @abstractmethod
    def reset(self) -> None:
        """Forget everything learned in a shot (integrators, observer states)."""

    @abstractmethod
    def update(self, error: np.ndarray, limit: np.ndarray) -> np.ndarray:
        """Command envelopes (k,) complex (modal force, N/sqrt(kg)) from the envelope errors (k,),
        reference minus measured (m/s sqrt(kg)); each command at most ``limit`` (k,) in magnitude,
        and a loop whose limit is zero rests."""

    def scale(self, factor: float) -> None:
        """Multiply every gain by ``factor`` (a stability test: a divergent loop must be caught)."""
        raise NotImplementedError(f"{type(self).__name__} cannot scale its gains")

    def hand_over(self, amount: np.ndarray) -> None:
        """A feed-forward beside the loops now gives ``amount`` (k,) complex more of each mode's command
        than it did: the loops' integral action gives that much less, so that the command does not jump
        and the integrators do not go on supplying what the feed-forward now does (a bumpless hand-over).
        Default: nothing (a law with no integral to hand it from)."""

    def observe(self, period: int, envelope: np.ndarray, sent: np.ndarray) -> None:
        """Called before :meth:`update` when ``observes`` is set: the period's index, each mode's
        own envelope as read (k,) (the other modes' planned share and the loops' leak removed,
        m/s sqrt(kg)) and the commands sent at the end of the period before (k,)."""

    def summary(self) -> dict | None:
        """What the controller learned during the shot, for the shot's metrics (JSON-ready), or None."""
        return None


class ControllerFactory(ABC):
    """A per-mode controller as plugins provide them (hook ``modalctl_controllers``): a subclass
    names itself and makes a :class:`Controller` for a plant.

    Attributes
    ----------
    name, summary : str
    senses_touch : bool
        Whether its controllers estimate a touch (and take a touch sensor's place, ``LoopOptions.touch_at``).
    """

    name: str = ""
    summary: str = ""
    senses_touch: bool = False

    @abstractmethod
    def create(self, plant: LoopPlant, **options) -> Controller:
        """The controller of ``plant``'s modes; ``options`` are the controller's own settings."""


@dataclass(frozen=True)
class LoopDesign:
    """Per-mode PI gains and what python-control says of each loop.

    Attributes
    ----------
    kp, ki : ndarray, shape (k,)
        Proportional (1) and integral (1/s) gains from envelope error (m/s sqrt(kg)) to modal force.
    crossover_hz, phase_margin_deg, gain_margin_db : ndarray, shape (k,)
    """

    kp: np.ndarray
    ki: np.ndarray
    crossover_hz: np.ndarray
    phase_margin_deg: np.ndarray
    gain_margin_db: np.ndarray
