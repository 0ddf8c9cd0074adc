"""The controller's window on the DSP (and on its own observers): where
batches, configuration and status go, and where flags, interrupts,
commands and the DSP's presence come from.

Two implementations of one small interface, so the same
:class:`controller.service.ControllerService` runs in three processes and in
the one-thread co-simulation:

* :class:`ZenohDspPort`: zenoh publishers, subscribers, the DSP's
  liveliness token, the TF query, the health publisher;
* :class:`workbench.cosim.DirectDspPort`: calls the DSP core directly; every
  message still goes through its codec (batch and TF codecs, pydantic JSON).

Events reach the controller through the ``sink(kind, payload, arrival,
attachment=None)`` it hands to :meth:`DspPort.connect`: ``kind`` is
``flag``, ``interrupt``, ``command``, ``test_command`` (the tester's
commands with test knobs, :mod:`protocol.command_fields`) or ``alive`` (payload ``b"1"``/``b"0"``).
``payload`` is bytes or zenoh's payload as received (``len`` and
``to_bytes()``: the controller caps its size before copying a byte, see
:mod:`service_kit.inbox`); ``attachment`` is the sending board's id on flags
and interrupts (the controller pairs with one board). The zenoh port calls
the sink in zenoh's threads, so decoding happens at the edge.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, Protocol

import zenoh

from protocol.keys import Keys
from protocol.messages import Health
from service_kit.encodings import BATCH, JSON, TF
from service_kit.relink import MovablePort, MovingOut
from service_kit.runtime import HealthPublisher

log = logging.getLogger(__name__)

Sink = Callable[..., None]
"""``sink(kind, payload, arrival, attachment=None)``."""


class DspPort(Protocol):
    synchronous: bool
    """True when every answer is in the sink before ``send_batch`` returns
    (nothing to wait for: a missing answer is missing)."""

    def connect(self, sink: Sink, clock: Callable[[], float]) -> None: ...

    def send_batch(self, payload: bytes) -> None: ...

    def send_config(self, payload: bytes) -> None: ...

    def send_status(self, payload: bytes) -> None: ...

    def download_tf(self, timeout_s: float) -> list[bytes]:
        """The TfSnapshot answers, as received (:mod:`protocol.tf_codec`; may raise on a dying transport)."""
        ...

    def publish_tf(self, payload: bytes) -> None:
        """``controller/tf``: a TF download as downloaded, binary (for recorders and viewers)."""
        ...

    def publish_param_change(self, payload: bytes) -> None:
        """``controller/param_changes``: a parameter change taken (:class:`~protocol.messages.ParamChanged`, JSON)."""
        ...

    def start_health(self, period_s: float, build: Callable[[int], Health]) -> None: ...

    def close(self) -> None: ...


class ZenohDspPort(MovablePort):
    """The DSP, the launcher and the monitor on zenoh. Movable to a new
    session (:mod:`service_kit.relink`): what the loop would send while it
    moves is dropped (the controller is alone then, nobody would hear it)
    and counted (:attr:`moves`, in health); the loop never waits for the move."""

    synchronous = False

    def __init__(self, session: zenoh.Session, rig_id: str) -> None:
        self.keys = Keys(rig_id)
        self.moves = MovingOut()
        """The out lock; moves to a new session and what the loop sent meanwhile, dropped."""
        self._sink: tuple[Sink, Callable[[], float]] | None = None
        self._subs: list[object] = []
        self._token: object | None = None
        self._health_args: tuple[float, Callable[[int], Health]] | None = None
        self._health: HealthPublisher | None = None
        self.bind(session)

    def bind(self, session: zenoh.Session) -> None:
        """Publishers on ``session``; the subscribers, token and health too once connected and started."""
        self.session = session
        block = zenoh.CongestionControl.BLOCK
        self._batch_pub = session.declare_publisher(self.keys.batch, encoding=BATCH, congestion_control=block, priority=zenoh.Priority.REAL_TIME, express=True)
        self._config_pub = session.declare_publisher(self.keys.dsp_config, encoding=JSON, congestion_control=block)
        self._status_pub = session.declare_publisher(self.keys.controller_status, encoding=JSON)
        self._tf_pub = session.declare_publisher(self.keys.tf_downloads, encoding=TF)
        if self._sink is not None:
            self._declare_inputs(*self._sink)
        if self._health_args is not None:
            self._health = HealthPublisher(session, self.keys.health("controller"), *self._health_args).start()
        self.moves.bound_to_new()

    def unbind(self) -> None:
        """Everything :meth:`bind` declared, undeclared (the session may be broken: nothing raises)."""
        self.moves.bound = False
        if self._health is not None:
            self._health.stop()
            self._health = None
        handles: list[Any] = [
            *self._subs,
            *([self._token] if self._token is not None else []),
            self._batch_pub,
            self._config_pub,
            self._status_pub,
            self._tf_pub,
        ]
        self._subs, self._token = [], None
        for handle in handles:
            try:
                handle.undeclare()
            except Exception as exc:  # noqa: BLE001 (a closed session's handles)
                log.debug("undeclare on the old session: %s", exc)

    def connect(self, sink: Sink, clock: Callable[[], float]) -> None:
        self._sink = (sink, clock)
        self._declare_inputs(sink, clock)

    def _declare_inputs(self, sink: Sink, clock: Callable[[], float]) -> None:
        keys, session = self.keys, self.session

        def put(kind: str) -> Callable[[zenoh.Sample], None]:
            # Stamp the arrival here: the MVME took an interrupt as a hardware
            # interrupt, not at the next tick. The payload goes uncopied: the sink
            # checks its size first.
            return lambda sample: sink(kind, sample.payload, clock(), sample.attachment)

        def alive(sample: zenoh.Sample) -> None:
            sink("alive", b"1" if sample.kind == zenoh.SampleKind.PUT else b"0", clock())

        self._subs = [
            session.declare_subscriber(keys.flag, put("flag")),
            session.declare_subscriber(keys.interrupt, put("interrupt")),
            session.liveliness().declare_subscriber(keys.alive("dsp"), alive, history=True),
            session.declare_subscriber(keys.controller_command, put("command")),
            session.declare_subscriber(keys.controller_test_command, put("test_command")),
        ]
        self._token = session.liveliness().declare_token(keys.alive("controller"))

    def _put(self, publisher: Callable[[], zenoh.Publisher], payload: bytes) -> None:
        """Sent on the current session; dropped and counted while the port moves (never waits)."""
        self.moves.send(lambda: publisher().put(payload))

    def send_batch(self, payload: bytes) -> None:
        self._put(lambda: self._batch_pub, payload)

    def send_config(self, payload: bytes) -> None:
        self._put(lambda: self._config_pub, payload)

    def send_status(self, payload: bytes) -> None:
        self._put(lambda: self._status_pub, payload)

    def download_tf(self, timeout_s: float) -> list[bytes]:
        return [reply.ok.payload.to_bytes() for reply in self.session.get(self.keys.tf, timeout=timeout_s) if reply.ok is not None]

    def publish_tf(self, payload: bytes) -> None:
        self._put(lambda: self._tf_pub, payload)

    def publish_param_change(self, payload: bytes) -> None:
        self.moves.send(lambda: self.session.put(self.keys.param_changes, payload, encoding=JSON))

    def start_health(self, period_s: float, build: Callable[[int], Health]) -> None:
        self._health_args = (period_s, build)
        self._health = HealthPublisher(self.session, self.keys.health("controller"), period_s, build).start()

    def close(self) -> None:
        with self.moves.lock:
            self.unbind()
