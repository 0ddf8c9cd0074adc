"""The compose rig's run and its report (called by .ci/compose-rig).

``run WORK``: inside the loopback-only namespace, starts docker-compose.yml
with docker-compose.python-router.yml through podman-compose, runs each
container's healthcheck every second (podman runs them from systemd timers,
which a host without systemd lacks) and notes when each became healthy,
takes one ``ralf-hil monitor --once --json`` snapshot from the host with the
tool's certificate (``tool.env``), feeds four kinds of bad input to the image
(a missing configuration, a wrong password, a certificate of another
authority, no router), stops the
services (SIGTERM) after the run and removes everything compose made. Every
step is bounded in time. Writes WORK/run.json.

``report WORK STAGES_JSON RESULTS``: checks run.json (every container exited
0, no ERROR line in any container's log (WARNING lines counted and reported),
every service ready with no numba kernel compiled at start, the router
listening on mutual TLS only, the
controller's log shows ticks, batches and interrupts, the DSP only on the
``lab`` network, the plant and controller only on ``cabinet``, each bad input
refused with a clear line), prints the verdict, writes RESULTS/run.json and
RESULTS/README.md, and exits 1 on any failure.
"""

from __future__ import annotations

import ast
import json
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from service_kit.readiness import parse_ready_line  # noqa: E402
from service_kit.zenoh_log import parse_line as parse_zenoh_line  # noqa: E402

SERVICES = ("zenoh-router", "dsp", "plant", "controller")
STARTUP_LIMIT_S = 150.0
"""Every container healthy within this long after ``up`` (a loaded CI host starts four Pythons on two cores)."""
NETWORKS = {"zenoh-router": {"cabinet", "lab"}, "dsp": {"lab"}, "plant": {"cabinet"}, "controller": {"cabinet"}}
RUN_ENDED = re.compile(r"run ended after (?P<ticks>\d+) ticks \((?P<sim>[0-9.]+) s simulated\): (?P<counters>\{.*\})")
HOPS = {
    "hop_sync_to_tpdo": "CAN: SYNC out -> TPDO1 back (controller <-> plant, one segment)",
    "hop_batch_to_dsp": "zenoh: batch sent -> DSP starts (controller -> router -> DSP)",
    "hop_irq_to_controller": "zenoh: interrupt raised -> received (DSP -> router -> controller)",
    "batch_to_interrupt": "batch sent -> interrupt received (both zenoh hops + DSP compute + its 100 ms hold)",
}


def sh(cmd: list[str], timeout: float, **kw: Any) -> subprocess.CompletedProcess[str]:
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False, **kw)
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout.decode(errors="replace") if isinstance(exc.stdout, bytes) else exc.stdout or ""
        return subprocess.CompletedProcess(cmd, 124, out, f"timed out after {timeout:.0f} s: {' '.join(cmd)}")


def containers(project: str) -> dict[str, dict[str, Any]]:
    """The project's containers by service."""
    out = sh(["podman", "ps", "-a", "--filter", f"label=io.podman.compose.project={project}", "--format", "json"], 30)
    found = {}
    for c in json.loads(out.stdout or "[]"):
        service = (c.get("Labels") or {}).get("com.docker.compose.service")
        if service:
            found[service] = {"name": c["Names"][0], "id": c["Id"]}
    return found


RIG_LINE = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d+ \S+ (?P<level>DEBUG|INFO|WARNING|ERROR|CRITICAL) ")
"""A line of the rig's own log format (service_kit.runtime.configure_logging): time, service, level."""
ANSI = re.compile(r"\x1b\[[0-9;]*m")
LOOSE_ERROR = re.compile(r"\b(ERROR|CRITICAL)\b|^Traceback \(most recent call last\)|^\w*(Error|Exception): ")
LOOSE_WARNING = re.compile(r"\bWARN(ING)?\b|\b\w+Warning: ")


