"""``ralf-hil``: the umbrella command (up, and the tools built on the rig)."""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from contextlib import nullcontext
from pathlib import Path
from typing import Any, NoReturn

from pydantic_settings import BaseSettings
from rich.console import Console
from rich.live import Live
from rich.table import Table
from rich.text import Text

from protocol.keys import validate_rig_id
from protocol.setting_hints import set_problem
from protocol.settings import ControllerSettings, DspSettings, PlantSettings, retired
from service_kit.private_files import LockHeld, RunLock, UnsafePath, keep, remove_stale_run_folders, run_folder, start_remover
from service_kit.runtime import stop_on_signals
from workbench import bench, campaign, experiments, measure_cli, memory_slope, monitor, timing_test
from workbench.cosim_guard import FAULT_FILE_VARIABLE
from workbench.extras import missing_extra
from workbench.fault_cli import add_fault_parser
from workbench.hostinfo import host_info, host_line
from workbench.launcher import START_ORDER, RigObserver, RigPlan, Supervision, plan_problems, supervise, tail
from workbench.live import cli as live_cli
from workbench.log_counts import count_log_files
from workbench.param_cli import add_param_parser
from workbench.plant_figures import cli as plant_cli
from workbench.progress import LONG_COMMANDS, ServiceLogWatch, activity, compiling_progress, controller_progress, heartbeat_unless_terminal, status_progress
from workbench.recording import cli as recording_cli
from workbench.recording.mf4_cli import is_mf4, record_mf4
from workbench.recording.tap import RigRecording
from workbench.rig_wire import RigWire, summary_rows, wire_request
from workbench.run_logs import RunLogs
from workbench.search import cli as search_cli
from workbench.timing_test.report import health_verdict, latency_class
from workbench.verdict import judge

console = Console(stderr=True)


SETTINGS_MODELS: dict[str, type[BaseSettings]] = {"dsp": DspSettings, "plant": PlantSettings, "controller": ControllerSettings}


def _parse_overrides(items: Sequence[str]) -> dict[str, dict[str, str]]:
    """``service.name=value`` (or ``name=value`` for every service that has
    that setting) -> environment per service. Unknown names are refused."""
    out: dict[str, dict[str, str]] = {"dsp": {}, "plant": {}, "controller": {}}
    for item in items:
        target, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"ralf-hil: --set {item!r}: expected [service.]NAME=VALUE")
        service, dot, name = target.rpartition(".")
        name = name.strip().lower().removeprefix("ralf_")
        if retired(name):  # a configuration error, as the services' own: exit 2
            print(f"ralf-hil: --set {item!r}: {retired(name)}", file=sys.stderr)
            raise SystemExit(2)
        if dot and service not in out:
            raise SystemExit(f"ralf-hil: --set {item!r}: unknown service {service!r} (dsp, plant, controller)")
        services = [service] if dot else [svc for svc, model in SETTINGS_MODELS.items() if name in model.model_fields]
        if problem := set_problem(item, None):  # as refused before the modules load (workbench/__main__.py)
            print(f"ralf-hil up: {problem}", file=sys.stderr)
            raise SystemExit(2)
        for svc in services:
            out[svc][f"RALF_{name.upper()}"] = value
    return out


FIRST_RUN_HINT_AFTER_S = 10.0
"""A start-up longer than this is said to be the first run's kernel compilation (later runs: 2-10 s)."""


def status_line(observer: RigObserver, elapsed: float, ended: bool = False) -> Text:
    """The live status; ``ended``: the last line, once the services were stopped as asked."""
    s = observer.status
    alive = "services stopped" if ended else " ".join(f"{name}:{'up' if observer.alive.get(name) else 'down'}" for name in START_ORDER)
    if s is None:
        slow = "  (a first run compiles the numba kernels once: ~30-60 s)" if elapsed > FIRST_RUN_HINT_AFTER_S else ""
        return Text(f"[{elapsed:6.1f} s] starting the services, waiting for the controller's first tick…  {alive}{slow}")
    freq = f"{s.latest_frequency_hz:.2f} Hz" if s.latest_frequency_hz else "–"
    return Text(
        f"[{elapsed:6.1f} s] sim {s.sim_time_s:8.2f} s | loop {s.loop_rate_hz:6.1f} Hz | batches {s.batches_sent} | "
        f"interrupts {s.interrupts} | f1 {freq} | misses {s.deadline_misses} | overruns {s.overruns} | {alive}"
    )


def summarize(observer: RigObserver, exit_codes: dict[str, int], elapsed: float) -> dict[str, Any]:
    s = observer.status
    summary: dict[str, Any] = {
        "wall_time_s": round(elapsed, 3),
        "exit_codes": exit_codes,
        "controller": s.model_dump(exclude={"wall_time_s"}) if s else None,
        "health": {name: h.model_dump(exclude={"wall_time_s"}) for name, h in observer.health.items()},
        "liveliness_events": observer.events,
        "undecodable_messages": observer.bad_messages,
        "health_refused": observer.health_refused,
        "host": host_info(),  # the machine the numbers were measured on (workbench/hostinfo.py)
    }
    return summary


WALL_CLOCK_LATENCIES = frozenset({"sync_interval", "sync_jitter", "sync_period_jitter", "sync_to_sample", "batch_to_interrupt", "interrupt_put"})
"""Latencies between events on the wall clock: nothing in a co-simulation,
whose events are stepped in one thread (its TET is the cost of a tick)."""


def config_changes_line(controller_health: dict[str, Any] | None) -> str | None:
    """The run-time commands the controller took (protocol/command_fields.py), for the summary: None if none."""
    counters = (controller_health or {}).get("counters", {})
    taken, knobs = counters.get("reconfigurations", 0), counters.get("test_knob_changes", 0)
    refused = counters.get("in_command_refused", 0) + counters.get("in_test_command_refused", 0)
    if not taken and not refused:
        return None
    return f"{taken} command(s) taken, {knobs} of them test knobs; {refused} refused (a field their key does not take)"


