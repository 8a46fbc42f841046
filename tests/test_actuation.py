"""Close modes the actuators push along one direction (``modalctl.model.actuation``), checked
against the plate's symmetry: mirrored patches see each mode with the sign its half-wave numbers'
parity gives, so the modes of one parity class share one gain direction, exactly."""

from __future__ import annotations

import json

import numpy as np

from modalctl.model.actuation import twin_modes
from modalctl.model.structures import Plate, PlatePatch
from modalctl.plan.convex_program import Program
from modalctl.plan.convex_refusal import _with_twins
from modalctl.plan.planner import PlanError
from modalctl.options import PlanOptions

GLASS = dict(thickness=1e-3, modulus=70e9, density=2500.0, poisson=0.22)


def _patches(centres) -> list[PlatePatch]:
    """12 x 8 mm patches at ``centres`` (m)."""
    return [PlatePatch((x - 0.006, x + 0.006), (y - 0.004, y + 0.004)) for x, y in centres]


MIRRORED = [(sx * 0.03, sy * 0.02) for sx in (-1, 1) for sy in (-1, 1)]  # about both axes of the plate
SCATTERED = [(-0.037, -0.021), (0.026, -0.013), (-0.019, 0.024), (0.034, 0.017)]  # off them


def test_mirrored_patches_make_twins_of_exactly_the_close_modes_of_one_parity_class():
    plate = Plate(0.12, 0.0853, **GLASS)  # sides in no simple ratio: no mode degenerate
    model = plate.modal_model(40, nx=25, ny=19, patches=_patches(MIRRORED))
    indices = np.asarray(model.meta["mode_indices"])
    parity = indices % 2  # the symmetry class, from the half-wave numbers alone
    f = model.frequencies
    close = 0.05
    driven = np.abs(model.actuator_gains).max(axis=1) > 1e-6 * np.abs(model.actuator_gains).max()
    expected = {(j, k) for j in range(f.size) for k in range(j + 1, f.size) if driven[j] and driven[k]
                and (parity[j] == parity[k]).all() and abs(f[k] - f[j]) < close * min(f[j], f[k])}
    assert len(expected) >= 3  # the case has something to find
    found = twin_modes(model, close=close)
    assert {(t.first, t.second) for t in found} == expected
    assert all(t.cosine > 1 - 1e-9 for t in found)  # one direction: parallel to round-off
    assert [t.spacing_hz for t in found] == sorted(t.spacing_hz for t in found)  # the closest first
    kept = [found[0].second]
    assert all(found[0].second in (t.first, t.second) for t in twin_modes(model, kept, close=close))


def test_patches_off_the_symmetry_axes_separate_the_classes():
    plate = Plate(0.12, 0.0853, **GLASS)  # sides in no simple ratio: no mode degenerate
    symmetric = plate.modal_model(40, nx=25, ny=19, patches=_patches(MIRRORED))
    shifted = plate.modal_model(40, nx=25, ny=19, patches=_patches(SCATTERED))
    assert len(twin_modes(symmetric)) > 0
    assert twin_modes(shifted) == []


def test_a_refusal_names_the_twins_slower_than_the_focus_time():
    plate = Plate(0.12, 0.0853, **GLASS)  # sides in no simple ratio: no mode degenerate
    model = plate.modal_model(40, nx=25, ny=19, patches=_patches(MIRRORED))
    pair = twin_modes(model)[0]
    modes = np.array([pair.first, pair.second])
    mask = np.zeros(model.grid.n, bool)
    focus_time = 0.5 / pair.spacing_hz  # the beat slower than the focus time: named
    program = Program(model, modes, np.ones(2), mask, focus_time, PlanOptions(margin=0.5))
    error = _with_twins(PlanError("refused", 0.7, 0.5, {"status": "infeasible"}), program)
    f = model.frequencies
    assert f"{f[pair.first]:.0f} and {f[pair.second]:.0f} Hz" in str(error) and "symmetric" in str(error)
    assert error.certificate["twin_modes"][0]["modes"] == [int(model.labels[pair.first]),
                                                           int(model.labels[pair.second])]
    assert (error.needed, error.limit) == (0.7, 0.5)
    quick = Program(model, modes, np.ones(2), mask, 2.0 / pair.spacing_hz, PlanOptions(margin=0.5))
    assert str(_with_twins(PlanError("refused"), quick)) == "refused"  # two beats within it: not the cause


def test_model_fe_says_which_close_modes_its_mirrored_patches_push_alike(tmp_path, capsys):
    from modalctl.cli import main

    mirrored = ["--patch=-30mm,-20mm,-30mm,-20mm", "--patch=20mm,30mm,-30mm,-20mm", "--patch=-30mm,-20mm,20mm,30mm",
                "--patch=20mm,30mm,20mm,30mm"]
    base = ["model", "fe", "--outline", "rect:100mm,100mm", "--thickness", "1mm", "--modes", "6", "--spacing",
            "4mm", "--no-plots", "--out", str(tmp_path / "square.npz")]
    assert main([*base, *mirrored, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    f = summary["frequencies_hz"]
    assert [pair["modes"] for pair in summary["twin_modes"]] == [[5, 6]]  # (1,3) and (3,1): one class
    assert abs(summary["twin_modes"][0]["spacing_hz"] - (f[5] - f[4])) < 1e-9
    assert main([*base[:-1], str(tmp_path / "again.npz"), *mirrored]) == 0
    assert "note: the patches push 1 pair(s) of close modes" in capsys.readouterr().out
