"""Hardware-in-the-loop simulation, installed as ``modalctl.hil``.

The truth plant, board emulators and scenarios arrive with the open-loop issue; nothing
here is used yet.
"""
