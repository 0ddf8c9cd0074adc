"""``ralf-hil timing-test SCENARIO``: run a rig under a scenario's link
faults and judge its timing against acceptance criteria.

The scenario file (:class:`service_kit.link_faults.Scenario`) names the
faults, the mode of the rig (:class:`workbench.hil.HilRig`) (``cosim``, ``lockstep``: the one-process rig on a
virtual CAN bus and an in-process zenoh session, or ``realtime``: the same
on the wall clock), the duration, settings per service and the criteria.
The report (:mod:`workbench.timing_test.report`): Markdown, JSON and PNG
histograms in ``--out``; exit code 0 if every criterion passes and the
run's verdict (:mod:`workbench.verdict`, in the report as ``run_verdict``)
is PASS or DEGRADED, 1 otherwise, 2 if the run could not be made. A
criterion judged over fewer batches (ticks) than could break it (its limit
plus one) fails: "too few to judge". The wake-up latency criteria are
the host's latency class (PREEMPT_RT): judged only with ``--strict`` (or a
limit given on the command line), otherwise reported.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

from service_kit.link_faults import Scenario, ScenarioError, load_scenario
from workbench.hil import HilRig, RigRunError, RigSettingError
from workbench.hostinfo import host_info
from workbench.progress import activity
from workbench.timing_test.report import Criteria, evaluate, verdict_failed, write_report
from workbench.verdict import judge

log = logging.getLogger(__name__)


def scenario_rig(scenario: Scenario, mode: str | None = None) -> HilRig:
    """The rig of ``scenario`` (cosim, or the one-process rig in lockstep/real time), its faults
    on the controller's links and the DSP board (``dsp_delay_s``); not recorded."""
    cfg = scenario.settings
    return HilRig(
        clock=mode or scenario.mode,  # type: ignore[arg-type]  # the scenario's mode is checked by its model
        controller=dict(cfg.get("controller", {})), plant_settings=dict(cfg.get("plant", {})), dsp_settings=dict(cfg.get("dsp", {})),
        faults=json.loads(scenario.model_dump_json()), mcap=False,
    )  # fmt: skip


def cmd_timing_test(args: argparse.Namespace) -> int:
    from workbench.output_paths import junit_clash

    clash = junit_clash(args.junit, args.out, "timing-test")
    if clash:
        print(f"ralf-hil timing-test: {clash}", file=sys.stderr)
        return 2
    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        print(f"ralf-hil timing-test: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    a = scenario.acceptance
    criteria = Criteria(
        wakeup_p99_us=args.wakeup_p99_us if args.wakeup_p99_us is not None else a.wakeup_p99_us,
        wakeup_p999_us=args.wakeup_p999_us if args.wakeup_p999_us is not None else a.wakeup_p999_us,
        max_consecutive_misses=args.max_consecutive_misses if args.max_consecutive_misses is not None else a.max_consecutive_misses,
        # Wake-up latency is the host's class (PREEMPT_RT or not): judged when asked for.
        strict=bool(args.strict or args.wakeup_p99_us is not None or args.wakeup_p999_us is not None),
    )
    if scenario.description:
        print(f"timing test {scenario.name}: {' '.join(scenario.description.split())}")
    host_before = host_info()
    try:
        rig = scenario_rig(scenario, args.mode)
        with activity(f"timing test {scenario.name}: the rig runs ({args.mode or scenario.mode}, {args.duration or scenario.duration_s:g} s simulated)"):
            with rig:
                run = rig.run(args.duration or scenario.duration_s)
    except (RigSettingError, RigRunError) as exc:
        print(f"ralf-hil timing-test: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    host_after = host_info()
    verdict = evaluate(rig.controller_service, criteria, mode=args.mode or scenario.mode)
    failed = [c["name"] for c in verdict["criteria"] if verdict_failed(str(c["verdict"]))]
    facts = {
        "controller": {"ticks": run.ticks},
        "health": {name: h.model_dump(exclude={"wall_time_s"}) for name, h in run.health.items()},
        "exit_codes": {},
        "failure": run.error or "",
        "log_warnings": dict(run.log_warnings),
        "log_errors": dict(run.log_errors),
    }
    run_verdict = judge(facts, "FAIL: " + ", ".join(failed) if failed else "PASS")
    out = Path(args.out)
    report = {
        "scenario": json.loads(scenario.model_dump_json()),
        "mode": args.mode or scenario.mode,
        "error": run.error,
        "ticks": run.ticks,
        "wall_time_s": run.wall_time_s,
        "host": {**host_before, "load_average_after": host_after["load_average"]},
        **verdict,
        "run_verdict": run_verdict.as_dict(),
    }
    paths = write_report(report, rig.controller_service, out)
    if args.junit:
        from workbench.junit import timing_suite, write_junit

        print(f"JUnit XML: {write_junit(args.junit, [timing_suite(report)])}")
    print(f"timing test {scenario.name}: {'PASS' if report['passed'] else 'FAIL'}; report {paths[0]}")
    for c in report["criteria"]:
        judged = f" over {c['judged']} {c['unit']}" if "judged" in c else ""
        print(f"  {c['name']}: {c['value']} (limit {c['limit']}{judged}) {c['verdict']}")
    print(f"run verdict: {run_verdict.line()}")
    return 0 if report["passed"] and run.error is None and run_verdict.exit_code == 0 else 1


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("timing-test", help="run a rig under a scenario's link faults and judge its timing (report: Markdown, JSON, PNG)")
    p.add_argument("scenario", help="scenario file (YAML or JSON), see docs/timing-faults.md")
    p.add_argument("--out", default="timing-report", help="report directory (default: timing-report)")
    p.add_argument("--mode", choices=["cosim", "lockstep", "realtime"], default=None, help="override the scenario's mode")
    p.add_argument("--duration", type=float, default=None, help="override the scenario's duration (simulated s)")
    p.add_argument(
        "--strict",
        action="store_true",
        help="also judge the wake-up latency against the scenario's limits (PREEMPT_RT class; by default it is reported, not judged)",
    )
    p.add_argument("--wakeup-p99-us", type=float, default=None, help="criterion: wake-up latency p99 (us; default 250; implies --strict)")
    p.add_argument("--wakeup-p999-us", type=float, default=None, help="criterion: wake-up latency p99.9 (us; default 1000; implies --strict)")
    p.add_argument("--max-consecutive-misses", type=int, default=None, help="criterion: longest run of consecutive deadline misses (default 1)")
    p.add_argument("--junit", default=None, metavar="FILE", help="also write the verdict as JUnit XML (one test case per criterion) for CI")
    p.set_defaults(func=cmd_timing_test)
