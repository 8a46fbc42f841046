"""Transports that open ports: a board on a serial line (:mod:`.serial`, pyserial) or a CAN FD bus
(:mod:`.can`, python-can); what they share is the device side of the protocol (:mod:`.protocol_device`)."""
