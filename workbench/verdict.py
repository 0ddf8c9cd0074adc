"""One verdict for a whole run: PASS, DEGRADED, FAIL or INVALID.

A pure function of what the run left behind (its summary: the controller's
status and every service's health, the exit codes, the supervisor's
failure, the WARNING and ERROR lines counted in each service's log), used by
``ralf-hil up`` (its table, ``--json`` and exit code), ``ralf-hil
timing-test`` (report and JUnit) and the pytest plugin's run record.

The rule (docs/reliability.md, "The run's verdict"), the first that applies:

* **INVALID**: the run tested nothing: the plant model died (an FMU step
  returned Error or Fatal, or asked to terminate: its samples are frozen
  from then on), or the controller made no control tick.
* **FAIL**: a service exited non-zero or the rig failed (a plant fault, a
  monitor's ``stop``, a service that died), or the timing verdict
  failed (deadline misses in a row beyond the criterion; with ``strict``
  the wake-up latency and the runs of overruns too). A plant process that
  died (a crash inside its FMU included) is FAIL, not INVALID: its samples
  stopped rather than froze, and the controller ended the run on its
  plant-fault policy (:mod:`workbench.loss_grace`).
* **DEGRADED**: the run went on but something went wrong on the way: a
  deadline missed (one at a time: absorbed), an interrupt lost, a schedule
  re-based with samples skipped, a plant SYNC watchdog trip (valves held
  at zero), the plant model's step discarded or non-finite (last outputs
  held), the DSP lost, or any WARNING or ERROR line in a service's log.
* **PASS**: none of the above.

A test knob set under the run (`protocol/command_fields.py`, the tester's
`test_command`) degrades it; a change by `ralf-hil reconfigure` is a note
beside the level, which it leaves as it is.

``up`` exits 0 on PASS and DEGRADED, 1 on FAIL and INVALID (130 when
interrupted, whatever the verdict).

A **deadline miss** (``deadline_misses``) is a batch whose interrupt had
not come by its deadline tick (counted once per batch, whether it comes
late or never); an **interrupt lost** (``interrupts_lost``) is one that
never came: given up after four deadlines, or, under a link fault in
lockstep and co-simulation, dropped and declared lost at its due tick
without a wait (so it is not counted as a miss there). Both are shown side
by side; each degrades the run.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

Level = Literal["PASS", "DEGRADED", "FAIL", "INVALID"]
LEVELS: tuple[Level, ...] = ("PASS", "DEGRADED", "FAIL", "INVALID")
EXIT_CODES: Mapping[Level, int] = {"PASS": 0, "DEGRADED": 0, "FAIL": 1, "INVALID": 1}
"""``ralf-hil up``'s exit code per verdict (130 when interrupted, whatever the verdict)."""

PLANT_MODEL_DEAD = ("fmu_step_errors", "fmu_terminated")
"""Plant health counters of a model that made its last step (FMI allows no doStep after Error/Fatal/Terminate)."""

DEGRADING: tuple[tuple[str, str, str], ...] = (
    # (service, counter, what it means): each non-zero one degrades the run
    ("controller", "deadline_misses", "deadline misses (interrupts not there by their deadline)"),
    ("controller", "interrupts_lost", "interrupts lost (never came)"),
    ("controller", "schedule_resyncs", "schedules re-based (the loop fell behind)"),
    ("controller", "periods_skipped", "sample periods skipped"),
    ("controller", "dsp_lost", "DSP lost"),
    ("plant", "watchdog_trips", "plant SYNC watchdog trips (valves held at zero)"),
    ("plant", "fmu_step_discards", "plant model steps discarded (outputs held)"),
    ("plant", "fmu_non_finite_outputs", "plant model steps with non-finite outputs (outputs held)"),
)


