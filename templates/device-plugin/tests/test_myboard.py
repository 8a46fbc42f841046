"""The template plugin against modalctl's board emulator: registered, opened by URL, a shot played."""

import numpy as np

from modalctl.hil.scenario import Perturbation
from modalctl.hil.serial_board import SerialBoardEmulator
from modalctl.io.device import open_device, transports
from modalctl.model.scenes import load_scene
from modalctl.plugin.manager import plugin_manager


def test_the_entry_point_registers_the_scheme():
    assert "myboard" in transports(plugin_manager())


def test_an_open_loop_shot_through_the_plugin():
    model = load_scene("thesis-al-cc", 105)
    with SerialBoardEmulator(model, Perturbation()) as board:
        device = open_device(f"myboard://{board.path}")
        caps = device.configure(200e3)
        assert caps.channels == model.actuator_gains.shape[1]
        device.activate()
        volts = np.zeros((caps.channels, 2000))
        volts[0, :100] = np.hanning(100)
        device.upload(volts)
        capture = device.trigger()
        assert capture.voltages.shape == volts.shape and np.abs(capture.sensors).max() > 0
