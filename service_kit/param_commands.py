"""``ralf-hil param`` on a board's side (docs/calibration.md): the
parameter table answered on a query, changes taken from the roles the run
allows, each answered once. The controller and the plant each have one, on
their own keys (``BOARD/params``, ``BOARD/param_set``, ...).

On ``BOARD/params`` (a queryable, rate-limited as every answer is:
:mod:`service_kit.query_gate`) the board answers a
:class:`~protocol.messages.ParamTable`: every parameter, its unit, limits
and value in effect, and the roles whose changes it takes.

A change (:class:`~protocol.messages.ParamSet`) arrives on the key of its
sender's role: ``BOARD/param_set`` only the tester may publish,
``BOARD/param_set_tool`` only a tool (the rig's access rules,
service_kit/access.py, drop anyone else's), so the key names the role. A
change from a role the run's ``param_write_roles`` does not name, one the
table or the guards refuse (:mod:`service_kit.param_path`), is answered at
once on ``BOARD/param_answer``, refused with the reason, and counted; an
accepted one joins the board's parameter path and is answered when it is
applied, at the step (tick, SYNC) from which it is in effect.

Off unless ``param_commands`` is set: nothing is declared.
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Any, Final

import zenoh

from protocol.errors import ProtocolError
from protocol.keys import Keys, param_keys
from protocol.messages import ParamAnswer, ParamSet, ParamTable, decode, encode
from service_kit.encodings import JSON
from service_kit.inbox import RateLimitedLog
from service_kit.param_path import ParamPath, ParamRefused
from service_kit.query_gate import OVER_RATE
from service_kit.query_gate import gate as query_gate
from service_kit.relink import MovingOut

__all__ = ["ROLES_THAT_WRITE", "ParamCommands", "write_roles"]

log = logging.getLogger(__name__)

ROLES_THAT_WRITE: Final = ("tester", "tool")
"""The roles a run may let change its parameters (``param_write_roles``)."""
MAX_PAYLOAD: Final = 4096
SEEN_REQUESTS: Final = 256


def write_roles(setting: str) -> tuple[str, ...]:
    """The roles of a ``param_write_roles`` setting, in :data:`ROLES_THAT_WRITE`'s order."""
    named = {r.strip() for r in setting.split(",") if r.strip()}
    return tuple(r for r in ROLES_THAT_WRITE if r in named)


class ParamCommands:
    """A board's parameter keys on one zenoh session (module docstring)."""

    def __init__(self, session: zenoh.Session, rig_id: str, path: ParamPath, roles: tuple[str, ...], sim_time: Callable[[], float]) -> None:
        self.keys = param_keys(Keys(rig_id), path.board)
        self.path = path
        self.roles = roles
        self.sim_time = sim_time
        self.malformed = 0
        self._seq = 0
        self._lock = threading.Lock()
        self._seen: OrderedDict[str, ParamAnswer | None] = OrderedDict()
        """Recent request ids and their answers (None: not answered yet): a resent request is taken once."""
        self._gate = query_gate("params")
        self._log = RateLimitedLog(log, 10.0)
        self.moves = MovingOut()
        """The out lock; a move to a new session (service_kit/relink.py) and what was sent meanwhile, dropped."""
        self._handles: list[Any] = []
        self.bind(session)
        path.answer = self.send_answer

    # -- changes -----------------------------------------------------------------------
    def _on_set(self, role: str, sample: zenoh.Sample) -> None:
        payload = sample.payload
        if len(payload) > MAX_PAYLOAD:
            self.malformed += 1
            return
        try:
            cmd = decode(ParamSet, payload.to_bytes())
        except ProtocolError as exc:
            self.malformed += 1
            self._log.warning("param_set_malformed", "undecodable parameter change: %s", exc)
            return
        with self._lock:
            repeated = cmd.request_id in self._seen
            earlier = self._seen.get(cmd.request_id)
            if not repeated:
                self._seen[cmd.request_id] = None
                while len(self._seen) > SEEN_REQUESTS:
                    self._seen.popitem(last=False)
        if repeated:  # a resend: its answer again if it has one, nothing taken twice
            if earlier is not None:
                self._put(earlier)
            return
        reason = self.take(role, cmd.name, cmd.value, cmd.request_id)
        if reason is not None:
            self.send_answer(ParamAnswer(seq=0, sim_time_s=self.sim_time(), request_id=cmd.request_id, name=cmd.name, accepted=False, reason=reason))

    def take(self, role: str, name: str, value: float, request_id: str | None) -> str | None:
        """Queue ``name = value`` from ``role``: None if queued, else why not (counted, logged once a while)."""
        if role not in self.roles:
            allowed = ",".join(self.roles) or "none"
            reason = f"the {role} role may not change parameters in this run (param_write_roles: {allowed})"
            self.path.refused += 1
        else:
            try:
                self.path.set(name, value, "param", role, request_id)
                return None
            except ParamRefused as exc:
                reason = str(exc)
        self._log.warning("param_set_refused", "parameter change refused: %s", reason)
        return reason

    def send_answer(self, answer: ParamAnswer) -> None:
        with self._lock:
            answer = answer.model_copy(update={"seq": self._seq})
            self._seq += 1
            if answer.request_id in self._seen:
                self._seen[answer.request_id] = answer
        self._put(answer)

    def _put(self, answer: ParamAnswer) -> None:
        payload = encode(answer)
        try:
            self.moves.send(lambda: self.session.put(self.keys.param_answer, payload, encoding=JSON))
        except Exception as exc:  # noqa: BLE001 - a closing session: the answer is lost, the change is not
            log.debug("parameter answer not sent: %s", exc)

    # -- the table ---------------------------------------------------------------------
    def table(self) -> ParamTable:
        return ParamTable(seq=0, sim_time_s=self.sim_time(), params=self.path.table(), write_roles=self.roles)

    def _on_query(self, query: zenoh.Query) -> None:
        if not self._gate.admit():
            query.reply_err(OVER_RATE)
            return
        try:
            query.reply(self.keys.params, encode(self.table()), encoding=JSON)
            self._gate.note_answered()
        except Exception as exc:  # noqa: BLE001 - a querier gone; counted
            self._gate.note_failed()
            log.debug("parameter table not sent: %s", exc)

    def counters(self) -> dict[str, int]:
        return {"param_sets_malformed": self.malformed, **self._gate.as_dict()}

    # -- the session (movable: service_kit/relink.py) ------------------------------------
    @property
    def out_lock(self) -> threading.Lock:
        return self.moves.lock

    def bind(self, session: zenoh.Session) -> None:
        """The subscribers and the queryable on ``session``."""
        self.session = session
        self._handles = [
            session.declare_subscriber(self.keys.param_set, lambda s: self._on_set("tester", s)),
            session.declare_subscriber(self.keys.param_set_tool, lambda s: self._on_set("tool", s)),
            session.declare_queryable(self.keys.params, self._on_query),
        ]
        self.moves.bound_to_new()

    def unbind(self) -> None:
        """Everything declared, undeclared (the session may be broken: nothing raises)."""
        self.moves.bound = False
        for handle in self._handles:
            try:
                handle.undeclare()
            except Exception as exc:  # noqa: BLE001 - a closed session's handles
                log.debug("undeclare: %s", exc)
        self._handles = []

    def close(self) -> None:
        with self.moves.lock:
            self.unbind()
