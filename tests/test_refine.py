"""The voltage correction that holds the margin on the whole model (:mod:`modalctl.plan.refine`)."""

import numpy as np
import pytest

import modalctl.plan.refine as refine_module
from modalctl.model.propagate import Plant
from modalctl.model.scenes import load_scene


def test_the_searchs_gradient_is_the_plants_adjoint(monkeypatch):
    """The gradient L-BFGS-B is given (the plant run backwards in time) against central
    differences of the objective it is given, on a random drive of the whole beam."""
    model = load_scene("thesis-al-cc", 105)
    fs, n = 200e3, 1200
    rng = np.random.default_rng(4)
    voltages = rng.standard_normal((8, n))
    mask = np.zeros(model.grid.n, bool)
    mask[60:70] = True
    seen = {}

    def capture(fun, x0, args, **_):
        seen["fun"], seen["x0"], seen["args"] = fun, x0, args
        raise StopIteration  # one look is enough

    monkeypatch.setattr(refine_module, "minimize", capture)
    with pytest.raises(StopIteration):
        refine_module.refine(model, voltages, 1000, fs, mask, margin=1e-6, search=refine_module.Search(1e-3, 0.5e-3))
    fun, args = seen["fun"], seen["args"]
    z = 0.3 * rng.standard_normal(seen["x0"].size)
    value, grad = fun(z, *args)
    for _ in range(3):
        d = rng.standard_normal(z.size) * 1e-4
        numeric = (fun(z + d, *args)[0] - fun(z - d, *args)[0]) / 2
        assert numeric == pytest.approx(grad @ d, rel=1e-5)


def test_the_correction_only_adds_to_the_window_and_moves_the_focus_little():
    """On a plan-like drive (a few modes' carriers ringing up to a focus) the search lowers the
    whole model's off-target peak and leaves the rest of the shot and the focus field alone."""
    model = load_scene("thesis-al-cc", 105)
    fs, focus = 250e3, 2500
    t = np.arange(3000) / fs
    envelope = np.exp(np.minimum(t - t[focus], 0) * 400)
    voltages = np.vstack([np.cos(model.omega[k] * (t - t[focus])) * envelope for k in range(8)])
    mask = np.zeros(model.grid.n, bool)
    mask[70:80] = True
    found = refine_module.refine(model, voltages, focus, fs, mask, margin=0.0, search=refine_module.Search(iterations=30))
    assert found.ratio < found.ratio_before
    assert found.focus_change < 1e-2
    assert found.correction.shape == (8, int(round(0.9e-3 * fs)))
    corrected = voltages.copy()
    corrected[:, found.start:found.start + found.correction.shape[1]] += found.correction
    velocity = Plant(model, fs).simulate(corrected)
    off = np.abs(model.shapes[:, ~mask].T @ velocity[:, found.start:]).max()
    peak = np.abs(model.shapes.T @ Plant(model, fs).simulate(voltages)[:, focus]).max()
    assert off / peak == pytest.approx(found.ratio, rel=1e-9)  # the reported ratio is the plant's
