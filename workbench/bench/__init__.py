"""``ralf-hil bench``: the rig's latencies and speeds, each measured beside
its floor in the same run, with the ratio.

Items (``--only``):

* ``zenoh``: batch -> interrupt through the real DSP service (emulated
  latency 0) vs a bare zenoh ping-pong of the batch's size vs bare UDP;
* ``can``: SYNC -> TPDO1 through the plant node (lockstep) vs a bare
  python-can udp_multicast ping-pong;
* ``realtime``: the three-process rig in real time at 200 Hz and 1 kHz:
  loop rate, SYNC jitter, TET, batch -> interrupt, overruns, deadline
  misses, from the controller's health and status;
* ``lockstep``: simulated seconds per wall second, three processes,
  the one-thread co-simulation (:mod:`workbench.cosim`, against its 100x target)
  and one process (:mod:`workbench.composition`);
* ``cosim``: the co-simulation alone (simulated s per wall s and per CPU
  s, µs per tick against the 100x budget, and where a tick goes,
  :mod:`workbench.bench.cosim_parts`);
* ``dsp``: :func:`dsp_service.bench.bench_identifier` (n = 2048);
* ``dsp-rigs``: how many 200 Hz rigs one DSP process serves (:mod:`workbench.bench.dsp_rigs`);
* ``hotpath``: controller tick and plant step in a micro-benchmark
  (:mod:`workbench.bench.hotpath`) against the 100 µs target, with their parts.
* ``fmu``: the FMU plant's SYNC -> TPDO1 step against the built-in arm's,
  and the co-simulation's speed with the example FMU against 50x
  (:mod:`workbench.bench.fmu_plant`).

Nothing here asserts a time: the numbers are reported, with the machine
they were measured on. Helper processes: :mod:`workbench.bench.peer`.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path
from typing import Any, Literal

from rich.console import Console, Group, RenderableType
from rich.table import Table
from rich.text import Text

from workbench.bench.items import FLOOR_ITEMS, ITEMS, QUICK_ITEMS, BenchContext, run_item
from workbench.bench.stats import load_average, machine_info
from workbench.progress import activity

DEFAULT_JSON = "ralf-bench.json"
TABLE_WIDTH = 120
"""The bench's table fits this many columns (long names fold)."""
SCHEMA = "ralf-hil-bench/1"

console = Console(stderr=True)


def options_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """Effective options: ``--quick`` shortens every default, explicit values win."""
    quick = bool(args.quick)
    names = list(dict.fromkeys(args.only)) if args.only else list(FLOOR_ITEMS if args.floors_only else QUICK_ITEMS if quick else ITEMS)
    return {
        "items": names,
        "quick": quick,
        "floors_only": bool(args.floors_only),
        "duration_s": args.duration if args.duration is not None else (3.0 if quick else 10.0),
        "iterations": args.iterations if args.iterations is not None else (100 if quick else 2000),
        "warmup": 10 if quick else 100,
        "rates": [list(r) for r in (args.rate or [])],
        "batch_period_s": args.batch_period,
        "floor_s": args.floor_seconds,
        "burners": args.burners,
        "rt_priority": args.rt_priority,
        "cpu_affinity": args.cpu_affinity,
        "rt_cpu_latency_us": args.rt_cpu_latency_us,
    }


def run_bench(options: dict[str, Any], log_dir: Path | None = None, say: Any = None) -> dict[str, Any]:
    """Run the chosen items and return the report (JSON-ready)."""
    log_dir = log_dir or Path(tempfile.mkdtemp(prefix="ralf-bench-"))
    ctx = BenchContext(
        quick=options["quick"],
        duration_s=options["duration_s"],
        iterations=options["iterations"],
        warmup=options["warmup"],
        log_dir=log_dir,
        floors_only=options["floors_only"],
        say=say or (lambda text: None),
        rates=tuple((float(r), None if sec is None else float(sec)) for r, sec in options.get("rates", [])),
        batch_period_s=options.get("batch_period_s", 0.2),
        floor_s=options.get("floor_s", 5.0),
        burners=options.get("burners", 0),
        rt_priority=options.get("rt_priority", 0),
        cpu_affinity=options.get("cpu_affinity", ""),
        rt_cpu_latency_us=options.get("rt_cpu_latency_us", -1),
    )
    report: dict[str, Any] = {"schema": SCHEMA, "machine": machine_info(), "options": {**options, "log_dir": str(log_dir)}, "items": {}}
    started = time.monotonic()
    try:
        for number, name in enumerate(options["items"], 1):
            ctx.say(f"bench {name}")
            with activity(f"bench item {name} ({number} of {len(options['items'])})"):
                report["items"][name] = run_item(name, ctx)
    except KeyboardInterrupt:
        for name in options["items"]:
            report["items"].setdefault(name, {"status": "interrupted", "measurements": {}, "config": {}, "notes": [], "errors": ["interrupted"], "skipped": []})
        report["interrupted"] = True
    report["machine"]["load_average_at_end"] = load_average()
    report["wall_s"] = round(time.monotonic() - started, 3)
    return report


