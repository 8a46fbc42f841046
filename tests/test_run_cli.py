"""``modalctl run`` end to end on sim://, the device lifecycle, and every refusal's exit code."""

import json
from dataclasses import replace

import numpy as np
import pytest

from modalctl.cli import main
from modalctl.errors import InputError
from modalctl.io.device import DeviceContext, DeviceError, open_device, transports
from modalctl.model.records import read_field_record
from modalctl.model.scenes import load_scene
from modalctl.plugin.manager import PluginError

RUN = ["run", "--scene", "thesis-al-cc", "--points", "351", "--shape", "sinc", "--param", "width=18mm",
       "--param", "center=24mm", "--quiet"]


def run(capsys, *args):
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_run_writes_metrics_fields_and_pictures(capsys, tmp_path):
    code, out, err = run(capsys, *RUN, "--focus-time", "25ms", "--modes", "9", "--drift", "1%", "--out",
                         str(tmp_path), "--json")
    assert code == 0, err
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    for key in ("tau", "tau_norm", "nrmse", "margin_ratio", "margin_ok", "peak_voltage", "modes_used",
                "plan_seconds", "sim_seconds"):
        assert key in metrics
    assert 0.75 < metrics["tau"] < 0.95  # a 1% drift: DESIGN says about 0.85 open loop
    fields = read_field_record(tmp_path / "fields.npz")
    assert fields.field.shape == (351, fields.times.size)
    for name in ("spacetime", "modal_bars", "voltages", "spectrogram"):
        assert (tmp_path / f"{name}.png").stat().st_size > 10_000


def test_closed_loop_run_recovers_the_drifted_focus_and_logs_every_period(capsys, tmp_path):
    from modalctl.loops.recorder import read_log

    args = [*RUN, "--focus-time", "25ms", "--drift", "1%", "--damping-error", "20%", "--snr", "40",
            "--sample-rate", "500kHz"]
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "open"), "--json", "--no-plots")
    assert code == 0, err
    code, _, err = run(capsys, *args, "--loop", "closed", "--out", str(tmp_path / "closed"), "--json")
    assert code == 0, err
    opened = json.loads((tmp_path / "open" / "metrics.json").read_text())
    closed = json.loads((tmp_path / "closed" / "metrics.json").read_text())
    assert opened["tau"] < 0.85 and closed["tau"] > 0.95
    assert closed["loop"]["state"] == "inactive" and closed["loop"]["fault"] is None
    assert 0 < closed["loop"]["configure_seconds"] < closed["sim_seconds"]  # the board's set-up, timed apart
    records, header = read_log(tmp_path / "closed" / "log")
    assert records.size == closed["loop"]["periods"] == header["meta"]["control_rate_hz"] * 0.029
    assert (tmp_path / "closed" / "loop.png").stat().st_size > 10_000


def test_closed_loop_rate_must_divide_the_sample_rate(capsys, tmp_path):
    code, _, err = run(capsys, *RUN, "--focus-time", "25ms", "--loop", "closed", "--control-rate", "30kHz",
                       "--out", str(tmp_path))
    assert code == 2 and "must divide" in err


def test_focus_time_too_short_for_the_voltage_limit(capsys, tmp_path):
    code, _, err = run(capsys, *RUN, "--focus-time", "1ms", "--voltage-limit", "2V", "--out", str(tmp_path / "c"))
    assert code == 1 and "no drive on this basis reaches the focus within voltage 2 V" in err
    code, _, err = run(capsys, *RUN, "--focus-time", "1ms", "--voltage-limit", "2V", "--planner", "envelope",
                       "--margin", "none", "--out", str(tmp_path / "e"))
    assert code == 1 and "above the 2 V limit" in err


def test_margin_no_envelope_can_meet(capsys, tmp_path):
    code, _, err = run(capsys, *RUN, "--focus-time", "25ms", "--modes", "9", "--margin", "10%", "--planner",
                       "envelope", "--out", str(tmp_path))
    assert code == 1 and "no envelope meets the 0.1 margin" in err and "best plan found reaches" in err


