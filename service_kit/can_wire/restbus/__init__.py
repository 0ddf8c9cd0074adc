"""The rest of the bus from a DBC (docs/can-wire.md, section Restbus).

- :mod:`~service_kit.can_wire.restbus.traffic`: the DBC's cyclic messages,
  their payloads (start values, counters, checksums), the schedule, the
  load, the checks before start and the simulated back-end;
- :mod:`~service_kit.can_wire.restbus.sender`: the python-can back-end;
- :mod:`~service_kit.can_wire.restbus.cli`: ``python -m service_kit.can_wire.restbus``.
"""
