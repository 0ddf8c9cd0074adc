"""CAN as a wire: the exact bits of a classical CAN frame, their time on the
bus, bitwise arbitration, fault confinement and bus load (docs/can-wire.md).

A pure, deterministic model: nothing in the running rig uses it unless asked.
"""