def log_problems(text: str) -> tuple[list[str], list[str]]:
    """The ERROR and the WARNING lines of one container's log (colour codes removed).

    A line in the rig's own format is judged by its level field, a raw zenoh
    line (its Rust format, coloured or not) by zenoh's level as the services
    would log it (:func:`service_kit.zenoh_log.parse_line`: routine start-up
    warnings are INFO); any other line (a traceback, a Python warning, a tool's
    own output) by its words. A CRITICAL counts as an ERROR."""
    errors: list[str] = []
    warnings: list[str] = []
    for raw in text.splitlines():
        line = ANSI.sub("", raw).rstrip()
        m = RIG_LINE.match(line)
        if m is not None:
            level = m["level"]
            is_error, is_warning = level in ("ERROR", "CRITICAL"), level == "WARNING"
        elif (zenoh := parse_zenoh_line(line)) is not None:
            is_error, is_warning = zenoh[0] >= 40, zenoh[0] == 30
        else:
            is_error = LOOSE_ERROR.search(line) is not None
            is_warning = not is_error and LOOSE_WARNING.search(line) is not None
        if is_error:
            errors.append(line)
        elif is_warning:
            warnings.append(line)
    return errors, warnings


def first_line(text: str, pattern: str) -> str:
    for line in text.splitlines():
        if re.search(pattern, line):
            return line.strip()
    return ""


def bad_inputs(image: str, network: str, env: dict[str, Any]) -> dict[str, Any]:
    """Four kinds of bad input, each as a container of the image: one clear line, a non-zero exit.
    ``env``: the router's address, a CAN port, and the certificate variables of the run (``own``)
    and of another authority (``foreign``)."""

    def common(name: str) -> list[str]:
        return ["podman", "run", "--rm", "--name", f"{os.environ['PROJECT']}-bad-{name.replace('_', '-')}"]

    def client(tls: dict[str, str], password: str) -> list[str]:
        """A plant as compose starts one, on the cabinet network, with these certificate variables (ralf.env's)."""
        settings = {
            "RALF_ZENOH_MODE": "client",
            "RALF_ZENOH_CONNECT": f"tls/{env['router_ip']}:7447",
            "RALF_ZENOH_USER": "plant",
            "RALF_ZENOH_PASSWORD": password,
            "RALF_ZENOH_TLS_CA_BASE64": tls["ZENOH_TLS_CA"],
            "RALF_ZENOH_TLS_CERTIFICATE_BASE64": tls["ZENOH_TLS_CERTIFICATE_PLANT"],
            "RALF_ZENOH_TLS_KEY_BASE64": tls["ZENOH_TLS_KEY_PLANT"],
            "RALF_CAN_PORT": env["can_port"],
        }
        return ["--network", network, *(arg for k, v in settings.items() for arg in ("-e", f"{k}={v}"))]

    cases = {
        # the router's configuration file is missing (credentials not generated)
        "missing_credentials": [
            *common("missing_credentials"),
            "--network",
            "none",
            image,
            "python",
            "-m",
            "service_kit.router",
            "/etc/ralf/zenoh-router.json5",
        ],
        # a service with the run's certificate and a wrong password, against the running router
        "wrong_password": [*common("wrong_password"), *client(env["own"], "not-the-password"), image, "ralf-plant"],
        # a service with a certificate of another authority (and the right password)
        "foreign_certificate": [*common("foreign_certificate"), *client(env["foreign"], env["own"]["ZENOH_PASSWORD_PLANT"]), image, "ralf-plant"],
        # no router: a client retries for 30 s with a line per try, then exits with one error line
        "router_not_up": [
            *common("router_not_up"),
            "--network",
            "none",
            "-e",
            "RALF_ZENOH_MODE=client",
            "-e",
            "RALF_ZENOH_CONNECT=tcp/127.0.0.1:7447",
            image,
            "ralf-dsp",
        ],
    }
    procs = {name: subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for name, cmd in cases.items()}
    return {"procs": procs, "started": time.monotonic()}