def print_summary(summary: dict[str, Any], verbose: bool = False) -> None:
    """The run's summary on stdout: only rows that mean something in the run's
    clock (no wall-clock rates or real-time measures in a co-simulation);
    the per-hop latencies (``hop_*``, docs/timing-faults.md) with ``verbose``."""
    cosim = summary.get("clock") == "cosim"
    table = Table(title="ralf-hil run summary", show_header=True)
    table.add_column("item")
    table.add_column("value", justify="right")
    table.add_row("wall time", f"{summary['wall_time_s']:.1f} s")
    if summary.get("startup_s") is not None and not cosim:
        table.add_row("start-up (launch to first tick)", f"{summary['startup_s']:.1f} s")
    if summary.get("control_wall_s") is not None and not cosim:
        table.add_row("control time (wall)", f"{summary['control_wall_s']:.1f} s")
    c = summary["controller"]
    if c:
        table.add_row("simulated time", f"{c['sim_time_s']:.2f} s")
        table.add_row("control ticks", str(c["ticks"]))
        if cosim:
            table.add_row("simulated / wall", f"{summary['sim_per_wall']}x real time" if summary.get("sim_per_wall") else "–")
        else:
            table.add_row("loop rate", f"{c['loop_rate_hz']:.1f} Hz")
        table.add_row("batches sent", str(c["batches_sent"]))
        table.add_row("interrupts", str(c["interrupts"]))
        f = c["latest_frequency_hz"]
        table.add_row("latest identified f1", f"{f:.3f} Hz" if f else "–")
        table.add_row("deadline misses", str(c["deadline_misses"]))
        lost = summary["health"].get("controller", {}).get("counters", {}).get("interrupts_lost")
        if lost is not None:
            table.add_row("interrupts lost", f"{lost} (never came; a miss is one not there by its deadline)")
        table.add_row("overruns", str(c["overruns"]))
    changed = config_changes_line(summary["health"].get("controller"))
    if changed:
        table.add_row("configuration changed under the run", changed)
    hops = 0
    for name, health in summary["health"].items():
        for lname, stats in health["latencies"].items():
            if cosim and lname in WALL_CLOCK_LATENCIES:
                continue
            if lname.startswith("hop_") and stats["count"] and not verbose:
                hops += 1
                continue
            if stats["count"]:
                table.add_row(
                    f"{name} {lname}",
                    f"p50 {stats['p50'] * 1e3:.2f} ms, p99 {stats['p99'] * 1e3:.2f} ms, max {stats['max'] * 1e3:.2f} ms (n={stats['count']})",
                )
    if hops:
        table.add_row("per-hop latencies", f"{hops} hop_* rows: --verbose (where a tick's or a batch's time goes, docs/timing-faults.md)")
    for name, health in summary["health"].items():
        counters = health.get("counters", {})
        if "rt_gc_frozen" in counters and not cosim:
            fifo = counters.get("rt_fifo_priority", 0)
            table.add_row(
                f"{name} real-time measures",
                f"{'SCHED_FIFO ' + str(fifo) if fifo else 'normal scheduler'}, "
                f"{str(counters.get('rt_pinned_cpus', 0)) + ' CPU(s) pinned' if counters.get('rt_pinned_cpus') else 'not pinned'}, "
                f"gc {'frozen' if counters['rt_gc_frozen'] else 'not frozen'}",
            )
    table.add_row("exit codes", ", ".join(f"{k}={v}" for k, v in summary["exit_codes"].items()))
    if summary.get("health_refused"):
        table.add_row("health refused", f"{summary['health_refused']} (the payload named another service than its key)")
    if summary.get("host"):
        table.add_row("host", host_line(summary["host"]).removeprefix("host: "))
    controller_health = summary["health"].get("controller")
    verdict = health_verdict(controller_health) if controller_health else None
    if verdict:
        table.add_row("timing verdict", verdict)
    latency = latency_class(controller_health, summary.get("host")) if controller_health else None
    if latency:
        table.add_row("host latency class", latency)
    if summary.get("log_warnings") is not None:
        errors = summary.get("log_errors") or {}
        table.add_row(
            "warning / error lines in the logs",
            ", ".join(f"{name} {n} / {errors.get(name, 0)}" for name, n in summary["log_warnings"].items()) or "no log counted",
        )
    run = summary.get("verdict")
    if run:
        for reason in run["reasons"]:
            table.add_row("what went wrong", reason)
        table.add_row("run verdict", f"{run['verdict']} (exit {run['exit_code']}; rule: docs/reliability.md#the-runs-verdict)")
    if summary.get("can_wire"):
        for item, value in summary_rows(summary["can_wire"]):
            table.add_row(item, value)
    if summary.get("recording"):
        r = summary["recording"]
        table.add_row(
            "recording", f"{r['path']}: {r['can_frames']} CAN frames, {r['messages']} messages, {r['dropped']} dropped, {r['undecodable']} undecodable"
        )
    if summary.get("live"):
        v = summary["live"]
        table.add_row(
            "live view",
            f"{v['url']}: {v['published']} sent, {v['decimated']} decimated, {v['handoff_dropped']} dropped before the view, {v['statuses']} statuses, "
            f"{v['clients_seen']} client(s), {v['slow_client_notices']} slow-client notice(s), {v['slow_clients_disconnected']} slow client(s) disconnected",
        )
    Console().print(table)  # the summary is the command's result: stdout


def add_verdict(summary: dict[str, Any]) -> None:
    """The run's verdict (:mod:`workbench.verdict`) into ``summary["verdict"]``, judged
    with the timing verdict of the table's "timing verdict" row."""
    controller_health = summary["health"].get("controller")
    summary["verdict"] = judge(summary, health_verdict(controller_health) if controller_health else None).as_dict()


STARTUP_ALLOWANCE_S = 120.0
"""``ralf-hil up``: a rig whose controller has not ticked this long after the launch has failed."""


def acquire_rig_lock(rig_id: str, directory: str | None = None) -> RunLock:
    """Hold this host's lock of ``rig_id`` (service_kit/private_files.py) until
    the returned lock is released (its file is removed then): a second
    ``ralf-hil up`` of the same rig id would share its CAN port and zenoh keys,
    so it is refused (exit 2), as is a lock path that is not a regular file of
    this user (a planted symlink, FIFO or folder), which is left untouched."""
    try:
        return RunLock.acquire(rig_id, directory)
    except LockHeld as exc:
        console.print(f"[red]ralf-hil up: rig {rig_id!r} is already running on this host ({exc}); stop it or choose another --rig-id[/red]")
    except UnsafePath as exc:
        console.print(f"[red]ralf-hil up: {exc}[/red]", highlight=False, soft_wrap=True)
    raise SystemExit(2)


