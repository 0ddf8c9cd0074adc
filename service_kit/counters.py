"""The one shape of every board's counters: a dataclass of named ints that
flattens into a health message (``Health.counters``)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Counters:
    """Base of a counters dataclass: subclasses declare ``name: int = 0`` fields."""

    def as_dict(self) -> dict[str, int]:
        """The counters by name, as a health message carries them."""
        return dict(vars(self))
