"""Which fields of a run-time :class:`~protocol.messages.ConfigChange` each
command key takes: the access rules (:mod:`service_kit.access`) say who may
publish on a key, this table says what a message on that key may change.

* ``controller/command`` (the ``tool`` and ``tester`` roles): exactly what
  ``ralf-hil reconfigure`` offers, the FFT width, the batch size and the
  averaging factor (and the request id its acknowledgement answers).
* ``controller/test_command`` (the ``tester`` role only, and only where
  ``zenoh_acl`` is ``scenarios``): those, and the test knobs
  (:data:`TEST_KNOBS`: the emulated DSP latency, bounded by
  :data:`protocol.messages.MAX_LATENCY_S`).

``reset`` is the controller's own (the run-start reset it sends the DSP):
no command key takes it. A command that sets a field its key does not
take is refused whole (counted as ``in_<kind>_refused`` in the controller's
health) and changes nothing.
"""

from __future__ import annotations

from typing import Final

from protocol.messages import ConfigChange

RECONFIGURE_FIELDS: Final[frozenset[str]] = frozenset({"fft_width", "batch_size", "alpha"})
"""What ``ralf-hil reconfigure`` changes (its ``--fft-width``, ``--batch-size``, ``--alpha``)."""

TEST_KNOBS: Final[frozenset[str]] = frozenset({"emulated_latency_s"})
"""Fields meant for tests: they make the rig worse on purpose."""

HEADER_FIELDS: Final[frozenset[str]] = frozenset({"seq", "sim_time_s", "wall_time_s", "request_id"})
"""Fields that change nothing: numbering, times, the acknowledgement's id."""

COMMAND_KINDS: Final[dict[str, frozenset[str]]] = {
    "command": RECONFIGURE_FIELDS,
    "test_command": RECONFIGURE_FIELDS | TEST_KNOBS,
}
"""The controller's inbox kind of each command key -> the fields it takes."""

COMMAND_KEYS: Final[dict[str, str]] = {"command": "controller/command", "test_command": "controller/test_command"}
"""The inbox kind -> its key suffix under ``ralf/<rig>/``."""


def changed_fields(change: ConfigChange) -> frozenset[str]:
    """The fields of ``change`` that would change something (set, and not their no-op default)."""
    defaults = {name: info.default for name, info in ConfigChange.model_fields.items()}
    return frozenset(name for name in ConfigChange.model_fields if name not in HEADER_FIELDS and getattr(change, name) != defaults[name])


def refused_fields(kind: str, change: ConfigChange) -> frozenset[str]:
    """The fields ``change`` sets that a command of inbox kind ``kind`` may not set (empty: it may be taken)."""
    return changed_fields(change) - COMMAND_KINDS[kind]