def provision_access(plan: RigPlan, directory: Path, scenarios: bool = False, run_s: float | None = None) -> Path:
    """This run's credentials (service_kit/access.py): its own certificate
    authority with one certificate per role, so every link of the rig is
    mutual TLS and each node knows the role of every session it links to,
    whichever end opened the link; and a password per role, which binds a
    zenoh id to the role that first linked with it (zenoh refuses a second
    link for a linked id under another user name, not under another
    certificate). Every node applies the rig's access rules. Writes the
    certificates, the credentials file (keys and passwords owner-only) and
    ``tool.env``, the variables that let ``ralf-hil reconfigure``/``monitor``/
    ``live``/``record`` join the run; returns its path. ``run_s``: the
    run's planned wall time, which the certificates cover
    (:func:`workbench.certificates.validity_for`)."""
    from service_kit.access import ROLES, generate_credentials, role_env, write_credentials_file
    from workbench.certificates import validity_for, write_role_certificates

    roles = [r for r in ROLES if r != "tester" or scenarios]
    certificates = write_role_certificates(directory, roles, valid_for=validity_for(run_s))
    credentials = generate_credentials(roles)
    path = write_credentials_file(directory / "zenoh-credentials.txt", credentials)
    plan.common_env.update(RALF_ZENOH_CREDENTIALS_FILE=str(path), RALF_ZENOH_ACL="scenarios" if scenarios else "on")
    plan.use_tls({role: {**files.env(), **role_env(role, credentials)} for role, files in certificates.items()})
    for role in ("tool", "tester") if scenarios else ("tool",):  # tester.env: ralf-hil fault, where scenarios are on
        fd = os.open(directory / f"{role}.env", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as fh:
            variables = {
                **certificates[role].env(),
                **role_env(role, credentials),
                "RALF_ZENOH_CONNECT": plan.zenoh_endpoint,
                "RALF_CAN_PORT": str(plan.can_port),  # ralf-hil record and live tap the bus too
                **{k: plan.common_env[k] for k in ("RALF_CAN_INTERFACE", "RALF_CAN_CHANNEL") if plan.common_env.get("RALF_CAN_INTERFACE") == "ralfhub"},
                "RALF_RIG_ID": plan.rig_id,
            }
            fh.writelines(f"{k}={v}\n" for k, v in variables.items())
    return directory / "tool.env"


def shorter_duration(given: str | None, duration_s: float) -> str:
    """``controller.duration_s`` for a lockstep run of ``--duration`` simulated
    seconds: the shorter of the two when both are given (a value that is not
    a number is kept, for the settings check to name it)."""
    if given is None:
        return str(duration_s)
    try:
        return str(min(float(given), duration_s))
    except ValueError:
        return given


def refuse_bad_settings(overrides: dict[str, dict[str, str]], command: str = "ralf-hil up") -> None:
    """Every service's settings as it will read them (its ``RALF_*``
    variables and the ``--set`` values for it), validated before anything
    starts: a bad value is one line on stderr naming it, and exit 2."""
    from protocol.errors import ConfigError
    from protocol.settings import load_settings

    for service, env in overrides.items():
        saved = {name: os.environ.get(name) for name in env}
        os.environ.update(env)
        try:
            load_settings(SETTINGS_MODELS[service])  # type: ignore[arg-type]
        except ConfigError as exc:
            lines = [line.strip() for line in str(exc).splitlines()[1:]] or [str(exc)]
            print(f"{command}: the {service}'s settings: {'; '.join(lines)}", file=sys.stderr)
            raise SystemExit(2) from None
        finally:
            for name, value in saved.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value


def refuse_bad_plant_model(overrides: dict[str, dict[str, str]]) -> None:
    """An FMU plant (``plant.model=fmu:PATH``) is checked before anything
    starts (:func:`plant_emulator.fmu.preflight`: file, FMI version and
    kind, the mapping's variables, one step of the sample period on a
    throw-away instance, in a child process); a bad one, or one that
    crashes, is one line on stderr and exit 2."""
    plant = {k.removeprefix("RALF_").lower(): v for k, v in overrides.get("plant", {}).items()}
    if not str(plant.get("model", os.environ.get("RALF_MODEL", "ralf"))).startswith("fmu:"):
        return
    if os.environ.get(FAULT_FILE_VARIABLE):  # a guarded co-simulation: its parent checked the FMU already
        return
    from plant_emulator.fmu.isolated_check import preflight_isolated
    from protocol.errors import ConfigError
    from protocol.settings import load_settings

    try:
        load_settings(PlantSettings, plant)  # a bad setting named here, before a process is started for the check
        preflight_isolated(plant)  # in a process of its own: an FMU crashing in its first step does not end ralf-hil
    except ConfigError as exc:
        print(f"ralf-hil up: plant refused: {' '.join(str(exc).split())}", file=sys.stderr)
        raise SystemExit(2) from None


def refuse_clashing_outputs(args: argparse.Namespace, overrides: dict[str, dict[str, str]]) -> None:
    """Two outputs of the run naming one file (records, recording, CAN log,
    JSON summary, logs: :func:`workbench.output_paths.output_clashes`) are
    refused before anything starts, in every clock: one line each, exit 2."""
    from workbench.output_paths import output_clashes

    clashes = output_clashes(overrides, clock=args.clock, json=args.json, record=args.record, can_log=args.can_log, log_dir=args.log_dir)
    if clashes:
        for line in clashes:
            print(f"ralf-hil up: {line}", file=sys.stderr)
        raise SystemExit(2)


INTERRUPTED = 130
"""``ralf-hil up``'s exit code when Ctrl-C (SIGINT), SIGTERM or a closed terminal ended it."""


def refuse_unwritable_outputs(args: argparse.Namespace) -> None:
    """``--json``, ``--record`` and ``--can-log`` under a path this user cannot write in, and a
    ``--log-dir`` that cannot be a folder, are one line and exit 2 before the run, not an
    error after it."""
    for option, value in (("--json", args.json), ("--record", args.record), ("--can-log", args.can_log)):
        if value:
            folder = next(p for p in Path(value).absolute().parents if p.exists())  # the folders below it are made
            if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
                raise SystemExit(f"ralf-hil up: {option} {value}: {folder} is not a folder this user can write in")
    if args.log_dir and Path(args.log_dir).exists() and not Path(args.log_dir).is_dir():
        raise SystemExit(f"ralf-hil up: --log-dir {args.log_dir}: not a folder")


def cmd_up(args: argparse.Namespace) -> int:
    try:
        validate_rig_id(args.rig_id)
    except ValueError as exc:
        raise SystemExit(f"ralf-hil up: {exc}") from None
    if args.duration is not None and not args.duration > 0:
        raise SystemExit(f"ralf-hil up: --duration must be a positive number of seconds, got {args.duration}")
    overrides = _parse_overrides(args.set)
    if args.duration is not None and args.clock == "lockstep":
        # Simulated seconds in every clock: a lockstep controller stops itself after them
        # (with controller.duration_s too, both simulated seconds: the shorter ends the run).
        overrides["controller"]["RALF_DURATION_S"] = shorter_duration(overrides["controller"].get("RALF_DURATION_S"), args.duration)
    refuse_clashing_outputs(args, overrides)
    args.wire = wire_request(args.can_bitrate, args.restbus, overrides, args.clock)  # bad input: one line, before any process
    refuse_bad_plant_model(overrides)
    refuse_unwritable_outputs(args)
    if args.live and args.clock == "cosim":
        raise SystemExit("ralf-hil up: --live serves a running rig (--clock realtime or lockstep); record a co-simulation with --record and open the file")
    if is_mf4(args.record):  # recorded as MCAP, then exported (workbench/recording/mf4_cli.py)
        return record_mf4(lambda a: _up_checked(a, overrides), args)
    return _up_checked(args, overrides)


def _up_checked(args: argparse.Namespace, overrides: dict[str, dict[str, str]]) -> int:
    if args.clock == "cosim":
        return _up_cosim(args, overrides)
    lock = acquire_rig_lock(args.rig_id)
    try:
        return _up_locked(args, overrides)
    finally:
        lock.release()


def _up_locked(args: argparse.Namespace, overrides: dict[str, dict[str, str]]) -> int:
    plan = RigPlan.local(rig_id=args.rig_id, clock=args.clock, overrides=overrides, common={"RALF_CAN_PORT": str(args.can_port)} if args.can_port else None)
    problems = plan_problems(plan)
    if problems:
        for line in problems:
            console.print(f"[red]ralf-hil up: {line}[/red]", highlight=False, soft_wrap=True)
        return 2
    refuse_bad_settings(overrides)  # before the logs and any service
    params = str(plan.service_env.get("controller", {}).get("RALF_PARAM_COMMANDS", "")).strip().lower() in ("1", "true", "yes", "on")
    live_view = _start_live(args, params)  # before anything is created: a port in use is one line, the rig untouched
    access_dir = private_run_dir(f"ralf-{args.rig_id}-access-")  # may refuse (exit 2): before the logs, so a refusal leaves none
    try:
        logs = RunLogs.create(args.log_dir, args.rig_id, keep=args.keep_logs)
    except OSError as exc:
        if live_view is not None:
            live_view.close()
        shutil.rmtree(access_dir, ignore_errors=True)
        raise SystemExit(f"ralf-hil up: --log-dir {args.log_dir}: {exc.strerror or exc}") from None
    code = 1  # an exception on the way: the logs stay
    try:
        try:
            start_remover(access_dir)  # removes it if this process is killed (SIGKILL) before the finally below
        except (OSError, subprocess.SubprocessError) as exc:
            console.print(f"ralf-hil up: no remover for the run's credentials ({exc}): a SIGKILL of up leaves {access_dir}", highlight=False, soft_wrap=True)
        from workbench.certificates import planned_run_s

        run_s = planned_run_s(args.duration, args.clock, plan.service_env.get("controller", {}).get("RALF_DURATION_S"))
        wire = getattr(args, "wire", None)
        rig_wire = None
        if wire is not None:  # the arbiter's socket in the run's private folder; every node pointed at it
            rig_wire = RigWire(wire, access_dir, logs.path, plan)
        tool_env = provision_access(plan, access_dir, scenarios=args.scenarios, run_s=run_s)  # credentials of this run, valid for all of it; access rules on
        code = _up_supervised(args, plan, logs.path, tool_env, live_view, rig_wire)
        return code
    finally:
        if live_view is not None:
            live_view.close()
        where = logs.finish(code)  # a temporary folder of a run that went well is removed
        if where:
            console.print(where, highlight=False, soft_wrap=True)
        if args.keep_credentials:
            keep(access_dir)
            console.print(f"the run's credentials are kept in {access_dir} (owner-only)")
        else:
            shutil.rmtree(access_dir, ignore_errors=True)


def private_run_dir(prefix: str) -> Path:
    """A fresh folder only its owner may enter (0700), for a run's credentials,
    in this user's private runtime folder; the folders of launchers that ended
    without removing theirs (SIGKILL) are removed first."""
    try:
        remove_stale_run_folders()
        return run_folder(prefix)
    except UnsafePath as exc:
        console.print(f"[red]ralf-hil up: {exc}[/red]", highlight=False, soft_wrap=True)
        raise SystemExit(2) from None


def _up_supervised(args: argparse.Namespace, plan: RigPlan, log_dir: Path, tool_env: Path, live_view: Any, rig_wire: RigWire | None = None) -> int:
    # A closed terminal too: services stopped, credentials removed.
    stop, received = stop_on_signals((signal.SIGINT, signal.SIGTERM, signal.SIGHUP), say=False)
    observer = RigObserver(plan)
    panel_session = None
    if live_view is not None and live_view.params is not None:  # the panel's changes go out as the tool's (the launcher only observes)
        from workbench.live.params import tool_session

        try:
            panel_session = live_view.params.session = tool_session(tool_env)
        except Exception as exc:  # noqa: BLE001 - the view goes on without its panel, said in one line
            console.print(f"live view: no parameter panel ({' '.join(str(exc).split())})", highlight=False, soft_wrap=True)
    live = Live(status_line(observer, 0.0), console=console, refresh_per_second=4, transient=not console.is_terminal)
    said_ready = False
    startup = None if console.is_terminal else ServiceLogWatch({name: log_dir / f"{name}.log" for name in START_ORDER})  # a log sees the start-up

    def on_poll(sup: Supervision, _status: object) -> None:
        nonlocal said_ready
        for event in startup.events() if startup is not None else ():  # a service's ready line can follow the first tick
            live.console.print(event, highlight=False, soft_wrap=True)
        if sup.ready_at is not None and not said_ready:
            said_ready = True
            live.console.print(f"start-up: all services ready after {sup.startup_s:.1f} s; control starts (--duration counts from here)", soft_wrap=True)
        live.update(status_line(observer, time.monotonic() - sup.started))
        wire_figures()

    def wire_figures() -> None:
        """The arbiter's newest period figures (workbench/rig_wire.py) into the recording and the live view."""
        figures = rig_wire.poll_live() if rig_wire is not None and recording is not None else None
        if figures is not None and recording is not None:
            from workbench.recording.schemas import CAN_BUS_LOAD_SCHEMA, CAN_BUS_LOAD_TOPIC

            recording.recorder.on_record(CAN_BUS_LOAD_TOPIC, CAN_BUS_LOAD_SCHEMA, figures)

    def progress() -> str:
        up = [name for name in START_ORDER if observer.alive.get(name)]
        return status_progress(observer.status, waiting=f"starting the services (up: {', '.join(up) or 'none yet'}), waiting for the controller's first tick")

    recording: RigRecording | None = None
    wire_stats: dict[str, Any] | None = None
    try:
        if rig_wire is not None:  # before the tap and the services: they connect to it
            from service_kit.can_wire.hub import HubError

            try:
                rig_wire.start()
            except HubError as exc:
                console.print(f"[red]ralf-hil up: the CAN wire: {exc}[/red]", highlight=False, soft_wrap=True)
                return 2
        if args.record or live_view is not None:  # the tap starts before the services, so it holds their start-up
            recording = RigRecording(plan, args.record, observer.session, can_log=args.can_log, clock=args.clock, mirror=live_view)
        # Before any service starts (their Python start-up takes a second or more), so a bus
        # logger started on this line, or on a --can-port chosen beforehand, sees every frame.
        can_line = (
            f"CAN wire at {rig_wire.request.bitrate} bit/s (ralfhub {rig_wire.socket_path})"
            if rig_wire is not None
            else f"CAN udp_multicast port {plan.can_port}"
        )
        print(f"rig {plan.rig_id!r}: {can_line}, zenoh {plan.zenoh_endpoint}, logs in {log_dir}, tools' credentials in {tool_env}", flush=True)
        with live, activity(progress):
            sup = supervise(
                plan,
                log_dir,
                lambda: observer.status,
                run_for_s=args.duration if args.clock == "realtime" else None,
                startup_timeout_s=STARTUP_ALLOWANCE_S,
                stop=stop,
                on_poll=on_poll,
                poll_s=0.25,
            )
        if not console.is_terminal:
            console.print(status_line(observer, time.monotonic() - sup.started, ended=True))
        if not received:
            time.sleep(0.2)  # let the last health messages arrive
        summary = summarize(observer, sup.exit_codes, time.monotonic() - sup.started)
        if recording is not None:
            wire_figures()  # the last period the arbiter published
            stats = recording.close().as_dict()
            if args.record:
                summary["recording"] = {"path": args.record, **stats}
            if live_view is not None:  # the view's records came through the same bounded queue
                live_view.stats.handoff_dropped, live_view.stats.can_socket_drops = stats["dropped"], stats["can_socket_drops"]
            recording = None
        if live_view is not None:
            summary["live"] = {"url": live_view.url, **live_view.close().as_dict()}
        if rig_wire is not None:
            wire_stats = rig_wire.stop()
            summary["can_wire"] = wire_stats
    finally:
        if recording is not None:  # an error on the way: the file is still closed
            recording.close()
        if rig_wire is not None and wire_stats is None:
            rig_wire.stop()
        if live_view is not None:
            live_view.close()
        if panel_session is not None:
            panel_session.close()
        observer.close()
    summary["startup_s"] = None if sup.startup_s is None else round(sup.startup_s, 3)
    summary["control_wall_s"] = round(sup.control_s, 3)
    failure = sup.failure
    status = summary["controller"]
    if not failure and not received and (status is None or status["ticks"] == 0):
        failure = "the controller made no progress (0 control ticks)"
    summary["failure"] = failure
    summary["log_warnings"], summary["log_errors"] = count_log_files({name: p.log_path for name, p in sup.procs.items()})
    add_verdict(summary)
    print_summary(summary, verbose=args.verbose)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(summary, indent=2))
    if received:
        console.print(f"interrupted ({received[0]}) {sup.ended_at - sup.started:.1f} s after the launch: every service stopped")
        return INTERRUPTED
    if failure:
        console.print(f"[red]rig failed: {failure}[/red]")
    bad = {k: v for k, v in sup.exit_codes.items() if v != 0}
    for name in bad:
        console.print(f"[red]{name} exited with {bad[name]}; last log lines:[/red]\n{tail(sup.procs[name].log_path)}")
    return max(1 if (failure or bad) else 0, int(summary["verdict"]["exit_code"]))