def collect_bad(running: dict[str, Any], logs: Path) -> dict[str, Any]:
    results = {}
    for name, proc in running["procs"].items():
        try:
            out, _ = proc.communicate(timeout=max(5.0, 60 - (time.monotonic() - running["started"])))
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
            results[name] = {"exit": "hung", "line": "", "lines": len(out.splitlines())}
            continue
        (logs / f"bad-{name}.log").write_text(out)
        stamp = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d+ ")  # the rig's own log lines (zenoh's have another format)
        lines = [line.strip() for line in out.splitlines() if line.strip()]
        own = [stamp.sub("", line) for line in lines if stamp.match(line)]
        errors = [line for line in own if " ERROR " in line]
        results[name] = {"exit": proc.returncode, "line": (errors or own or lines or [""])[-1], "lines": len(own), "zenoh_lines": len(lines) - len(own)}
    return results


def cold_start(image: str, project: str, logs: Path, limit_s: float = 150.0) -> dict[str, Any]:
    """The check's control: the DSP of the same image with an empty numba cache
    (NUMBA_CACHE_DIR), alone (a zenoh peer, no network), must report its compiled kernels."""
    name = f"{project}-bad-cold-start"
    started = sh(
        ["podman", "run", "-d", "--name", name, "--network", "none", "-e", "NUMBA_CACHE_DIR=/tmp/cold", "-e", "RALF_ZENOH_MODE=peer", image, "ralf-dsp"], 60
    )
    text = ""
    if started.returncode == 0:
        deadline = time.monotonic() + limit_s
        while time.monotonic() < deadline:
            out = sh(["podman", "logs", name], 30)
            text = out.stdout + out.stderr
            if parse_ready_line(text) is not None:
                break
            time.sleep(1.0)
    stop = sh(["podman", "stop", "-t", "20", name], 40)
    code = sh(["podman", "inspect", "--format", "{{.State.ExitCode}}", name], 20).stdout.strip()
    sh(["podman", "rm", "-f", name], 30)
    (logs / "cold-start-dsp.log").write_text(text + stop.stderr)
    ready = parse_ready_line(text)
    return {
        "ready_s": ready.seconds if ready else None,
        "compiled": ready.compiled if ready else None,
        "exit": int(code) if code.lstrip("-").isdigit() else code,
    }


