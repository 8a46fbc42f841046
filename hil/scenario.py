"""What makes the truth differ from the controller's model: drift, damping error, noise, amplifier."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from modalctl.model import ModalModel

__all__ = ["Perturbation", "perturb"]


@dataclass(frozen=True)
class Perturbation:
    """A realistic departure of the structure and the electronics from the model.

    Attributes
    ----------
    drift : float
        Relative shift of every resonance frequency (0.01 = +1%, a few kelvin on aluminium).
    drift_spread : float
        Standard deviation of an extra random shift per mode (relative).
    damping_error : float
        Relative error of every damping ratio (0.2 = 20% more damping than modelled).
    snr_db : float or None
        Measurement noise: white, with a standard deviation of the shot's peak over 10^(snr/20)
        (the vibrometer: the peak velocity over the whole grid; each sensor: its own peak).
    amplifier_bandwidth : float or None
        First-order amplifier bandwidth (Hz).
    voltage_limit : float or None
        Amplifier rails (V).
    seed : int
        Random seed of the spread and the noise.
    """

    drift: float = 0.0
    drift_spread: float = 0.0
    damping_error: float = 0.0
    snr_db: float | None = None
    amplifier_bandwidth: float | None = None
    voltage_limit: float | None = None
    seed: int = 0

    def describe(self) -> str:
        """One line for tables and reports."""
        parts = [f"drift {100 * self.drift:+.1f}%" if self.drift else "",
                 f"spread {100 * self.drift_spread:.1f}%" if self.drift_spread else "",
                 f"damping {100 * self.damping_error:+.0f}%" if self.damping_error else "",
                 f"SNR {self.snr_db:g} dB" if self.snr_db is not None else "",
                 f"amplifier {self.amplifier_bandwidth / 1e3:g} kHz" if self.amplifier_bandwidth else "",
                 f"rails {self.voltage_limit:g} V" if self.voltage_limit else ""]
        return ", ".join(p for p in parts if p) or "perfect model"


def perturb(model: ModalModel, p: Perturbation) -> ModalModel:
    """The truth model: ``model`` with drifted resonances and erred damping (shapes unchanged)."""
    rng = np.random.default_rng(p.seed)
    shift = 1 + p.drift + p.drift_spread * rng.standard_normal(model.n_modes)
    return replace(model, frequencies=model.frequencies * shift,
                   damping=model.damping * (1 + p.damping_error))
