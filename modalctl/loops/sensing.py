"""How the loops read their modes through the sensors, and what each mode's drive leaks into them.

Shared by the closed loop (:mod:`modalctl.loops.shot`) and the trackers' scenarios: each kept mode
is read through a combination of the sensors (:func:`sensor_weights`); driving a mode at its
carrier also moves the other modes, whose answer reaches that reading (:func:`feedthrough`, removed
as a static gain), and a loop whose reading sees more of the others than of its own mode rests
(:func:`leak_ratio`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["sensor_weights", "feedthrough", "leak_ratio"]


def sensor_weights(model, modes, nulls: int = 0) -> np.ndarray:
    """Sensor combinations that read each mode, shape (k, s).

    Row ``i`` gives 1 for mode ``modes[i]`` and 0 for the ``nulls`` modes of ``model`` nearest
    to it in frequency, the least-norm such weights. The default (no nulls, the matched
    filter) leaves the separation to the lock-in: on thesis-al-cc with four sensors, nulling
    three neighbours amplified the leakage of weakly sensed modes (mode 16 lost its lock).
    """
    c = model.sensor_gains  # (all modes, s)
    rows = []
    for k in np.atleast_1d(modes):
        order = np.argsort(np.abs(np.log(model.frequencies / model.frequencies[k])))
        near = [j for j in order if j != k][:nulls]
        rows.append(np.linalg.pinv(c[[k, *near]]) @ np.eye(len(near) + 1)[0])
    return np.array(rows)


def feedthrough(model, modes, sensors: np.ndarray, actuators: np.ndarray) -> np.ndarray:
    """What each mode's reading picks up from the *other* modes answering its own drive, shape (k,).

    Mode ``modes[i]`` is driven at its carrier through actuator weights ``actuators[:, i]``;
    every other mode j answers at that frequency with ``H_j(j w_i) (b_j . g_i)`` (off resonance,
    nearly independent of drift) and reaches the reading ``sensors[i]`` through ``C_j``. The sum
    multiplies the drive envelope in the mode's frame: subtract it from the response envelope
    before tracking (a pole tracker would read it as a pole shift).

    Parameters
    ----------
    sensors : ndarray, shape (k, s)
        Sensor weights per tracked mode.
    actuators : ndarray, shape (a, k)
        Actuator weights per tracked mode (unit modal force).
    """
    terms = _paths(model, modes, sensors, actuators)
    terms[np.arange(terms.shape[0]), modes] = 0  # the mode itself is what is tracked
    return terms.sum(axis=1)


def leak_ratio(model, modes, sensors: np.ndarray, actuators: np.ndarray) -> np.ndarray:
    """How much more each mode's reading sees of the other modes' answer to its drive than of its
    own mode's (:func:`feedthrough` over the own path ``H_i(j w_i) (b_i . g_i) (w_i . C_i)``), shape (k,).

    Large where the sensors sit at a node of the mode: the weights that read it (least norm,
    ``w_i . C_i = 1``) are huge, and so is every other mode seen through them.
    """
    terms = _paths(model, modes, sensors, actuators)
    own = terms[np.arange(terms.shape[0]), modes]
    leak, own = np.abs(terms.sum(axis=1) - own), np.abs(own)  # the leak: feedthrough's sum
    return np.divide(leak, own, out=np.full(own.shape, np.inf), where=own > 0)


def _paths(model, modes, sensors: np.ndarray, actuators: np.ndarray) -> np.ndarray:
    """Reading of mode ``modes[i]`` per unit of its drive envelope through each mode j, shape (k, all modes):
    ``H_j(j w_i) (b_j . g_i) (w_i . C_j)``, the mode's own path at ``j = modes[i]``."""
    modes = np.asarray(modes, int)
    s = 2j * np.pi * model.frequencies[modes]  # (k,)
    w, z = model.omega, model.damping
    h = s[:, None] / (s[:, None] ** 2 + 2 * z * w * s[:, None] + w**2)  # (k, all modes): H_j(j w_i)
    drive = (model.actuator_gains @ actuators).T  # (k, all): b_j . g_i
    seen = sensors @ model.sensor_gains.T  # (k, all): w_i . C_j
    return h * drive * seen
