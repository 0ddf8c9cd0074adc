"""A one-process lockstep rig with its controller's XCP slave on, and pyxcp masters for it."""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from pyxcp.config import create_application_from_config
from pyxcp.daq_stim import DaqList, DaqOnlinePolicy
from pyxcp.master import Master

from workbench.composition import InProcessRun, run_in_process


def free_port(kind: int) -> int:
    """A port the kernel just gave out on 127.0.0.1 (for ``kind`` SOCK_DGRAM or SOCK_STREAM)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class BackgroundRig:
    """A lockstep run in a thread until :meth:`stop`."""

    controller: dict[str, Any]
    common: dict[str, Any] | None = None
    plant: dict[str, Any] | None = None
    at_tick: tuple[int, Any] | None = None
    stop_event: threading.Event = field(default_factory=threading.Event)
    run: InProcessRun | None = None
    error: BaseException | None = None

    def _target(self) -> None:
        try:
            self.run = run_in_process(controller=self.controller, plant=self.plant, common=self.common, at_tick=self.at_tick, stop=self.stop_event)
        except BaseException as exc:  # handed to the test
            self.error = exc

    def start(self) -> BackgroundRig:
        self._thread = threading.Thread(target=self._target, name="rig", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> InProcessRun:
        self.stop_event.set()
        self._thread.join(timeout=120)
        if self.error is not None:
            raise self.error
        assert self.run is not None, "the rig did not finish"
        return self.run


@contextmanager
def master(port: int, protocol: str, policy: Any = None, raw_errors: bool = False, disconnect: bool = True) -> Iterator[Master]:
    """A connected pyxcp master on 127.0.0.1:``port`` over ``protocol`` (UDP or TCP).
    ``raw_errors``: pyxcp's error handling off (a negative response raises its
    ``XcpResponseError`` at once instead of the error matrix's retries).
    ``disconnect``: False when the slave is gone by the end (no DISCONNECT sent)."""
    app = create_application_from_config({"Transport": {"Eth": {"host": "127.0.0.1", "port": port, "protocol": protocol}}})
    app.transport.layer = "ETH"
    app.general.disable_error_handling = raw_errors
    app.transport.timeout = 2.0
    with Master("eth", config=app, policy=policy) as x:
        x.connect()
        yield x
        if disconnect:
            x.disconnect()


@contextmanager
def can_master(channel: str, id_master: int, id_slave: int, policy: Any = None) -> Iterator[Master]:
    """A connected pyxcp master over its CAN transport on python-can's ``virtual`` bus ``channel``."""
    app = create_application_from_config(
        {"Transport": {"CAN": {"interface": "virtual", "channel": channel, "can_id_master": id_master, "can_id_slave": id_slave}}}
    )
    app.transport.layer = "CAN"
    app.transport.timeout = 2.0
    with Master("can", config=app, policy=policy) as x:
        x.connect()
        yield x
        x.disconnect()


class Collect(DaqOnlinePolicy):
    """Keeps every decoded DAQ sample: (list, timestamp1 (the slave's, ns), values)."""

    def __init__(self, lists: list[DaqList]) -> None:
        # With a logger, pyxcp does not look for its application (which would parse sys.argv: pytest's).
        super().__init__(lists, logger=logging.getLogger("pyxcp.daq_stim"))
        self.pid_off = False  # PID_OFF is CAN's
        self.samples: list[tuple[int, int, list[Any]]] = []

    def on_daq_list(self, daq_list: int, timestamp0: int, timestamp1: int, payload: list[Any]) -> None:
        self.samples.append((daq_list, timestamp1, list(payload)))


def wait_for(predicate: Any, timeout: float = 60.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False