def _start_live(args: argparse.Namespace, params: bool = False) -> Any:
    """``--live [HOST:]PORT``: the live view's server (:mod:`workbench.live.view`), or None;
    ``params`` (the controller's ``param_commands``): with its parameter panel (docs/calibration.md)."""
    if not args.live:
        return None
    from workbench.live.params import ParamPanel
    from workbench.live.view import LiveView, LiveViewError, parse_address
    from workbench.recording.schemas import CAN_BUS_LOAD_SCHEMA, CAN_BUS_LOAD_TOPIC, rig_topics

    topics = rig_topics(args.rig_id)
    if getattr(args, "wire", None) is not None:  # the arbiter's figures (workbench/rig_wire.py)
        topics.append((CAN_BUS_LOAD_TOPIC, CAN_BUS_LOAD_SCHEMA))
    try:
        host, port = parse_address(args.live)
        panel = ParamPanel(args.rig_id) if params else None  # its session: the observer's, once it is open
        live = LiveView(host, port, rate_hz=args.live_rate, topics=topics, params=panel)
    except LiveViewError as exc:
        raise SystemExit(f"ralf-hil up: {exc}") from None
    console.print(f"live view: {live.url} (Foxglove: Open connection -> Foxglove WebSocket; layout docs/foxglove-layout.json), {args.live_rate:g} Hz per topic")
    return live


