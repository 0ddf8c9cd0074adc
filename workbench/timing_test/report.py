"""Statistical verdicts: percentiles, histograms, run lengths of
consecutive misses and pass/fail against stated criteria."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from workbench.hostinfo import host_line


@dataclass(frozen=True)
class Criteria:
    """What a run is judged on. The rig promises no two deadline misses in a
    row (one late batch is absorbed by holding the last parameters; a second
    is what ``policy_deadline``/``policy_stale`` act on) and, where the same
    run measured a sleep-only loop (the bench), overruns at most
    ``overrun_ratio_to_floor`` times that loop's per tick. An overrun is
    otherwise only counted (``policy_overrun`` count, the default): a
    general-purpose kernel's scheduler makes them, not the rig.

    ``strict`` (``timing-test --strict``, or a wake-up limit given on the
    command line) also judges the wake-up latency and the runs of overruns
    (at most ``max_consecutive_misses``): a PREEMPT_RT host's criteria."""

    wakeup_p99_us: float = 250.0
    wakeup_p999_us: float = 1000.0
    max_consecutive_misses: int = 1
    strict: bool = False
    overrun_ratio_to_floor: float = 2.0


RT_CLASS_P99_US = 250.0
"""Wake-up p99 at 200 Hz that a PREEMPT_RT host with the real-time measures
meets (docs/timing.md); a general-purpose kernel typically shows 0.3-2 ms."""


def latency_class(controller_health: dict[str, Any], host: dict[str, Any] | None = None) -> str | None:
    """The host's latency class, as information: its kernel (PREEMPT_RT or
    general-purpose) and the wake-up p99/p99.9 this run measured, against
    the PREEMPT_RT class figure. None without wall-clock wake-ups (cosim)."""
    lat = controller_health.get("latencies", {}).get("sync_jitter") or {}
    if not lat.get("count"):
        return None
    kernel = "PREEMPT_RT kernel" if (host or {}).get("preempt_rt") else "general-purpose kernel"
    p99, p999 = lat["p99"] * 1e6, lat["p999"] * 1e6
    within = "within" if p99 <= RT_CLASS_P99_US else "outside"
    return f"{kernel}: wake-up p99 {p99:.0f} us, p99.9 {p999:.0f} us ({within} the PREEMPT_RT class, p99 <= {RT_CLASS_P99_US:g} us)"


def health_verdict(controller_health: dict[str, Any], criteria: Criteria | None = None, overrun_floor_per_tick: float | None = None) -> str | None:
    """A one-line verdict from the controller's health (``ralf-hil up``'s
    summary, the bench): the longest run of deadline misses; given the same
    run's sleep-only loop's overruns per tick, the overruns against it; with
    ``criteria.strict`` the longest run of overruns and the wake-up p99/p99.9
    too. What is not judged is said as information after a semicolon (see
    :func:`latency_class` for the host's line)."""
    c = criteria or Criteria()
    lat = controller_health.get("latencies", {}).get("sync_jitter") or {}
    counters = controller_health.get("counters", {})
    parts, info, ok = [], [], True
    if "deadline_miss_run_max" in counters:
        ok &= counters["deadline_miss_run_max"] <= c.max_consecutive_misses
        parts.append(f"deadline misses in a row {counters['deadline_miss_run_max']} (<= {c.max_consecutive_misses})")
    ticks = lat.get("count") or int(counters.get("ticks", 0))
    if overrun_floor_per_tick is not None and "overruns" in counters and ticks:
        allowed = max(1, math.ceil(c.overrun_ratio_to_floor * overrun_floor_per_tick * ticks))
        ok &= counters["overruns"] <= allowed
        parts.append(f"overruns {counters['overruns']} (<= {allowed}: {c.overrun_ratio_to_floor:g}x the sleep-only loop's)")
    if "overrun_run_max" in counters:
        if c.strict:
            ok &= counters["overrun_run_max"] <= c.max_consecutive_misses
            parts.append(f"overruns in a row {counters['overrun_run_max']} (<= {c.max_consecutive_misses})")
        elif counters.get("overruns") and overrun_floor_per_tick is None:
            info.append(f"overruns {counters['overruns']}, at most {counters['overrun_run_max']} in a row (counted, not judged)")
    if c.strict and lat.get("count"):
        for name, key, limit in (("p99", "p99", c.wakeup_p99_us), ("p99.9", "p999", c.wakeup_p999_us)):
            value = lat[key] * 1e6
            ok &= value <= limit
            parts.append(f"wake-up {name} {value:.0f} us (<= {limit:g})")
    if not parts:
        return None
    return ("PASS: " if ok else "FAIL: ") + ", ".join(parts) + "".join(f"; {text}" for text in info)


