"""Transports to boards, installed as ``modalctl.transports``: they open ports; the core does not."""
