"""Acceptance filters, as a CAN controller's: which received frames a node
takes at all. The rule is python-can's (``can.BusABC.set_filters``): a frame
is accepted when no filter is set, or when for at least one filter
``identifier & can_mask == can_id & can_mask`` and, if the filter names
``extended``, the frame's identifier kind is that one.

:func:`compile_filters` turns python-can's list of dicts into plain tuples
(refusing what is no filter, one line); :func:`accepts` applies them. The
wire arbiter (:mod:`service_kit.can_wire.hub`) runs them for each client, so
a process is never woken for a frame it would throw away.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import can

from service_kit.can_wire.bits import EXTENDED_ID_MAX

EITHER, STANDARD_ONLY, EXTENDED_ONLY = 0, 1, 2
"""Which identifier kind a filter applies to (python-can's ``extended`` absent, False, True)."""

Filter = tuple[int, int, int]
"""(can_id & can_mask, can_mask, kind), identifier and mask cut to 29 bits."""


NEVER: Filter = (1, 0, EITHER)
"""A filter no frame passes (``identifier & 0`` is never 1)."""


NO_FRAME: list[can.typechecking.CanFilter] = [{"can_id": EXTENDED_ID_MAX + 1, "can_mask": EXTENDED_ID_MAX + 1}]
"""python-can filters no frame passes (they ask for an identifier bit no frame has): a bus that only sends."""


class FilterError(ValueError):
    """A filter that python-can would not apply (one line)."""


def compile_filters(filters: Iterable[Mapping[str, Any]] | None) -> tuple[Filter, ...] | None:
    """python-can's filters as tuples; None (accept every frame) for None or none at all."""
    if not filters:
        return None
    out: list[Filter] = []
    for i, f in enumerate(filters):
        try:
            can_id, can_mask = f["can_id"], f["can_mask"]
        except (KeyError, TypeError):
            raise FilterError(f"filter {i}: needs can_id and can_mask, got {f!r}") from None
        if not isinstance(can_id, int) or not isinstance(can_mask, int) or isinstance(can_id, bool) or isinstance(can_mask, bool):
            raise FilterError(f"filter {i}: can_id and can_mask must be integers, got {can_id!r} and {can_mask!r}")
        if can_id < 0 or can_mask < 0:
            raise FilterError(f"filter {i}: can_id and can_mask must not be negative")
        kind = EITHER if "extended" not in f else EXTENDED_ONLY if f["extended"] else STANDARD_ONLY
        if can_id & can_mask & ~EXTENDED_ID_MAX:
            out.append(NEVER)  # asks for identifier bits no frame has: python-can's rule matches nothing
            continue
        mask = can_mask & EXTENDED_ID_MAX  # no identifier has more bits: the rest cannot change a match
        out.append((can_id & mask, mask, kind))
    return tuple(out)


def accepts(filters: tuple[Filter, ...] | None, identifier: int, extended: bool) -> bool:
    """Whether a frame with ``identifier`` (``extended`` or not) passes ``filters``."""
    if filters is None:
        return True
    kind = EXTENDED_ONLY if extended else STANDARD_ONLY
    for can_id, mask, which in filters:
        if (which == EITHER or which == kind) and identifier & mask == can_id:
            return True
    return False