def _up_cosim(args: argparse.Namespace, overrides: dict[str, dict[str, str]]) -> int:
    """``ralf-hil up --clock cosim``: the three boards co-simulated in this
    process (:class:`workbench.hil.HilRig`, one thread); ``--duration`` is simulated time."""
    with activity("loading the co-simulation's modules"):
        from service_kit import crash_report
        from service_kit.readiness import watch_compiles
        from workbench.cosim import logging_to
        from workbench.cosim_guard import guarded_child_faults, run_guarded
        from workbench.hil import HilRig, RigRunError, RigSettingError
        from workbench.output_paths import COSIM_LOG

    faults = guarded_child_faults()
    model = str({k.removeprefix("RALF_").lower(): v for k, v in overrides.get("plant", {}).items()}.get("model", os.environ.get("RALF_MODEL", "ralf")))
    if model.startswith("fmu:") and faults is None and getattr(args, "argv", None) is not None:
        return run_guarded(args.argv, model.removeprefix("fmu:"))  # an FMU crashing mid-run ends the child, told in one line
    crash_report.enable(faults)  # in the guarded child: its frames (the FMI call) for the parent's line
    own = {svc: {k.removeprefix("RALF_").lower(): v for k, v in env.items()} for svc, env in overrides.items()}
    if args.duration is not None and "duration_s" not in own["controller"]:
        own["controller"]["duration_s"] = str(args.duration)
    started = time.monotonic()
    console.print("co-simulating plant, controller and DSP in one thread (no processes, no network)")
    if args.can_log and not args.record:
        console.print("[red]ralf-hil up: --can-log goes with --record[/red]")
        return 2
    running: list[Any] = []  # the controller, once built: the progress line reads it

    def progress() -> str:
        return controller_progress(running[0]) if running else (compiling_progress() or "building the plant, controller and DSP")

    watch_compiles()
    try:
        rig = HilRig(
            clock="cosim", controller=own["controller"], plant_settings=own["plant"], dsp_settings=own["dsp"], rig_id=args.rig_id,
            mcap=args.record or False, can_log=args.can_log, meta={"argv": sys.argv} if args.record else {}, on_start=running.append,
        )  # fmt: skip
        with logging_to(Path(args.log_dir) / COSIM_LOG if args.log_dir else None), activity(progress):
            rec = rig.run()
    except (RigSettingError, RigRunError) as exc:
        console.print(f"[red]ralf-hil up: {exc}[/red]")
        return 2
    except OSError as exc:  # an output that cannot be written (checked before, but a file system can still refuse)
        console.print(f"[red]ralf-hil up: {exc.filename or ''}: {exc.strerror or exc}[/red]", highlight=False, soft_wrap=True)
        return 2
    wall = time.monotonic() - started
    summary: dict[str, Any] = {
        "wall_time_s": round(wall, 3),
        "exit_codes": {"controller": 0 if rec.error is None else 3},
        "controller": rec.status.model_dump(exclude={"wall_time_s"}) if rec.status else None,
        "health": {name: h.model_dump(exclude={"wall_time_s"}) for name, h in rec.health.items()},
        "liveliness_events": [],
        "undecodable_messages": 0,
        "startup_s": 0.0,
        "control_wall_s": round(wall, 3),
        "sim_per_wall": round(rec.sim_time_s / wall, 3) if wall > 0 else None,
        "clock": "cosim",
        "host": host_info(),
        "failure": rec.error or ("" if rec.ticks else "the controller made no progress (0 control ticks)"),
        "log_warnings": {name: rec.log_warnings.get(name, 0) for name in ("controller", "plant", "dsp", "rig") if name in rec.log_warnings or name != "rig"},
        "log_errors": {name: rec.log_errors.get(name, 0) for name in ("controller", "plant", "dsp", "rig") if name in rec.log_errors or name != "rig"},
    }
    console.print(f"co-simulated {rec.sim_time_s:.2f} s in {wall:.2f} s wall: {summary['sim_per_wall']}x real time")
    if args.record:
        summary["recording"] = {"path": args.record, "can_log": args.can_log, **(rec.recording_counts or {})}
        console.print(f"recorded into {args.record}" + (f" (CAN also in {args.can_log})" if args.can_log else ""))
    if rec.can_bus is not None:
        b = summary["can_bus"] = rec.can_bus
        console.print(
            f"CAN wire {b['bitrate'] // 1000} kbit/s: busy {b['busy_mean_pct']:.1f} % (max {b['busy_max_pct']:.1f} % per 100 ms), "
            f"{b['frames_per_s']:.0f} frames/s, SYNC->RPDO1 p50 {b['sync_to_rpdo1_us']['p50']} us, {b['late_tpdo1']} late TPDO1",
            highlight=False,
        )
    add_verdict(summary)
    print_summary(summary, verbose=args.verbose)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(summary, indent=2))
    if rec.error or rec.ticks == 0:
        console.print(f"[red]rig failed: {rec.error or 'the controller made no progress (0 control ticks)'}[/red]")
        return 1
    return int(summary["verdict"]["exit_code"])