@pytest.mark.slow
def test_the_convex_planner_holds_the_margin_and_its_refusal_is_written_with_the_certificate(capsys, tmp_path):
    code, out, err = run(capsys, *RUN, "--focus-time", "25ms", "--modes", "9", "--planner", "convex",
                         "--margin", "0.5", "--out", str(tmp_path / "ok"))
    assert code == 0, err
    metrics = json.loads((tmp_path / "ok" / "metrics.json").read_text())
    assert metrics["planner"] == "convex" and metrics["margin_ratio"] <= 0.5 + 1e-6  # measured on the sim's scan
    assert "on every sample of the whole model" in out
    code, _, err = run(capsys, *RUN, "--focus-time", "25ms", "--modes", "9", "--planner", "convex",
                       "--margin", "0.2", "--out", str(tmp_path / "no"))
    refusal = json.loads((tmp_path / "no" / "refusal.json").read_text())
    assert code == 1 and "side lobes" in err and "certificate:" in err
    assert refusal["certificate"]["status"] == "infeasible" and refusal["needed"] > 0.2


def test_a_margin_program_out_of_plan_time_is_refused_saying_so_and_none_lifts_the_budget(capsys, tmp_path):
    """``--plan-time 0s``: the margin program stops after its first round (its first drive is over the
    margin here): exit 1, the refusal saying where it stopped, its certificate not certified; ``none``
    plans it. With the envelope planner the option does not apply: exit 2, nothing written."""
    case = [*RUN, "--focus-time", "25ms", "--modes", "9", "--margin", "0.5"]
    code, _, err = run(capsys, *case, "--plan-time", "0s", "--out", str(tmp_path / "no"))
    refusal = json.loads((tmp_path / "no" / "refusal.json").read_text())
    assert code == 1 and "stopped at its 0 s budget (--plan-time, ConvexOptions.program_seconds) after 1 rounds" in err
    assert refusal["certificate"]["status"] == "not certified" and refusal["certificate"]["program_seconds"] == 0
    code, _, err = run(capsys, *case, "--plan-time", "none", "--out", str(tmp_path / "ok"))
    assert code == 0, err
    code, _, err = run(capsys, *case, "--planner", "envelope", "--plan-time", "10s", "--out", str(tmp_path / "env"))
    assert code == 2 and "--plan-time bounds the convex planner" in err
    assert not (tmp_path / "env").exists()


def test_an_unknown_planner_exits_2_before_any_work(capsys, tmp_path):
    code, _, err = run(capsys, *RUN, "--focus-time", "25ms", "--planner", "magic", "--out", str(tmp_path / "r"))
    assert code == 2 and "unknown planner 'magic'" in err and "convex" in err
    assert not (tmp_path / "r").exists()


def test_uncontrollable_mode_the_shape_needs(capsys, tmp_path):
    model = load_scene("thesis-al-cc", 351)
    gains = model.actuator_gains.copy()
    gains[1] = 0.0  # mode 2: every patch on its nodes
    path = replace(model, actuator_gains=gains).save(tmp_path / "crippled.npz")
    code, _, err = run(capsys, "run", "--model", str(path), "--shape", "sinc", "--param", "width=18mm",
                       "--param", "center=24mm", "--focus-time", "25ms", "--quiet", "--out", str(tmp_path / "r"))
    assert code == 1 and "mode 2: no actuator can drive it" in err


