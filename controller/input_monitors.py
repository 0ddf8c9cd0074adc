"""Plausibility checks on the controller's A/D inputs: does what TPDO1
carries look like a sound sensor?

Four monitors, each off unless the ``input_monitors`` setting names it, each
with its policy in ``policies`` (``input_range``, ``input_stuck``,
``input_rate``, ``input_disagree``; :mod:`controller.monitors`):

* ``input_range``: an input at the converter's clip (a word at or above
  the 12-bit top code's ``0x7FF0``, or the bottom word ``-0x8000``: a
  shorted, open-to-rail or over-range sensor), or a cylinder's extension
  outside ``extension_range_in`` (its stroke);
* ``input_stuck``: an input's word unchanged for ``stuck_samples`` ticks in
  which the set-point moved. Only moving ticks count: at rest a quiet
  extension sensor may hold its code for long, while the arm following
  the trajectory moves every joint and shakes both links, so a sound
  sensor's code changes within a few ticks (a clean lap of the thesis
  trajectory: at most 6 in a row, docs/results/fault-detection.md);
* ``input_rate``: ``|word_k - word_(k-1)|`` in volts over the sample period
  above the input's rate limit (``extension_rate_v_s`` for AI1, AI2;
  ``deflection_rate_v_s`` for AI3, AI4): a step no cylinder or link makes;
* ``input_disagree``: a measured deflection more than ``disagree_in``
  from the sag the measured joint angles imply at rest
  (:func:`protocol.static_sag.static_sag_in`): the bound covers the links'
  vibration along the trajectory and a payload's extra sag.

A monitor fires when one of its channels enters its condition (one
episode, counted as ``episodes_input_*`` in the controller's health, with
an entry ``(tick, monitor, detail)`` in :attr:`InputMonitorChecks.events`
and in the run record's metadata) and clears when none of its channels is
in it. The checks read the tick's engineering values before the tick's
valve command goes out, so under ``stop`` the faulted sample never reaches
the valves: the run ends and the valves go to zero.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

from controller.loop import ROW_NAMES
from controller.monitors import INPUT_MONITORS, Monitors
from protocol.can_map import WORD16_VOLTS_PER_LSB
from protocol.setting_groups import InputMonitors
from protocol.static_sag import static_sag_in

__all__ = ["CLIP_HIGH_WORD", "CLIP_LOW_WORD", "InputMonitorChecks"]

CLIP_HIGH_WORD: Final[int] = 0x7FF0
"""A word at or above this is at the converter's top (the 12-bit top code, left-justified)."""
CLIP_LOW_WORD: Final[int] = -0x8000
"""The bottom word of every resolution."""
CHANNELS: Final[tuple[str, ...]] = ("AI1", "AI2", "AI3", "AI4")

_WORDS: Final[int] = ROW_NAMES.index("ai1_word")
_EXT: Final[int] = ROW_NAMES.index("ext1_in")
_DEFL: Final[int] = ROW_NAMES.index("defl1_in")
_THETA: Final[int] = ROW_NAMES.index("theta1")
_REF: Final[int] = ROW_NAMES.index("phi_ref1")


@dataclass
class InputMonitorChecks:
    """The four checks on one run's inputs, fed one tick's row at a time."""

    limits: InputMonitors
    monitors: Monitors
    sample_period_s: float
    events: list[tuple[int, str, str]] = field(default_factory=list)
    """Every firing: (tick, monitor, detail)."""
    _words: list[int] | None = None
    _ref: tuple[float, float] | None = None
    _unchanged: list[int] = field(default_factory=lambda: [0, 0, 0, 0])

    def __post_init__(self) -> None:
        for name in INPUT_MONITORS:
            self.monitors.episodes.setdefault(name, 0)
        self._rates()

    def set_limits(self, limits: InputMonitors) -> None:
        """New limits from the next tick on (the parameter path's change, checked against the
        settings' bounds): each check reads its limit every tick; the stuck counters, the last
        words and the monitors' episodes carry on."""
        self.limits = limits
        self._rates()

    def _rates(self) -> None:
        lsb = WORD16_VOLTS_PER_LSB
        self._rate_words = tuple(limit * self.sample_period_s / lsb for limit in (self.limits.extension_rate_v_s,) * 2 + (self.limits.deflection_rate_v_s,) * 2)
        """The rate limits as words per tick."""

    def check(self, tick: int, row: Sequence[float]) -> None:
        """The checks on one tick's row (:data:`controller.loop.ROW_NAMES`); may raise
        :class:`controller.monitors.MonitorStop` under policy ``stop``."""
        lim = self.limits
        words = [int(w) for w in row[_WORDS : _WORDS + 4]]
        ref = (row[_REF], row[_REF + 1])
        prev, prev_ref = self._words, self._ref
        if lim.range:
            self._report(tick, "input_range", self._range(words, row))
        if lim.stuck:
            moved = prev_ref is not None and ref != prev_ref
            found = []
            for j in range(4):
                if prev is None or words[j] != prev[j]:
                    self._unchanged[j] = 0
                elif moved:
                    self._unchanged[j] += 1
                if self._unchanged[j] >= lim.stuck_samples:
                    found.append(f"{CHANNELS[j]} word {words[j]} unchanged for {self._unchanged[j]} ticks while the set-point moves")
            self._report(tick, "input_stuck", found)
        if lim.rate and prev is not None:
            found = []
            for j in range(4):
                step = abs(words[j] - prev[j])
                if step > self._rate_words[j]:
                    found.append(
                        f"{CHANNELS[j]} changed {step * WORD16_VOLTS_PER_LSB:.3f} V in one tick ({step * WORD16_VOLTS_PER_LSB / self.sample_period_s:.0f} V/s)"
                    )
            self._report(tick, "input_rate", found)
        if lim.disagree:
            sag = static_sag_in(row[_THETA], row[_THETA + 1])
            found = []
            for j in range(2):
                gap = row[_DEFL + j] - sag[j]
                if abs(gap) > lim.disagree_in:
                    found.append(f"{CHANNELS[2 + j]} reads {row[_DEFL + j]:.3f} in, the joints imply {sag[j]:.3f} in at rest")
            self._report(tick, "input_disagree", found)
        self._words, self._ref = words, ref

    def _range(self, words: list[int], row: Sequence[float]) -> list[str]:
        found = []
        lo, hi = self.limits.extension_range_in
        for j in range(4):
            if words[j] >= CLIP_HIGH_WORD or words[j] <= CLIP_LOW_WORD:
                found.append(f"{CHANNELS[j]} at the converter's clip (word {words[j]})")
            elif j < 2 and not lo <= row[_EXT + j] <= hi:
                found.append(f"{CHANNELS[j]} reads {row[_EXT + j]:.3f} in, outside the stroke {lo:g}..{hi:g} in")
        return found

    def _report(self, tick: int, monitor: str, found: list[str]) -> None:
        if found:
            if monitor not in self.monitors.active:
                detail = f"tick {tick}: " + "; ".join(found)
                self.events.append((tick, monitor, detail))
                self.monitors.fire(monitor, detail)
        elif monitor in self.monitors.active:
            self.monitors.clear(monitor)

    def first_tick(self, monitor: str) -> int | None:
        """The tick ``monitor`` first fired at, or None."""
        return next((tick for tick, name, _ in self.events if name == monitor), None)