# --- rendering ------------------------------------------------------------------------------------


def _us(value: float | None) -> str:
    if value is None or not math.isfinite(value):
        return "–"
    if value < 1000:
        return f"{value:.0f} µs"
    if value < 1e6:
        return f"{value / 1e3:.2f} ms"
    return f"{value / 1e6:.2f} s"


def _ratio(value: float | None) -> str:
    if value is None:
        return "–"
    return f"{value:.2f}×" if value >= 0.1 else f"{value:.2g}×"


def _scalar(value: Any, unit: str) -> str:
    if value is None:
        return "–"
    if unit == "us":
        return _us(float(value))
    if isinstance(value, int):
        return f"{value} {unit}"
    return f"{value:.3g} {unit}" if abs(value) < 1000 else f"{value:.0f} {unit}"


_STATUS = {"ok": "green", "partial": "yellow", "failed": "red", "skipped": "dim", "interrupted": "red"}


def render(report: dict[str, Any]) -> RenderableType:
    """The report as a table (every figure beside its floor and the ratio) and the items' problems below it."""
    mach = report["machine"]
    table = Table(
        title="ralf-hil bench",
        caption=f"{mach['cpu_model']}, {mach['cores']} cores, Python {mach['python']}, zenoh {mach['packages'].get('eclipse-zenoh')}, "
        f"python-can {mach['packages'].get('python-can')}, {mach['date']}, load {mach.get('load_average_at_start')} -> {mach.get('load_average_at_end')}",
    )
    columns: tuple[tuple[str, Literal["left", "right"]], ...] = (
        ("item", "left"),
        ("measurement", "left"),
        ("n", "right"),
        ("p50", "right"),
        ("p99", "right"),
        ("p99.9", "right"),
        ("max", "right"),
        ("floor", "left"),
        ("×p50", "right"),
        ("×p99", "right"),
    )
    for col, just in columns:
        table.add_column(col, justify=just, overflow="fold")
    problems: list[Text] = []
    notes: list[Text] = []
    for name, item in report["items"].items():
        status = Text(f"{name} ({item['status']})", style=_STATUS.get(item["status"], ""))
        first = True
        for mname, m in item["measurements"].items():
            label = status if first else ""
            first = False
            floor = m.get("floor") or ""
            if m["kind"] == "latency":
                r = m.get("ratio") or {}
                table.add_row(
                    label,
                    mname,
                    str(m.get("n", "")),
                    _us(m.get("p50_us")),
                    _us(m.get("p99_us")),
                    _us(m.get("p999_us")),
                    _us(m.get("max_us")),
                    floor,
                    _ratio(r.get("p50")),
                    _ratio(r.get("p99")),
                )
            else:
                value = _scalar(m.get("value"), m.get("unit", ""))
                if floor:
                    floor = f"{floor} = {_scalar(m.get('floor_value'), m.get('unit', ''))}"
                table.add_row(label, mname, "", value, "", "", "", floor, _ratio(m.get("ratio")), "")
        if first:
            table.add_row(status, Text("no measurement (see below)", style="dim"), "", "", "", "", "", "", "", "")
        table.add_section()
        problems += [Text(f"{name}: {e}", style="red") for e in item["errors"]]
        problems += [Text(f"{name}: skipped {s}", style="yellow") for s in item["skipped"]]
        notes += [Text(f"{name}: {n}", style="dim") for n in item["notes"]]
    return Group(table, *problems, *notes)


def write_json(report: dict[str, Any], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")


def cmd_bench(args: argparse.Namespace) -> int:
    options = options_from_args(args)
    report = run_bench(options, Path(args.log_dir) if args.log_dir else None, say=lambda text: console.print(text, markup=False, highlight=False))
    out = Console()
    out = Console(width=min(out.width, TABLE_WIDTH) if out.is_terminal else TABLE_WIDTH)
    out.print(render(report))
    if args.json:
        path = Path(args.json)
        write_json(report, path)
        console.print(f"results written to {path} (service logs in {report['options']['log_dir']})", markup=False, highlight=False)
    else:
        console.print(f"service logs in {report['options']['log_dir']}; --json PATH keeps the results", markup=False, highlight=False)
    if report.get("interrupted"):
        return 130
    return 1 if any(item["status"] == "failed" for item in report["items"].values()) else 0


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text!r}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return value