def run(work: Path) -> int:
    project, image, run_s = os.environ["PROJECT"], os.environ["IMAGE"], float(os.environ["RUN_S"])
    pdir = work / "project"
    env_file = pdir / "secrets" / "ralf.env"
    passwords = dict(line.split("=", 1) for line in env_file.read_text().splitlines() if "=" in line)
    foreign_dir = work / "foreign"  # another run's authority, for the bad input
    sh([os.environ["RIG_CLI"], "credentials", "--out", str(foreign_dir)], 60)
    foreign = dict(line.split("=", 1) for line in (foreign_dir / "ralf.env").read_text().splitlines() if "=" in line)
    pc = [
        os.environ["PODMAN_COMPOSE"],
        "--in-pod",
        "false",
        "-p",
        project,
        "--env-file",
        str(env_file),
        "-f",
        str(pdir / "docker-compose.yml"),
        "-f",
        str(pdir / "docker-compose.python-router.yml"),
    ]
    logs = work / "logs"
    logs.mkdir(exist_ok=True)
    record: dict[str, Any] = {"load_avg_before": os.getloadavg()[0], "run_s": run_s, "healthy_after_s": {}, "exit": {}, "networks": {}, "problems": []}
    t_up = time.monotonic()
    up = sh([*pc, "up", "-d", "--no-build"], 180)
    (logs / "podman-compose-up.log").write_text(up.stdout + up.stderr)
    record["up_s"] = round(time.monotonic() - t_up, 1)
    record["up_warnings"] = sorted({line.strip() for line in up.stderr.splitlines() if "Ignored" in line or "WARN" in line})
    if up.returncode != 0:
        record["problems"].append(f"podman-compose up failed ({up.returncode}): {(up.stderr or up.stdout)[-600:]}")
    found = containers(project)
    record["containers"] = {s: c["name"] for s, c in found.items()}
    bad: dict[str, Any] | None = None
    monitor: dict[str, Any] | None = None
    # Start-up (bounded): every container's healthcheck once a second until all pass.
    startup_end = t_up + STARTUP_LIMIT_S
    while len(record["healthy_after_s"]) < len(found) and time.monotonic() < startup_end and up.returncode == 0:
        for service, c in found.items():
            if service not in record["healthy_after_s"] and sh(["podman", "healthcheck", "run", c["name"]], 10).returncode == 0:
                record["healthy_after_s"][service] = round(time.monotonic() - t_up, 1)
        time.sleep(1.0)
    if len(record["healthy_after_s"]) < len(found):
        record["problems"].append(f"not healthy within {STARTUP_LIMIT_S:.0f} s of up: {sorted(set(found) - set(record['healthy_after_s']))}")
    # The run: run_s seconds of the whole rig, the bad input beside it, one snapshot from the host near its end.
    t_run = time.monotonic()
    end = t_run + run_s
    if up.returncode == 0 and "zenoh-router" in found:
        router_ip = sh(
            ["podman", "inspect", "--format", f'{{{{(index .NetworkSettings.Networks "{project}_cabinet").IPAddress}}}}', found["zenoh-router"]["name"]], 20
        )
        bad = bad_inputs(image, f"{project}_cabinet", {"can_port": "43999", "router_ip": router_ip.stdout.strip(), "own": passwords, "foreign": foreign})
    while time.monotonic() < end:
        if monitor is None and time.monotonic() > end - 8:
            monitor = watch(pdir / "secrets" / "tool.env")
        time.sleep(max(0.0, min(1.0, end - time.monotonic())))
    if monitor is None:
        monitor = watch(pdir / "secrets" / "tool.env")
    record["monitor"] = monitor
    record["ran_s"] = round(time.monotonic() - t_run, 1)
    record["load_avg_after"] = os.getloadavg()[0]
    for service in ("controller", "plant", "dsp", "zenoh-router"):  # the controller first: its run summary is logged on SIGTERM
        if service in found:
            sh(["podman", "stop", "-t", "20", found[service]["name"]], 40)
    record["cold_start"] = cold_start(image, project, logs)
    for service, c in found.items():
        record["exit"][service] = int(sh(["podman", "inspect", "--format", "{{.State.ExitCode}}", c["name"]], 20).stdout.strip() or -1)
        nets = sh(["podman", "inspect", "--format", "{{json .NetworkSettings.Networks}}", c["name"]], 20).stdout.strip()
        record["networks"][service] = sorted(n.removeprefix(f"{project}_") for n in json.loads(nets or "{}"))
        text = sh(["podman", "logs", c["name"]], 30)
        (logs / f"{service}.log").write_text(text.stdout + text.stderr)
    record["bad_input"] = collect_bad(bad, logs) if bad else {}
    down = sh([*pc, "down", "-t", "5"], 120)
    (logs / "podman-compose-down.log").write_text(down.stdout + down.stderr)
    record["down_exit"] = down.returncode
    (work / "run.json").write_text(json.dumps(record, indent=2) + "\n")
    return 0


