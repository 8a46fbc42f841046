"""Talking to hardware: the device contract, the board protocol, and the transports that open ports.

:mod:`.device` is the contract a device plugin implements (:class:`~modalctl.io.device.Device`,
with the phasor board of :mod:`modalctl.loops.runtime` for closed loops) and opens devices by URL;
:mod:`.protocol` is the board protocol's messages and framings (pure encoding); :mod:`.transports`
carry them over a serial line or a CAN FD bus.

Imports the layers below (model, plan, loops) and the plugin manager.
"""