def positive_seconds(text: str) -> float:
    """argparse type: a finite number of seconds above zero."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if math.isnan(value):
        raise argparse.ArgumentTypeError("NaN (not a number) is not a duration")
    if not 0 < value <= 1e7:
        raise argparse.ArgumentTypeError(f"{text} s: give a duration above 0 and at most 1e7 s")
    return value


def wait_for_ack(session: Any, keys: Any, change: Any, timeout_s: float) -> Any:
    """Send ``change`` to the controller and wait for the DSP's
    :class:`~protocol.messages.ConfigAck` carrying its ``request_id``; None if
    nothing answers within ``timeout_s``."""
    from protocol.errors import ProtocolError
    from protocol.messages import ConfigAck, decode, encode
    from service_kit.encodings import JSON

    got: list[Any] = []
    answered = threading.Event()

    def on_ack(sample: Any) -> None:
        try:
            ack = decode(ConfigAck, sample.payload.to_bytes())
        except ProtocolError:
            return
        if ack.request_id == change.request_id:
            got.append(ack)
            answered.set()

    sub = session.declare_subscriber(keys.dsp_config_ack, on_ack)
    try:
        deadline = time.monotonic() + timeout_s
        # Resend until answered: the tool's session may take a moment to find
        # the controller, and a command nobody received is not an error yet.
        while not answered.is_set() and time.monotonic() < deadline:
            session.put(keys.controller_command, encode(change), encoding=JSON)
            answered.wait(min(0.5, max(0.0, deadline - time.monotonic())))
    finally:
        sub.undeclare()
    return got[0] if got else None


def cmd_reconfigure(args: argparse.Namespace) -> int:
    """Send a run-time configuration change to a running controller, which
    applies the batch size and forwards the rest to the DSP; succeed only
    when the DSP acknowledges it."""
    import uuid

    from pydantic import ValidationError

    from protocol.errors import ConfigError
    from protocol.keys import Keys
    from protocol.messages import ConfigChange
    from protocol.settings import CommonSettings, load_settings
    from service_kit.transport import open_zenoh

    try:
        change = ConfigChange(seq=0, sim_time_s=0.0, fft_width=args.fft_width, batch_size=args.batch_size, alpha=args.alpha, request_id=uuid.uuid4().hex)
    except ValidationError as exc:
        problems = "; ".join(
            ("--" + str(e["loc"][0]).replace("_", "-") + ": " if e["loc"] else "") + str(e["msg"]).removeprefix("Value error, ") for e in exc.errors()
        )
        print(f"ralf-hil reconfigure: {problems}", file=sys.stderr)
        return 2
    if change.fft_width is None and change.batch_size is None and change.alpha is None:
        console.print("[red]ralf-hil reconfigure: give --fft-width, --batch-size or --alpha[/red]")
        return 2
    overrides = {"rig_id": args.rig_id} if args.rig_id is not None else {}
    if args.connect:
        overrides["zenoh_connect"] = args.connect
    try:
        settings = load_settings(CommonSettings, overrides)
    except ConfigError as exc:
        console.print(f"[red]{exc}[/red]")
        return 2
    try:
        session = open_zenoh(settings, retry_for_s=0.0)
    except ConfigError as exc:
        console.print(f"[red]ralf-hil reconfigure: {exc}[/red]")
        return 2
    wanted = change.model_dump(include={"fft_width", "batch_size", "alpha"}, exclude_none=True)
    try:
        ack = wait_for_ack(session, Keys(settings.rig_id), change, args.timeout)
    finally:
        session.close()
    if ack is None:
        console.print(
            f"[red]ralf-hil reconfigure: no acknowledgement from the DSP of rig {settings.rig_id!r} within {args.timeout:g} s "
            f"(is the rig running, and is {args.connect or 'its endpoint'} the one `ralf-hil up` printed?){monitor.credentials_hint(settings)}; {wanted} not applied[/red]"
        )
        return 1
    if not ack.accepted:
        console.print(f"[red]ralf-hil reconfigure: the DSP refused {wanted}: {ack.reason}[/red]")
        return 1
    console.print(f"applied on rig {settings.rig_id!r}: {wanted}; the DSP now runs N={ack.fft_width}, l={ack.batch_size}, alpha={ack.alpha:g}")
    return 0


COMPOSE_PASSWORD_VARS = {
    "controller": "ZENOH_PASSWORD_CONTROLLER",
    "dsp": "ZENOH_PASSWORD_DSP",
    "plant": "ZENOH_PASSWORD_PLANT",
    "tool": "ZENOH_PASSWORD_TOOL",
    "tester": "ZENOH_PASSWORD_TESTER",
}
"""The variables docker-compose.yml takes the services' passwords from (not
``RALF_*``: they are compose's, never a service's)."""


COMPOSE_ROUTER_HOSTS: tuple[str, ...] = ("zenoh-router", "localhost", "127.0.0.1", "::1")
"""The names the compose router's certificate is valid for: its service name on
the compose networks and the host's loopback (its published port 7447)."""