def watch(tool_env: Path) -> dict[str, Any]:
    """``ralf-hil monitor --once --json`` from the host, as a user watches the rig: with the
    tool's certificate and password (``tool.env``, which ``ralf-hil credentials`` writes)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RALF_")}
    env.update(dict(line.split("=", 1) for line in tool_env.read_text().splitlines() if "=" in line))
    out = sh([os.environ["RIG_CLI"], "monitor", "--once", "--json", "--window", "3"], 30, env=env)
    try:
        return {"exit": out.returncode, "snapshot": json.loads(out.stdout)}
    except json.JSONDecodeError:
        return {"exit": out.returncode, "error": (out.stderr or out.stdout)[-400:]}


EXPECTED_BAD = {
    "missing_credentials": "no such file",
    "wrong_password": "refused the session",
    "foreign_certificate": "refused the session",
    "router_not_up": "nothing answered",
}
"""Each bad input and what its last line says."""
MIN_CHECKS = 3 * len(SERVICES) + len(NETWORKS) + 1 + 1 + 3 + 1 + 1 + len(EXPECTED_BAD)
"""The checks a judged run makes at least: each service's exit, ready line and log, each service's
networks, the router's endpoint (TLS only), the controller's run summary and its ticks, batches and interrupts, the monitor's view of
its health, the cold-start control and the four bad inputs. A run judged on fewer (a record or
logs missing their parts) fails as "too few checks", never passes on what was not looked at."""


def evaluate(work: Path) -> dict[str, Any]:
    record = json.loads((work / "run.json").read_text())
    logs = {s: (work / "logs" / f"{s}.log").read_text(errors="replace") if (work / "logs" / f"{s}.log").exists() else "" for s in SERVICES}
    failures: list[str] = list(record["problems"])
    made = 0

    def check(ok: bool, failure: str) -> bool:
        nonlocal made
        made += 1
        if not ok:
            failures.append(failure)
        return ok

    for service in SERVICES:
        check(record["exit"].get(service) == 0, f"{service} exited {record['exit'].get(service, 'never started')}")
    startup: dict[str, Any] = {}
    for service in SERVICES:
        ready = parse_ready_line(logs[service])
        if not check(ready is not None, f"{service}: no ready line in its log") or ready is None:
            continue
        startup[service] = {"ready_s": ready.seconds, "kernels_cached": ready.cached, "kernels_compiled": ready.compiled}
        if service != "zenoh-router":
            check(not ready.compiled, f"{service}: {ready.compiled} numba kernel(s) compiled at start: {first_line(logs[service], 'ready in')}")
            check(bool(ready.cached), f"{service}: no numba kernel loaded from cache")
    for service, wanted in NETWORKS.items():
        check(set(record["networks"].get(service, [])) == wanted, f"{service} is on networks {record['networks'].get(service)}, not {sorted(wanted)}")
    log_lines: dict[str, dict[str, Any]] = {}
    for service in SERVICES:
        errors, warnings = log_problems(logs[service])
        log_lines[service] = {"errors": len(errors), "warnings": len(warnings), "error_lines": errors[:20], "warning_lines": warnings[:20]}
        check(not errors, f"{service}: {len(errors)} ERROR line(s) in its log: " + " | ".join(errors[:5]))
    listening = re.search(r"listening on (?P<endpoints>.+)$", logs.get("zenoh-router", ""), flags=re.M)
    endpoints = listening["endpoints"].split(", ") if listening else []
    check(
        bool(endpoints) and all(e.startswith("tls/") for e in endpoints), f"the router does not listen on mutual TLS only: {endpoints or 'no listening line'}"
    )
    m = RUN_ENDED.search(logs.get("controller", ""))
    controller: dict[str, Any] = {}
    if check(m is not None, "the controller's log has no run summary") and m is not None:
        counters = ast.literal_eval(m["counters"])
        controller = {"ticks": int(m["ticks"]), "sim_time_s": float(m["sim"]), **{k: v for k, v in counters.items() if isinstance(v, int)}}
        for name in ("ticks", "batches_sent", "interrupts"):
            check(bool(controller.get(name)), f"the controller's log shows no {name}: {m.group(0)[:300]}")
    hops: dict[str, Any] = {}
    services = ((record.get("monitor") or {}).get("snapshot") or {}).get("services") or {}
    health = {name: (s or {}).get("health") or {} for name, s in services.items()}
    for name, what in HOPS.items():
        stats = ((health.get("controller") or {}).get("latencies") or {}).get(name)
        if stats:
            hops[name] = {"what": what, **{k: stats[k] for k in ("count", "p50", "p99", "max")}}
    dsp_turnaround = ((health.get("dsp") or {}).get("latencies") or {}).get("batch_to_interrupt")
    if dsp_turnaround:
        hops["dsp_batch_to_interrupt"] = {
            "what": "the DSP's own turnaround (arrival -> interrupt put)",
            **{k: dsp_turnaround[k] for k in ("count", "p50", "p99", "max")},
        }
    check(bool(hops), f"ralf-hil monitor from the host saw no controller health: {(record.get('monitor') or {}).get('error', '')[:300]}")
    cold = record.get("cold_start") or {}
    check(bool(cold.get("compiled")), f"the DSP with an empty numba cache reported no compiled kernel (the check could not see one): {cold}")
    for case, text in EXPECTED_BAD.items():
        got = record["bad_input"].get(case)
        check(bool(got) and got["exit"] not in (0, "hung") and text in str(got["line"]).lower(), f"bad input {case}: {got}")
    if made < MIN_CHECKS:
        failures.append(f"too few checks: {made} made, at least {MIN_CHECKS} needed to judge the run")
    return {
        "verdict": "pass" if not failures else "fail",
        "checks": made,
        "min_checks": MIN_CHECKS,
        "failures": failures,
        "startup": startup,
        "healthy_after_s": record["healthy_after_s"],
        "controller": controller,
        "log_lines": log_lines,
        "hops": hops,
        "networks": record["networks"],
        "exit": record["exit"],
        "bad_input": record["bad_input"],
        "up_s": record.get("up_s"),
        "up_warnings": record.get("up_warnings", []),
        "run_s": record["run_s"],
        "cold_start": cold,
        "load_avg": [record.get("load_avg_before"), record.get("load_avg_after")],
    }


def machine() -> str:
    cpus = os.cpu_count()
    model = ""
    try:
        model = first_line(Path("/proc/cpuinfo").read_text(), r"^model name").split(":", 1)[1].strip()
    except (OSError, IndexError):
        pass
    podman = sh(["podman", "--version"], 10).stdout.strip()
    return f"{platform.system()} {platform.release()}, {cpus} CPUs ({model}), {podman}"


def ms(seconds: float) -> str:
    return f"{seconds * 1e3:.2f}"


def write_results(result: dict[str, Any], out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "run.json").write_text(json.dumps(result, indent=2) + "\n")
    c = result["controller"]
    lines = [
        "# The compose rig, as CI runs it",
        "",
        "Written by `.ci/compose-rig` (do not edit): the project's image built from its",
        "Dockerfile with podman, docker-compose.yml run by podman-compose with",
        "docker-compose.python-router.yml (the router replaced by service_kit/router.py)",
        "in a loopback-only network namespace, on the compose file's two bridge networks",
        "(`cabinet`: router, plant, controller; `lab`: router, DSP).",
        "",
        f"- Date: {result['date']}; machine: {result['machine']}; load average (1 min) {result['load_avg'][0]:.1f} before the run, "
        f"{result['load_avg'][1]:.1f} after (the host is shared: start-up times follow the load)",
        f"- Verdict: **{result['verdict']}** over {result.get('checks', '?')} checks (at least {result.get('min_checks', '?')})"
        + ("" if not result["failures"] else ": " + "; ".join(result["failures"])),
        f"- Run: {result['run_s']:.0f} s once every container was healthy; controller {c.get('ticks', 0)} ticks, {c.get('batches_sent', 0)} batches, "
        f"{c.get('interrupts', 0)} interrupts, {c.get('deadline_misses', 0)} deadline misses, {c.get('overruns', 0)} overruns (misses reported, not asserted)",
        "- Whole script: " + ", ".join(f"{k.removesuffix('_s').replace('_', ' ')} {v:.0f} s" for k, v in result["stages"].items()),
        "",
        "## Start-up per service",
        "",
        "| service | ready after process start (s) | numba kernels from cache | compiled at start | healthcheck passed (s after `up`) |",
        "|---|---|---|---|---|",
    ]
    for service in SERVICES:
        s = result["startup"].get(service, {})
        lines.append(
            f"| {service} | {s.get('ready_s', '-')} | {s.get('kernels_cached', '-')} | {s.get('kernels_compiled', '-')} | {result['healthy_after_s'].get(service, 'never')} |"
        )
    lines += [
        "",
        "## ERROR and WARNING lines in each container's log",
        "",
        "Any ERROR line fails the run; WARNING lines are counted and shown here.",
        "",
        "| service | ERROR lines | WARNING lines | first WARNING |",
        "|---|---|---|---|",
    ]
    for service in SERVICES:
        n = result.get("log_lines", {}).get(service, {})
        first = (n.get("warning_lines") or [""])[0].replace("|", "\\|")
        lines.append(f"| {service} | {n.get('errors', '-')} | {n.get('warnings', '-')} | {f'`{first}`' if first else '-'} |")
    cold = result.get("cold_start") or {}
    lines += [
        "",
        f"The check's control: the DSP of the same image with an empty numba cache (`NUMBA_CACHE_DIR`), alone, "
        f"was ready after {cold.get('ready_s')} s with {cold.get('compiled')} kernels compiled at start (exit {cold.get('exit')}).",
    ]
    lines += [
        "",
        "## Links and what they add (measured on the bridge, from the controller's health)",
        "",
        "| link | may cross hosts | count | p50 (ms) | p99 (ms) | max (ms) |",
        "|---|---|---|---|---|---|",
    ]
    crosses = {
        "hop_sync_to_tpdo": "no (CAN, one segment, TTL 1)",
        "hop_batch_to_dsp": "yes (zenoh via router)",
        "hop_irq_to_controller": "yes (zenoh via router)",
    }
    for name, h in result["hops"].items():
        lines.append(f"| {h['what']} | {crosses.get(name, '-')} | {h['count']} | {ms(h['p50'])} | {ms(h['p99'])} | {ms(h['max'])} |")
    lines += [
        "",
        "## Networks and bad input",
        "",
        "Networks: " + "; ".join(f"{s}: {', '.join(n)}" for s, n in result["networks"].items()) + ".",
        "",
        "| bad input | exit | its lines (zenoh's own) | its last line |",
        "|---|---|---|---|",
    ]
    for case, b in result["bad_input"].items():
        line = str(b["line"]).replace("|", "\\|")
        lines.append(f"| {case.replace('_', ' ')} | {b['exit']} | {b['lines']} ({b.get('zenoh_lines', 0)}) | `{line}` |")
    (out / "README.md").write_text("\n".join(lines) + "\n")


def report(work: Path, stages: str, out: Path) -> int:
    result = evaluate(work)
    result["stages"] = json.loads(stages)
    result["date"] = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    result["machine"] = machine()
    write_results(result, out)
    for service, n in result["log_lines"].items():
        print(f"compose-rig: {service} log: {n['errors']} ERROR, {n['warnings']} WARNING line(s)", file=sys.stderr)
        for line in n["error_lines"]:
            print(f"compose-rig:   {service} ERROR line: {line}", file=sys.stderr)
    for failure in result["failures"]:
        print(f"compose-rig: FAIL: {failure}", file=sys.stderr)
    print(f"compose-rig: {result['verdict']} over {result['checks']} checks (at least {result['min_checks']}); results in {out}", file=sys.stderr)
    return 0 if result["verdict"] == "pass" else 1


if __name__ == "__main__":
    if sys.argv[1:2] == ["run"]:
        raise SystemExit(run(Path(sys.argv[2])))
    if sys.argv[1:2] == ["report"]:
        raise SystemExit(report(Path(sys.argv[2]), sys.argv[3], Path(sys.argv[4])))
    print("usage: compose_rig.py run WORK | report WORK STAGES_JSON RESULTS", file=sys.stderr)
    raise SystemExit(2)