def _rate(text: str) -> tuple[float, float | None]:
    """``HZ`` or ``HZ:SECONDS`` (``--rate 1000:60``)."""
    rate, _, seconds = text.partition(":")
    try:
        r = float(rate)
        sec = float(seconds) if seconds else None
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected HZ or HZ:SECONDS, e.g. 1000:60") from None
    if not (math.isfinite(r) and 0 < r <= 5000) or (sec is not None and not (math.isfinite(sec) and sec > 0)):
        raise argparse.ArgumentTypeError(f"{text!r}: rate must be 0..5000 Hz and seconds positive")
    return r, sec


def _cpus(text: str) -> str:
    from service_kit.realtime import parse_cpus

    try:
        parse_cpus(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--only", nargs="+", action="extend", choices=list(ITEMS), metavar="NAME", help=f"run only these items: {', '.join(ITEMS)} (default: all)")
    p.add_argument(
        "--duration", type=_positive_float, default=None, metavar="S", help="seconds per real-time rate and per lockstep run (default 10, --quick 3)"
    )
    p.add_argument("--iterations", type=_positive_int, default=None, metavar="N", help="round trips per latency measurement (default 2000, --quick 100)")
    p.add_argument(
        "--quick",
        action="store_true",
        help="a smoke test, not a measurement to quote: the floors, one 200 Hz real-time rig, the co-simulation and the hot path, few iterations, short runs",
    )
    p.add_argument("--floors-only", action="store_true", help="only the bare transport floors (zenoh, UDP, udp_multicast); no service is started")
    rt = p.add_argument_group("realtime item (the acceptance runs: --rate 1000:60 --rate 200:600, then again with --burners 2)")
    rt.add_argument(
        "--rate",
        type=_rate,
        action="append",
        default=None,
        metavar="HZ[:S]",
        help="a real-time run at HZ for S seconds (default --duration); repeat for several (default: 200 and 1000 Hz)",
    )
    rt.add_argument(
        "--batch-period",
        type=_positive_float,
        default=0.2,
        metavar="S",
        help="batch size = S seconds of samples; above the DSP's 100 ms emulated latency leaves the deadline slack (default 0.2)",
    )
    rt.add_argument(
        "--floor-seconds", type=_positive_float, default=5.0, metavar="S", help="seconds of the sleep-only loop per rate, at most the run's (default 5)"
    )
    rt.add_argument(
        "--burners",
        type=int,
        choices=range(0, 17),
        default=0,
        metavar="N",
        help="N CPU-burning processes during the floors and the rig: a loaded host (default 0)",
    )
    rt.add_argument(
        "--rt-priority",
        type=int,
        choices=range(0, 100),
        default=0,
        metavar="P",
        help="RALF_REALTIME priority for the controller and plant: SCHED_FIFO where permitted (default 0: off)",
    )
    rt.add_argument(
        "--cpu-affinity", type=_cpus, default="", metavar="CPUS", help="RALF_REALTIME cpus for the controller and plant, e.g. 1 or 0-1 (default: not pinned)"
    )
    rt.add_argument(
        "--rt-cpu-latency-us",
        type=int,
        default=-1,
        metavar="US",
        help="RALF_REALTIME cpu_latency_us for the controller and plant, and the same for the sleep-only floor: "
        "a PM QoS bound on CPU wake-up latency (0: idle CPUs poll; default -1: off)",
    )
    p.add_argument("--json", default=None, metavar="PATH", help=f"write the results here as JSON (e.g. {DEFAULT_JSON}; default: none written)")
    p.add_argument("--log-dir", default=None, help="where helper and service logs go (default: a temporary directory)")


def register(subparsers: Any) -> None:
    """Add ``bench`` to ``ralf-hil``."""
    p = subparsers.add_parser(
        "bench",
        help="measure the rig's latencies and speeds beside their floors",
        description=__doc__.split("\n\n")[0].replace("``", "") + " Items: " + ", ".join(ITEMS) + ".",
    )
    add_arguments(p)
    p.set_defaults(func=cmd_bench)