@dataclass(frozen=True)
class Verdict:
    level: Level
    reasons: tuple[str, ...]
    """Why the verdict is not PASS (every finding, worst first); empty on PASS."""
    findings: dict[str, Any] = field(default_factory=dict)
    """The counts the rule looked at (all of them, zero ones too)."""
    by_level: dict[str, list[str]] = field(default_factory=dict)
    """The reasons under the level each one calls for (INVALID, FAIL, DEGRADED)."""
    notes: tuple[str, ...] = ()
    """Facts of the run that change no level (its configuration changed under it by ``reconfigure``)."""

    @property
    def exit_code(self) -> int:
        return EXIT_CODES[self.level]

    def line(self) -> str:
        notes = "".join(f" (note: {note})" for note in self.notes)
        return self.level + (": " + "; ".join(self.reasons) if self.reasons else ": nothing went wrong") + notes

    def as_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.level, "reasons": list(self.reasons), "by_level": self.by_level, "exit_code": self.exit_code,
            "findings": self.findings, "notes": list(self.notes),
        }  # fmt: skip


def _counters(summary: Mapping[str, Any], service: str) -> Mapping[str, Any]:
    health = (summary.get("health") or {}).get(service) or {}
    return health.get("counters") or {}


def _num(value: Any) -> int:
    try:
        return int(value or 0)
    except (TypeError, ValueError):
        return 0


def judge(summary: Mapping[str, Any], timing: str | None = None) -> Verdict:
    """The verdict of a run from its summary (the keys of ``ralf-hil up --json``:
    ``controller``, ``health``, ``exit_codes``, and where known ``failure`` and
    ``log_warnings``/``log_errors``: {service: lines}); ``timing``: the timing
    verdict line (:func:`workbench.timing_test.report.health_verdict`), FAIL
    when it starts with ``FAIL``."""
    invalid: list[str] = []
    fail: list[str] = []
    degraded: list[str] = []
    controller = _counters(summary, "controller")
    plant = _counters(summary, "plant")
    findings: dict[str, Any] = {}

    dead = sum(_num(plant.get(k)) for k in PLANT_MODEL_DEAD) + _num(controller.get("plant_model_dead"))
    findings["plant_model_dead"] = dead > 0
    if dead:
        plant_health = (summary.get("health") or {}).get("plant") or {}
        why = plant_health.get("last_miss") or "the plant model's step failed"
        invalid.append(f"plant model dead ({why}): its samples were frozen from then on, the run tested nothing after it")
    status = summary.get("controller") or {}
    ticks = _num(status.get("ticks"))
    findings["control_ticks"] = ticks
    if ticks == 0:
        invalid.append("no control tick")

    failure = str(summary.get("failure") or "")
    if failure:
        fail.append(f"rig failed: {failure}")
    bad = {name: code for name, code in (summary.get("exit_codes") or {}).items() if _num(code) != 0}
    if bad:
        fail.append("exit codes " + ", ".join(f"{name}={code}" for name, code in bad.items()))
    if timing and timing.startswith("FAIL"):
        fail.append(f"timing {timing}")

    for service, name, what in DEGRADING:
        count = _num((controller if service == "controller" else plant).get(name))
        findings[name] = count
        if count:
            degraded.append(f"{what}: {count}")
    for key, what in (("log_warnings", "WARNING"), ("log_errors", "ERROR")):
        lines = {name: _num(n) for name, n in (summary.get(key) or {}).items()}
        findings[key] = lines
        if any(lines.values()):
            degraded.append(f"{what} lines in the logs: " + ", ".join(f"{name} {n}" for name, n in lines.items() if n))

    notes: list[str] = []
    commands, knobs = _num(controller.get("reconfigurations")), _num(controller.get("test_knob_changes"))
    findings["reconfigurations"], findings["test_knob_changes"] = commands, knobs
    if knobs:
        degraded.append(f"test knobs set under the run: {knobs} (protocol/command_fields.py; the run's timing is not the rig's own)")
    if commands > knobs:
        notes.append(f"configuration changed under the run by {commands - knobs} command(s) (ralf-hil reconfigure)")

    level: Level = "INVALID" if invalid else "FAIL" if fail else "DEGRADED" if degraded else "PASS"
    return Verdict(level, tuple(invalid + fail + degraded), findings, {"INVALID": invalid, "FAIL": fail, "DEGRADED": degraded}, tuple(notes))