def test_bad_units_exit_2(capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_:
        main([*RUN, "--focus-time", "25kg", "--out", str(tmp_path)])
    assert exit_.value.code == 2 and "focus-time" in capsys.readouterr().err


@pytest.mark.parametrize("option, value, words", [
    ("--margin", "-0.2", "margin must lie in (0, 1]"), ("--margin", "1.5", "margin must lie in (0, 1]"),
    ("--margin", "0", "margin must lie in (0, 1]"), ("--robust-drift", "-1%", "robust-drift must lie in [0, 0.5]"),
    ("--robust-drift", "150%", "robust-drift must lie in [0, 0.5]"),
    ("--latency", "-1", "latency must lie in [0, 1000]"), ("--voltage-limit", "0V", "voltage-limit must lie in [0.001"),
    ("--voltage-limit", "0.5mV", "voltage-limit must lie in [0.001"),
    ("--slew-limit", "0.5V/s", "slew-limit must lie in [1"), ("--rails", "0.5mV", "rails must lie in [0.001"),
    ("--watchdog", "0", "watchdog must lie in [1"), ("--latency", "x", "invalid latency value"),
    ("--plan-time", "-1s", "plan-time must lie in [0"), ("--plan-time", "2V", "plan-time")])
def test_out_of_range_options_exit_2_before_any_work(capsys, tmp_path, option, value, words):
    with pytest.raises(SystemExit) as exit_:
        main([*RUN, "--focus-time", "25ms", "--loop", "closed", option, value, "--out", str(tmp_path / "r")])
    assert exit_.value.code == 2 and words in capsys.readouterr().err
    assert not (tmp_path / "r").exists()  # nothing planned, nothing written


def test_a_truth_of_another_structure_is_refused(capsys, tmp_path):
    code, _, err = run(capsys, *RUN, "--focus-time", "25ms", "--truth", "thesis-al-ff", "--out", str(tmp_path / "r"))
    assert code == 2 and "--truth thesis-al-ff has 6 actuators, the model 8" in err


def test_unknown_transport_exits_2(capsys, tmp_path):
    code, _, err = run(capsys, *RUN, "--focus-time", "25ms", "--transport", "nope://x", "--out", str(tmp_path))
    assert code == 2 and "no transport for 'nope://x'" in err


def test_a_device_url_written_wrong_exits_2_and_a_device_that_fails_exits_3(capsys, tmp_path):
    """An unknown option in the URL is the user's input (exit 2; it was a device error, exit 3, before); a port
    that is not there is the device's fault (exit 3)."""
    code, _, err = run(capsys, *RUN, "--focus-time", "25ms", "--transport", "sim://?bogus=1", "--out", str(tmp_path))
    assert code == 2 and "unknown option(s) bogus; known: hold, tol" in err
    code, _, err = run(capsys, *RUN, "--focus-time", "25ms", "--transport", "sim://?tol=-1", "--out", str(tmp_path))
    assert code == 2 and "tol must lie in (0, 1)" in err
    code, _, err = run(capsys, *RUN, "--focus-time", "25ms", "--transport", "serial:///dev/no-such-port",
                       "--out", str(tmp_path / "s"))
    assert code == 3 and "cannot open /dev/no-such-port" in err


def test_sim_device_lifecycle_and_transport_registry():
    assert {"sim", "serial", "can"} <= set(transports())
    with pytest.raises(PluginError, match="installed: can://, serial://, sim://"):
        open_device("usb://board0")
    model = load_scene("thesis-al-cc", 101)
    device = open_device("sim://", DeviceContext(model))
    with pytest.raises(DeviceError, match="configure before activate"):
        device.activate()
    caps = device.configure(1e6)
    assert caps.channels == model.actuator_gains.shape[1] and caps.can_scan
    device.activate()
    with pytest.raises(DeviceError, match="waveforms for"):
        device.upload(np.zeros((3, 10)))
    device.upload(np.zeros((caps.channels, 100)))
    capture = device.trigger()
    assert capture.sensors.shape == (caps.sensors, 100) and np.all(capture.sensors == 0)
    assert device.scan(np.array([0.0, 5e-5]), points=[3, 4]).shape == (2, 2)


def test_scan_indices_find_the_nearest_scan_points_and_refuse_a_far_one():
    from modalctl.io.device import Capabilities, scan_indices

    scan = np.linspace(-0.05, 0.05, 201)[:, None]  # a vibrometer's 0.5 mm grid
    caps = Capabilities("vibrometer", 1, 1, 1e6, None, True, scan)
    ours = np.linspace(-0.05, 0.05, 41)[:, None]  # the model's 2.5 mm grid
    index = scan_indices(caps, ours)
    assert np.array_equal(index, np.argmin(np.abs(ours - scan.T), axis=1))  # brute force, independently
    with pytest.raises(InputError, match="from the nearest scan point"):
        scan_indices(caps, np.r_[ours, [[0.06]]])  # 10 mm off the scanned beam
    assert scan_indices(Capabilities("bare", 1, 1, 1e6, None, False), ours) is None


def test_a_transports_options_are_its_own(capsys, tmp_path):
    """sim://'s truth options reach no other transport: given with a board's, they are refused,
    before any port is opened, with exit 2 and their names."""
    code, _, err = run(capsys, *RUN, "--focus-time", "25ms", "--drift", "1%", "--finger", "1Ns/m",
                       "--transport", "serial:///dev/does-not-exist", "--out", str(tmp_path))
    assert code == 2
    assert "--drift (sim://), --finger (sim://): not an option of serial://" in err


def _bare_device(model):
    """A Device subclass implementing only the abstract methods (the lifecycle's defaults inherited)."""
    from modalctl.hil.sim_device import SimDevice
    from modalctl.io.device import Device

    inner = SimDevice(model)

    class Bare(Device):
        def configure(self, sample_rate):
            self.capabilities = replace(inner.configure(sample_rate), phasor_mode=False)
            return self.capabilities

        def upload(self, voltages):
            inner.activate()
            inner.upload(voltages)

        def trigger(self, progress=False):
            return inner.trigger()

        def scan(self, times, points=None):
            return inner.scan(times, points)

    return Bare("bare://")


def test_the_device_contract_is_enough_for_a_shot_and_its_defaults_refuse_clearly():
    """A device implementing only the abstract methods plays an open-loop shot through run (the
    same tau as sim://); asked for a closed loop it is refused by its capabilities, not by a
    traceback; and the contract cannot be instantiated half-written."""
    from modalctl.io.device import Device
    from modalctl.model.shape import parse_params
    from modalctl.options import LoopOptions, PlanOptions, RunOptions
    from modalctl.plugin.manager import get_shape
    from modalctl.run import run as run_shot

    class Half(Device):
        def configure(self, sample_rate):
            raise AssertionError

    with pytest.raises(TypeError, match="abstract"):
        Half("half://")
    model = load_scene("thesis-al-cc", 211)
    sinc = get_shape("sinc")
    shape = sinc.generate(model.grid, **parse_params(sinc, {"width": "18mm", "center": "24mm"}))
    options = RunOptions(0.025, PlanOptions(sample_rate=500e3))
    bare = run_shot(model, shape, _bare_device(model), options)
    sim = run_shot(model, shape, open_device("sim://", DeviceContext(model)), options)
    assert bare.metrics.tau == pytest.approx(sim.metrics.tau, abs=1e-12) and bare.metrics.tau > 0.95
    with pytest.raises(DeviceError, match="no phasor mode"):
        run_shot(model, shape, _bare_device(model), replace(options, loop=LoopOptions()))
    device = _bare_device(model)
    with pytest.raises(DeviceError, match="no phasor mode"):
        device.phasor_board(1.0, 20e3)
    with device:  # a context manager that closes (the default close releases nothing)
        assert device.url == "bare://"


@pytest.mark.parametrize("option, value, words", [
    ("--snr", "nan", "snr must lie in [0, 200]"), ("--snr", "1e9", "snr must lie in [0, 200]"),
    ("--snr", "inf", "snr must lie in [0, 200]"), ("--drift-rate", "1e9%/s", "drift-rate must lie in (-10, 10]"),
    ("--finger", "1e12Ns/m", "finger must lie in [0, 100]"), ("--damping-error", "-100%", "damping-error must lie"),
    ("--drift", "60%", "drift must lie in (-0.5, 0.5]"), ("--focus-time", "1e400ms", "not a finite number")])
def test_non_finite_and_unphysical_truths_exit_2(capsys, tmp_path, option, value, words):
    """Each ended in exit 0 with a NaN or nonsense, or a traceback (issue 26), before the bounds."""
    with pytest.raises(SystemExit) as exit_:
        main([*RUN, "--focus-time", "25ms", option, value, "--out", str(tmp_path / "r")])
    assert exit_.value.code == 2 and words in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_an_infinite_shape_parameter_exits_2(capsys, tmp_path):
    code, _, err = run(capsys, "run", "--scene", "thesis-al-cc", "--points", "211", "--shape", "sinc", "--param",
                       "width=1e400mm", "--focus-time", "25ms", "--out", str(tmp_path))
    assert code == 2 and "is not a finite number" in err


@pytest.mark.parametrize("out, words", [("", "an empty name would write into the working one"),
                                        ("FILE", "is a file, not a directory")])
def test_an_out_that_is_no_directory_exits_2(capsys, tmp_path, out, words):
    """Before: '' wrote into the working directory and exited 0; a file raised FileExistsError."""
    if out == "FILE":
        out = str(tmp_path / "a-file")
        (tmp_path / "a-file").write_text("not a directory")
    with pytest.raises(SystemExit) as exit_:
        main([*RUN, "--focus-time", "25ms", "--out", out])
    assert exit_.value.code == 2 and words in capsys.readouterr().err


def test_an_empty_scene_name_is_an_unknown_scene(capsys, tmp_path):
    code, _, err = run(capsys, "run", "--scene", "", "--shape", "sinc", "--focus-time", "25ms",
                       "--out", str(tmp_path))
    assert code == 2 and "unknown scene ''" in err


def test_json_refusals_are_a_json_object_on_stdout(capsys, tmp_path):
    """Before, a refusal under --json left stdout empty: a script reading it had nothing to parse."""
    code, out, _ = run(capsys, *RUN, "--focus-time", "1ms", "--voltage-limit", "1V", "--json", "--out", str(tmp_path))
    said = json.loads(out)
    assert code == 1 and said["code"] == 1 and "no drive" in said["error"] and said["certificate"]["status"]
    with pytest.raises(SystemExit) as exit_:
        main([*RUN, "--focus-time", "1kg", "--json", "--out", str(tmp_path)])
    out, err = capsys.readouterr()
    said = json.loads(out)
    assert exit_.value.code == 2 and said["code"] == 2 and "unknown unit 'kg'" in said["error"] and "kg" in err


@pytest.mark.parametrize("focus_time, after", [("1000000s", "4ms"), ("25ms", "10s")])
def test_a_shot_longer_than_the_bound_exits_2_before_allocating(capsys, tmp_path, focus_time, after):
    """Before: --focus-time 1000000s asked numpy for 428 GiB (a MemoryError traceback); --after 10s
    played ten seconds to exit 0."""
    code, _, err = run(capsys, *RUN, "--focus-time", focus_time, "--after", after, "--out", str(tmp_path))
    assert code == 2 and "samples per channel; at most 1e+06" in err


def test_a_transport_that_refuses_its_url_with_a_plain_value_error_exits_2(capsys, tmp_path, monkeypatch):
    """A transport plugin, or the library under it (pyserial refuses a negative baud with a ValueError), that
    refuses what it was given with a plain ValueError refuses bad input: exit 2 naming the URL, not a bug (4)."""
    import modalctl.io.device

    def refusing(url, context=None, manager=None):
        raise ValueError("Not a valid baudrate: -1")

    monkeypatch.setattr(modalctl.io.device, "open_device", refusing)
    code, _, err = run(capsys, *RUN, "--focus-time", "25ms", "--transport", "sim://", "--out", str(tmp_path))
    assert code == 2 and "sim://: Not a valid baudrate: -1" in err and "internal" not in err
