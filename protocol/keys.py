"""zenoh key expressions. Everything of one rig lives under ``ralf/<rig-id>/``
so several rigs can share one zenoh network.

==============================  ==========================================  =========
key                             what travels                                  from
==============================  ==========================================  =========
dsp/batch                       sample batch (binary, :mod:`protocol.batch_codec`)  controller
dsp/flag                        :class:`~protocol.messages.BlockFlag`         dsp
dsp/interrupt                   :class:`~protocol.messages.Interrupt`         dsp
dsp/config                      :class:`~protocol.messages.ConfigChange`      controller/tools
dsp/config_ack                  :class:`~protocol.messages.ConfigAck`         dsp
dsp/tf                          queryable -> :class:`~protocol.messages.TfSnapshot`  dsp
plant/truth                     :class:`~protocol.messages.GroundTruth`       plant (test port)
plant/scenario                  :class:`~protocol.messages.ScenarioCommand`   tests/experiments
plant/events                    :class:`~protocol.messages.PlantEvent`        plant (test port)
controller/status               :class:`~protocol.messages.ControllerStatus`  controller
controller/tf                   :class:`~protocol.messages.TfSnapshot`        controller (each TF download, as downloaded)
controller/command              :class:`~protocol.messages.ConfigChange`      tools (``ralf-hil reconfigure``)
health/<service>                :class:`~protocol.messages.Health`            every service
alive/<service>                 liveliness token                             every service
==============================  ==========================================  =========
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_RIG_ID = re.compile(r"[A-Za-z0-9_-]{1,64}")
SERVICES = ("plant", "controller", "dsp")


def validate_rig_id(rig_id: str) -> str:
    """A rig id is one key chunk: letters, digits, ``-`` and ``_`` only."""
    # fullmatch, not match: "$" would also accept a trailing newline.
    if not isinstance(rig_id, str) or not _RIG_ID.fullmatch(rig_id):
        raise ValueError(f"rig id {rig_id!r} must be 1-64 characters of [A-Za-z0-9_-]")
    return rig_id


@dataclass(frozen=True)
class Keys:
    """All key expressions of one rig."""

    rig_id: str = "default"

    def __post_init__(self) -> None:
        validate_rig_id(self.rig_id)

    @property
    def root(self) -> str:
        return f"ralf/{self.rig_id}"

    @property
    def batch(self) -> str:
        return f"{self.root}/dsp/batch"

    @property
    def flag(self) -> str:
        return f"{self.root}/dsp/flag"

    @property
    def interrupt(self) -> str:
        return f"{self.root}/dsp/interrupt"

    @property
    def dsp_config(self) -> str:
        return f"{self.root}/dsp/config"

    @property
    def dsp_config_ack(self) -> str:
        return f"{self.root}/dsp/config_ack"

    @property
    def tf(self) -> str:
        return f"{self.root}/dsp/tf"

    @property
    def truth(self) -> str:
        return f"{self.root}/plant/truth"

    @property
    def scenario(self) -> str:
        return f"{self.root}/plant/scenario"

    @property
    def plant_events(self) -> str:
        return f"{self.root}/plant/events"

    @property
    def controller_status(self) -> str:
        return f"{self.root}/controller/status"

    @property
    def controller_command(self) -> str:
        return f"{self.root}/controller/command"

    @property
    def tf_downloads(self) -> str:
        return f"{self.root}/controller/tf"

    def health(self, service: str) -> str:
        return f"{self.root}/health/{service}"

    @property
    def health_all(self) -> str:
        return f"{self.root}/health/*"

    def alive(self, service: str) -> str:
        return f"{self.root}/alive/{service}"

    @property
    def alive_all(self) -> str:
        return f"{self.root}/alive/*"