def run_lengths(flags: npt.ArrayLike) -> list[int]:
    """Lengths of the runs of consecutive true values, in order."""
    f = np.asarray(flags, dtype=bool).astype(np.int8)
    if f.size == 0:
        return []
    edges = np.diff(np.concatenate([[0], f, [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return (stops - starts).tolist()


def percentiles_us(values_s: npt.ArrayLike) -> dict[str, float | int]:
    v = np.asarray(values_s, dtype=float) * 1e6
    if v.size == 0:
        return {"count": 0}
    p50, p99, p999 = np.percentile(v, [50.0, 99.0, 99.9])
    return {"count": int(v.size), "p50_us": float(p50), "p99_us": float(p99), "p999_us": float(p999), "max_us": float(v.max())}


def _series(controller: Any) -> dict[str, np.ndarray]:
    out = {"wakeup": controller.jitter.values(), "tet": controller.tet.values()}
    for name, values in controller.hops.values_s().items():
        if name != "wakeup":
            out[f"hop_{name}"] = values
    return out


def evaluate(controller: Any, criteria: Criteria, mode: str) -> dict[str, Any]:
    """Percentiles of every measured series, miss run lengths and the verdict per criterion."""
    series = _series(controller)
    stats = {name: percentiles_us(v) for name, v in series.items()}
    misses = run_lengths(np.frombuffer(controller.batch_missed, dtype=np.int8)) if len(controller.batch_missed) else []
    longest = max(misses, default=0)
    checks: list[dict[str, Any]] = []
    wake = stats["wakeup"]
    realtime = mode == "realtime" and wake.get("count", 0) > 0
    for name, key, limit in (("wakeup p99", "p99_us", criteria.wakeup_p99_us), ("wakeup p99.9", "p999_us", criteria.wakeup_p999_us)):
        if realtime and criteria.strict:
            value = float(wake[key])
            checks.append({"name": name, "value": round(value, 1), "limit": limit, "unit": "us", "verdict": "pass" if value <= limit else "fail"})
        elif realtime:
            value = float(wake[key])
            checks.append(
                {"name": name, "value": round(value, 1), "limit": limit, "unit": "us", "verdict": "info (the host's latency class; judged with --strict)"}
            )
        else:
            checks.append({"name": name, "value": None, "limit": limit, "unit": "us", "verdict": "n/a (no wall-clock schedule in this mode)"})
    # A run too short to break a criterion cannot pass it: at least max + 1 batches (ticks) judged.
    enough = criteria.max_consecutive_misses + 1
    batches = len(controller.batch_missed)
    checks.append(
        {
            "name": "consecutive deadline misses",
            "value": longest,
            "limit": criteria.max_consecutive_misses,
            "unit": "batches",
            "judged": batches,
            "verdict": _too_few(batches, enough, "batches") or ("pass" if longest <= criteria.max_consecutive_misses else "fail"),
        }
    )
    overruns_judged = criteria.strict or mode != "realtime"  # in real time the scheduler's (counted); judged with --strict
    ticks = int(controller.tick)
    checks.append(
        {
            "name": "consecutive overruns",
            "value": controller.overrun_run_max,
            "limit": criteria.max_consecutive_misses,
            "unit": "ticks",
            "judged": ticks,
            "verdict": (_too_few(ticks, enough, "ticks") or ("pass" if controller.overrun_run_max <= criteria.max_consecutive_misses else "fail"))
            if overruns_judged
            else "info (counted, not judged in real time without --strict)",
        }
    )
    faults = controller.faults.as_counters() if controller.faults is not None else {}
    return {
        "passed": not any(verdict_failed(str(c["verdict"])) for c in checks),
        "criteria": checks,
        "latencies": stats,
        "miss_run_lengths": {"runs": len(misses), "longest": longest, "histogram": {str(k): misses.count(k) for k in sorted(set(misses))}},
        "batches": len(controller.batch_missed),
        "monitor_episodes": dict(controller.monitors.episodes),
        "last_miss": controller.monitors.last or controller.last_miss,
        "faults": faults,
        "fault_events": len(controller.faults.engine.events) if controller.faults is not None else 0,
    }


def _too_few(judged: int, needed: int, unit: str) -> str | None:
    """A failing verdict for a criterion judged over fewer items than could break it, else None."""
    if judged >= needed:
        return None
    return f"fail (too few {unit} to judge: {judged}, at least {needed})"


def verdict_failed(verdict: str) -> bool:
    """A criterion's verdict that fails the test (``fail``, or ``fail (...)``: too few to judge)."""
    return verdict == "fail" or verdict.startswith("fail (")


def _histograms(controller: Any, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    for name, values in _series(controller).items():
        if values.size == 0:
            continue
        fig, ax = plt.subplots(figsize=(6, 3.2))
        us = values * 1e6
        ax.hist(us, bins=min(100, max(10, int(np.sqrt(us.size)))), log=True)
        for q, style in ((99.0, "--"), (99.9, ":")):
            ax.axvline(float(np.percentile(us, q)), color="k", linestyle=style, label=f"p{q:g}")
        ax.set_xlabel(f"{name} (us)")
        ax.set_ylabel("count")
        ax.legend()
        fig.tight_layout()
        path = out / f"hist_{name}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
    return paths


def write_report(report: dict[str, Any], controller: Any, out: Path) -> tuple[Path, Path]:
    """``report.md``, ``report.json`` and ``hist_*.png`` in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    figures = _histograms(controller, out)
    report["figures"] = [p.name for p in figures]
    js = out / "report.json"
    js.write_text(json.dumps(report, indent=2, default=str))
    lines = [
        f"# Timing test: {report['scenario']['name']}",
        "",
        f"**{'PASS' if report['passed'] else 'FAIL'}** ({report['mode']}, {report['ticks']} ticks, {report['wall_time_s']:.1f} s wall{', run error: ' + report['error'] if report['error'] else ''})",
        "",
        *(
            [f"Run verdict: **{report['run_verdict']['verdict']}**" + "".join(f"; {r}" for r in report["run_verdict"]["reasons"]), ""]
            if report.get("run_verdict")
            else []
        ),
        host_line(report["host"]) + f"; load after {report['host']['load_average_after']}",
        "",
        "| criterion | value | limit | verdict |",
        "| --- | --- | --- | --- |",
    ]
    for c in report["criteria"]:
        judged = f" (over {c['judged']} {c['unit']})" if "judged" in c else ""
        lines.append(f"| {c['name']} | {c['value'] if c['value'] is not None else '-'} {c['unit']}{judged} | {c['limit']} {c['unit']} | {c['verdict']} |")
    lines += ["", "| series | count | p50 (us) | p99 (us) | p99.9 (us) | max (us) |", "| --- | --- | --- | --- | --- | --- |"]
    for name, s in report["latencies"].items():
        if s.get("count"):
            lines.append(f"| {name} | {s['count']} | {s['p50_us']:.1f} | {s['p99_us']:.1f} | {s['p999_us']:.1f} | {s['max_us']:.1f} |")
    m = report["miss_run_lengths"]
    lines += ["", f"Deadline misses: {m['runs']} runs over {report['batches']} batches, longest {m['longest']} (run length: count {m['histogram']}).", ""]
    lines.append(f"Monitor episodes: {report['monitor_episodes']}; last: {report['last_miss']}")
    if report["faults"]:
        lines += ["", "Faults applied: " + ", ".join(f"{k} {v}" for k, v in sorted(report["faults"].items()) if v)]
    lines += [""] + [f"![{p.stem}]({p.name})" for p in figures]
    md = out / "report.md"
    md.write_text("\n".join(lines) + "\n")
    return md, js