def _b64(path: Path) -> str:
    import base64

    return base64.b64encode(path.read_bytes()).decode("ascii")


def _replace(path: Path) -> Path:
    """``path``, its previous file or link removed (credentials are made fresh
    each time, never merged with older ones); a folder there is an error."""
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.exists():
        raise ValueError(f"{path} is in the way (not a regular file)")
    return path


def write_compose_access(
    out: Path,
    rig_id: str = "default",
    scenarios: bool = False,
    mounted_at: str = "/etc/ralf",
    run_s: float | None = None,
    router_hosts: tuple[str, ...] = (),
) -> dict[str, Path]:
    """Credentials for the distributed rig, mutual TLS as in a local rig: a
    fresh authority (its key forgotten) with the router's certificate (valid
    for :data:`COMPOSE_ROUTER_HOSTS` and ``router_hosts``) and one per role;
    the router's configuration (TLS on its one endpoint, every client
    proven by its certificate and its password, the rig's access rules by
    certificate), its credentials file, ``ralf.env`` for ``docker compose
    --env-file`` (each service's password, certificate and key as base64,
    the authority's certificate) and ``tool.env`` for tools on the host.
    ``run_s``: the planned run's wall time, which the certificates cover
    (:func:`workbench.certificates.validity_for`). Every file owner-only."""
    from protocol.keys import Keys
    from service_kit.access import generate_credentials, router_config, write_credentials_file
    from workbench.certificates import CA_FILE, validity_for, write_role_certificates

    roles = list(COMPOSE_PASSWORD_VARS)
    out.mkdir(mode=0o700, parents=True, exist_ok=True)
    for name in (
        CA_FILE,
        *(f"{r}.{ext}" for r in ("router", *roles) for ext in ("pem", "key")),
        "zenoh-credentials.txt",
        "zenoh-router.json5",
        "ralf.env",
        "tool.env",
    ):
        _replace(out / name)
    hosts = tuple(dict.fromkeys((*COMPOSE_ROUTER_HOSTS, *router_hosts)))
    certificates = write_role_certificates(out, ["router", *roles], hosts=(), valid_for=validity_for(run_s), hosts_of={"router": hosts})
    credentials = generate_credentials()
    creds = write_credentials_file(out / "zenoh-credentials.txt", credentials)
    router = out / "zenoh-router.json5"
    tls = (f"{mounted_at}/{CA_FILE}", f"{mounted_at}/router.pem", f"{mounted_at}/router.key")
    config = router_config(Keys(rig_id), f"{mounted_at}/zenoh-credentials.txt", scenarios=scenarios, tls=tls)
    fd = os.open(router, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(json.dumps(config, indent=2) + "\n")
    env = out / "ralf.env"
    fd = os.open(env, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(f"ZENOH_TLS_CA={_b64(certificates['router'].ca)}\n")
        for role, var in COMPOSE_PASSWORD_VARS.items():
            suffix = var.removeprefix("ZENOH_PASSWORD_")
            fh.write(f"{var}={credentials[role]}\n")
            fh.write(f"ZENOH_TLS_CERTIFICATE_{suffix}={_b64(certificates[role].certificate)}\n")
            fh.write(f"ZENOH_TLS_KEY_{suffix}={_b64(certificates[role].key)}\n")
    tool = out / "tool.env"
    fd = os.open(tool, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as fh:
        variables = {
            "RALF_RIG_ID": rig_id,
            "RALF_ZENOH_MODE": "client",
            "RALF_ZENOH_CONNECT": "tls/127.0.0.1:7447",
            **{k: str(Path(v).resolve()) for k, v in certificates["tool"].env().items()},
            "RALF_ZENOH_USER": "tool",
            "RALF_ZENOH_PASSWORD": credentials["tool"],
        }
        fh.writelines(f"{k}={v}\n" for k, v in variables.items())
    return {"credentials": creds, "router": router, "env": env, "tool": tool, "ca": certificates["router"].ca}


def cmd_credentials(args: argparse.Namespace) -> int:
    from cryptography import x509

    try:
        validate_rig_id(args.rig_id)
        files = write_compose_access(Path(args.out), args.rig_id, args.scenarios, run_s=args.duration, router_hosts=tuple(args.router_host))
    except (ValueError, OSError) as exc:
        console.print(f"[red]ralf-hil credentials: {exc}[/red]", highlight=False, soft_wrap=True)
        return 2
    expires = x509.load_pem_x509_certificate(files["ca"].read_bytes()).not_valid_after_utc
    console.print(
        f"wrote {args.out}: the run's authority and certificates (valid until {expires:%Y-%m-%d %H:%M} UTC), "
        f"the router's configuration, {files['env'].name} and {files['tool'].name}; "
        f"start the rig with: docker compose --env-file {files['env']} up --build",
        highlight=False,
        soft_wrap=True,
    )
    return 0


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse, with a usage error as one line (and exit 2), not the usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(prog="ralf-hil", description="RALF hardware-in-the-loop rig: run it, test it, reproduce the thesis.")
    sub = parser.add_subparsers(dest="command", required=True)
    up = sub.add_parser("up", help="start plant, controller and DSP as local processes and show a live status")
    up.add_argument(
        "--duration",
        type=positive_seconds,
        default=None,
        help="stop after this many simulated seconds of control, in every clock (in real time: wall seconds counted once every service is ready; with controller.duration_s, the shorter); default: until Ctrl-C",
    )
    up.add_argument("--rig-id", default="default", help="zenoh namespace ralf/<rig-id>/ (default: default)")
    up.add_argument(
        "--clock",
        choices=("realtime", "lockstep", "cosim"),
        default="realtime",
        help="realtime (default), lockstep (three processes, handshake-stepped) or cosim (one thread, bit-identical to lockstep)",
    )
    up.add_argument(
        "--set", action="append", default=[], metavar="[SERVICE.]NAME=VALUE", help="a setting for one service (controller.oatf_mode=adaptive) or all (seed=3)"
    )
    up.add_argument(
        "--log-dir",
        default=None,
        help="where the services' logs go, kept after the run (default: a temporary folder, removed after a run that went well; kept, and named, after a failure or Ctrl-C)",
    )
    up.add_argument("--keep-logs", action="store_true", help="keep the default temporary log folder after a run that went well too (its path is printed)")
    up.add_argument("--json", default=None, help="also write the summary as JSON to this file")
    up.add_argument("--verbose", action="store_true", help="the summary also lists the per-hop latencies (hop_*: where a tick's and a batch's time goes)")
    up.add_argument(
        "--keep-credentials",
        action="store_true",
        help="keep the run's zenoh credentials (an owner-only folder, printed at start) after it ends; by default they are removed at exit",
    )
    up.add_argument(
        "--scenarios",
        action="store_true",
        help="accept scenario commands on the plant's test port from the tester role (tester.env beside tool.env: `ralf-hil fault`)",
    )
    up.add_argument(
        "--record",
        default=None,
        metavar="RUN.mcap",
        help="record the run (CAN frames, zenoh messages, truth, DSP answers, TF downloads, metadata) into this MCAP file (.mf4: an ASAM MDF 4.1 file)",
    )
    up.add_argument(
        "--can-log", default=None, metavar="BUS.blf", help="with --record: also write the CAN side in python-can's format for this suffix (.blf, .asc, .log)"
    )
    up.add_argument(
        "--live",
        default=None,
        metavar="[HOST:]PORT",
        help="serve the running rig over the Foxglove WebSocket protocol on this port (127.0.0.1 unless HOST is given): the recording's topics, live",
    )
    up.add_argument("--live-rate", type=float, default=20.0, metavar="HZ", help="with --live: at most this many messages per second per topic (default: 20)")
    up.add_argument(
        "--can-port", type=int, default=None, help="udp_multicast port of the rig's CAN bus (default: derived from the rig id; printed before start)"
    )
    up.add_argument(
        "--can-bitrate",
        type=int,
        default=None,
        metavar="BIT/S",
        help="put the rig's CAN on one wire at this bit rate (125000, 250000, 500000, 1000000): a wire arbiter with bitwise arbitration and wire time in real time (docs/can-bus.md; default: the setting can_bitrate, 0: off)",
    )
    up.add_argument(
        "--restbus",
        default=None,
        metavar="FILE.dbc",
        help="with a bit rate: send this DBC's cyclic messages on the wire beside the rig (docs/can-bus.md; default: the setting can_restbus)",
    )
    up.set_defaults(func=cmd_up)
    rc = sub.add_parser("reconfigure", help="change the FFT width, batch size or averaging of a running rig")
    rc.add_argument("--rig-id", default=None, help="the rig's id (default: RALF_RIG_ID, else default)")
    rc.add_argument("--connect", default="", help="zenoh endpoint(s) of the rig, e.g. the one `ralf-hil up` prints")
    rc.add_argument("--fft-width", type=int, default=None, help="DSP FFT width N (power of two; zeroes its history)")
    rc.add_argument("--batch-size", type=int, default=None, help="samples per batch l (keeps the DSP's history)")
    rc.add_argument("--alpha", type=float, default=None, help="DSP exponential averaging weight")
    rc.add_argument("--timeout", type=positive_seconds, default=5.0, help="seconds to wait for the DSP's acknowledgement (default: 5)")
    rc.set_defaults(func=cmd_reconfigure)
    add_fault_parser(sub)
    add_param_parser(sub)
    cr = sub.add_parser("credentials", help="generate the certificates, zenoh credentials and the router's access rules for docker compose")
    cr.add_argument("--out", default="secrets", help="directory to write them to (default: secrets, which docker-compose.yml mounts)")
    cr.add_argument("--rig-id", default="default")
    cr.add_argument("--scenarios", action="store_true", help="accept scenario commands on the plant's test port (from the tester role)")
    cr.add_argument(
        "--duration",
        type=positive_seconds,
        default=None,
        help="the planned run's wall seconds: the certificates are valid for twice that and a day, at least 30 days (default: 30 days)",
    )
    cr.add_argument(
        "--router-host",
        action="append",
        default=[],
        metavar="NAME",
        help="another name or address clients reach the router by (a DSP on another host); repeatable. Always: zenoh-router and the host's loopback",
    )
    cr.set_defaults(func=cmd_credentials)
    for module in (bench, monitor, experiments, campaign, recording_cli, plant_cli, measure_cli):
        module.register(sub)
    timing_test.register(sub)  # ralf-hil timing-test (workbench/timing_test)
    memory_slope.register(sub)
    live_cli.register(sub)  # ralf-hil live (workbench/live)
    search_cli.register(sub)  # ralf-hil search (workbench/search)
    return parser


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The first bytes of every MCAP file (the MCAP specification)."""


def input_problem(command: str, args: argparse.Namespace) -> str | None:
    """What is wrong with a command's input file before it starts: missing,
    not a readable file, or (a recording) not an MCAP file at all."""
    if command not in ("plot", "replay", "export"):
        return None
    path = Path(args.path)
    if not path.exists():
        return f"{path}: no such file"
    if not path.is_file() or not os.access(path, os.R_OK):
        return f"{path}: not a readable file"
    with open(path, "rb") as fh:
        if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            return f"{path}: not an MCAP recording (it does not start with MCAP's magic bytes)"
    return None


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # what a guarded co-simulation runs again (workbench/cosim_guard.py)
    problem = input_problem(args.command, args)
    if problem:
        print(f"ralf-hil {args.command}: {problem}", file=sys.stderr)
        return 2
    try:
        with heartbeat_unless_terminal(f"ralf-hil {args.command}") if args.command in LONG_COMMANDS else nullcontext():
            return int(args.func(args))
    except ModuleNotFoundError as exc:
        needs = missing_extra(exc)
        if needs is None:
            raise
        print(f"ralf-hil {args.command}: {needs}", file=sys.stderr)
        return 2
    except SystemExit as exc:
        if isinstance(exc.code, str):  # a refusal's text: one line, exit 2
            print(" ".join(exc.code.split()), file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
