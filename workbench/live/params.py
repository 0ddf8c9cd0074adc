"""The live view's parameter panel (docs/calibration.md, docs/live-view.md):
Foxglove's parameter capability (``getParameters``, ``setParameters``)
answered from the running controller's parameter table.

The panel is a client of the controller like ``ralf-hil param``
(:mod:`workbench.param_cli`'s functions on the view's zenoh session): a get
is a query of ``controller/params``, a set a
:class:`~protocol.messages.ParamSet` on the tool's key
(``controller/param_set_tool``), so every change takes the controller's
one path with its checks, and the live view's clients count as the tool
role: their sets are taken only where the run's ``param_write_roles``
names ``tool`` (``ralf-hil up --live`` opens a session of the tool's role
for it, :func:`tool_session`; ``ralf-hil live --params`` uses its own). A refused set (the role, the limits, the OATF's guards, no
answer) changes nothing, is counted (:attr:`ParamPanel.refused`), logged
once per reason, and told to the clients as a Foxglove status; the answer
to the set is the table as it is, so the panel shows the value in effect.
"""

from __future__ import annotations

import logging
import math
import threading
from pathlib import Path
from typing import Any

from protocol.keys import Keys

__all__ = ["ParamPanel", "tool_session"]

log = logging.getLogger(__name__)


def tool_session(env_file: str | Path) -> Any:
    """A zenoh session as the rig's tool, from the ``tool.env`` ``ralf-hil up`` writes (its
    ``RALF_*`` variables: credentials, certificates, the launcher's endpoint): the launcher's own
    session only observes, so the panel's changes go out on a session of the tool's role."""
    from protocol.settings import CommonSettings, load_settings
    from service_kit.transport import open_zenoh

    overrides: dict[str, Any] = {}
    for line in Path(env_file).read_text(encoding="utf-8").splitlines():
        name, sep, value = line.partition("=")
        if sep and name.startswith("RALF_"):
            overrides[name.removeprefix("RALF_").lower()] = value
    return open_zenoh(load_settings(CommonSettings, overrides), retry_for_s=10.0)


class ParamPanel:
    """The panel's side of the controller (module docstring). ``session`` may be given after the
    server starts (``ralf-hil up`` opens its session later); until then the panel is empty."""

    def __init__(self, rig_id: str, session: Any = None, *, timeout_s: float = 2.0) -> None:
        self.keys = Keys(rig_id)
        self.session = session
        self.timeout_s = timeout_s
        self.refused = 0
        self.taken = 0
        self._said: set[str] = set()
        self._lock = threading.Lock()
        self.on_refused: Any = None
        """Called with each refusal's line (the view sends it to its clients as a status)."""

    def values(self, names: list[str]) -> list[tuple[str, float]]:
        """``(name, value in effect)`` of ``names`` (all when empty; those without a value in this run, the
        OATF's without an OATF, left out); empty if the controller does not answer."""
        from workbench.param_cli import query_table

        if self.session is None:
            return []
        table = query_table(self.session, self.keys, self.timeout_s)
        if table is None:
            return []
        return [(p.name, p.value) for p in table.params if (not names or p.name in names) and p.value is not None]

    def set(self, name: str, value: Any) -> str | None:
        """Send ``name = value`` as the tool role; None if the controller took it, else the refusal's line (counted)."""
        from workbench.param_cli import send_set

        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            reason = f"{name}: {value!r} is not a finite number"
        elif self.session is None:
            reason = f"{name} not changed: the live view has no session to the rig yet"
        else:
            answer = send_set(self.session, self.keys, "tool", name, float(value), self.timeout_s)
            if answer is not None and answer.accepted:
                with self._lock:
                    self.taken += 1
                return None
            reason = (
                f"{name} not changed: {answer.reason}"
                if answer is not None
                else f"{name} not changed: no answer from the controller within {self.timeout_s:g} s (controller.param_commands=true?)"
            )
        with self._lock:
            self.refused += 1
            first = reason not in self._said
            self._said.add(reason)
        if first:
            log.warning("live view: parameter change refused: %s", reason)
        if self.on_refused is not None:
            self.on_refused(reason)
        return reason
