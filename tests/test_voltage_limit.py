"""The actuators' safe voltage (issue 39 item 3): each scene and model file carries it (a piezo
patch's depolarization field times its thickness), ``modalctl run`` plans under it unless told
otherwise, and a plan above it is refused with the planner's certificate, not played."""

import json
from dataclasses import replace

import numpy as np
import pytest

from modalctl.cli import main
from modalctl.model.modes import ModalModel, ModelError
from modalctl.model.scenes import SCENES, load_scene
from modalctl.model.structures import PZT5A_DEPOLARIZATION_FIELD, Piezo

#: The issue's case: a sinc near the Rython beam's end, no margin, planned at 2548 V and played.
FAR = ["run", "--scene", "thesis-rython-pp", "--shape", "sinc", "--param", "width=20mm", "--param", "center=-58mm",
       "--focus-time", "25ms", "--margin", "none", "--quiet", "--no-plots"]


def test_a_patch_s_safe_voltage_is_its_depolarization_field_times_its_thickness():
    assert 0.35e6 <= PZT5A_DEPOLARIZATION_FIELD <= 0.5e6  # PZT-5A against its poling
    assert Piezo().safe_voltage == pytest.approx(70.0)
    assert Piezo(thickness=0.5e-3).safe_voltage == pytest.approx(175.0)
    assert repr(Piezo()) == "Piezo(d31=1.71e-10, modulus=61000000000.0, thickness=0.0002)"  # the FE cache's key
    with pytest.raises(ModelError, match="piezo.depolarization_field"):
        Piezo(depolarization_field=float("nan"))


@pytest.mark.parametrize("name", [pytest.param(name, marks=pytest.mark.slow) if name == "panel-rounded" else name
                                  for name in SCENES])
def test_every_scene_carries_its_actuators_safe_voltage(name):
    model = load_scene(name)
    assert model.voltage_limit == pytest.approx(70.0)
    assert "0.2 mm" in model.meta["voltage_limit_source"]


def test_a_model_file_keeps_it_and_a_hostile_one_is_refused(tmp_path):
    model = load_scene("thesis-al-cc", 211)
    assert ModalModel.load(model.save(tmp_path / "m.npz")).voltage_limit == pytest.approx(70.0)
    for bad in ("70", -1.0, 0, True, float("nan"), float("inf")):
        with pytest.raises(ModelError, match="voltage_limit_v"):
            replace(model, meta={**model.meta, "voltage_limit_v": bad})
    assert replace(model, meta={k: v for k, v in model.meta.items() if k != "voltage_limit_v"}).voltage_limit is None


def test_model_fe_writes_it_into_the_file(tmp_path, capsys):
    out = tmp_path / "plate.npz"
    assert main(["model", "fe", "--outline", "rect:100mm,70mm", "--thickness", "1mm", "--modes", "2", "--spacing",
                 "4mm", "--patch", "10mm,20mm,0,10mm", "--no-plots", "--quiet", "--out", str(out)]) == 0
    assert ModalModel.load(out).voltage_limit == pytest.approx(70.0)


@pytest.mark.parametrize("planner", ["convex", "envelope"])
def test_a_plan_above_the_default_limit_is_refused_not_played(tmp_path, capsys, planner):
    out = tmp_path / "far"
    assert main([*FAR, "--planner", planner, "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "70 V" in err and "the model's actuators' safe voltage" in err and "Traceback" not in err
    refusal = json.loads((out / "refusal.json").read_text())
    assert refusal["voltage_limit"] == pytest.approx(70.0)
    if planner == "convex":
        assert refusal["certificate"]["limits"] == "voltage 70 V"
    assert not (out / "metrics.json").exists() and not (out / "fields.npz").exists()


def test_an_explicit_limit_or_none_replaces_the_default(tmp_path, capsys):
    assert main([*FAR, "--voltage-limit", "none", "--json", "--out", str(tmp_path / "none")]) == 0
    metrics = json.loads(capsys.readouterr().out)
    assert metrics["peak_voltage"] > 1000 and metrics["voltage_limit_v"] is None
    assert main([*FAR, "--voltage-limit", "60V", "--out", str(tmp_path / "sixty")]) == 1
    assert "within voltage 60 V" in capsys.readouterr().err


def test_a_shot_within_the_limit_plays_as_before_and_says_it(tmp_path, capsys):
    args = ["run", "--scene", "thesis-al-cc", "--points", "351", "--shape", "sinc", "--param", "width=18mm",
            "--param", "center=24mm", "--focus-time", "25ms", "--quiet", "--no-plots"]
    assert main([*args, "--out", str(tmp_path / "default")]) == 0
    said = capsys.readouterr().out
    assert "(limit 70 V)" in said
    metrics = json.loads((tmp_path / "default" / "metrics.json").read_text())
    assert metrics["voltage_limit_v"] == pytest.approx(70.0) and "PZT-5A" in metrics["voltage_limit_source"]
    assert main([*args, "--voltage-limit", "none", "--out", str(tmp_path / "none")]) == 0
    unlimited = json.loads((tmp_path / "none" / "metrics.json").read_text())
    assert metrics["peak_voltage"] < 70 and np.isclose(metrics["tau"], unlimited["tau"], atol=1e-6)


def test_a_model_identified_on_the_simulator_carries_the_scene_s(tmp_path, capsys):
    out = tmp_path / "beam.npz"
    assert main(["identify", "--scene", "thesis-al-cc", "--f-high", "6kHz", "--step", "2mm", "--out", str(out),
                 "--quiet", "--no-plots", "--json"]) == 0
    assert ModalModel.load(out).voltage_limit == pytest.approx(70.0)
