"""Starting, watching and stopping the three services as local processes.

The embedded default of ``ralf-hil up``: zenoh peer-to-peer on loopback
(the launcher's own session and each service listen on a free loopback
port; every service connects to the launcher only and zenoh's gossip links
the services to each other, one link per pair, since zenoh 1.9+ peers do
not relay for each other; no router). Explicit links between services would
meet gossip's links in the other direction: zenoh keeps one link per pair
(``transport/unicast/max_links`` 1) and refuses the second with ``Received a
close message (reason INVALID)``, an ERROR every ~4 s on both sides), CAN over
python-can's ``udp_multicast`` on a UDP port of the rig's own, so several
rigs can run side by side.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from protocol.errors import ProtocolError
from protocol.keys import Keys
from protocol.messages import ControllerStatus, Health, decode
from protocol.rig_description import RIG, start_order, stop_order
from service_kit.access import insert_access_from_env
from service_kit.crash_report import death_line
from service_kit.transport import PEER_AUTOCONNECT_STRATEGY
from service_kit.zenoh_log import init_zenoh_log
from workbench.loss_grace import controller_acts_on
from workbench.monitor import health_key_service

SERVICE_MODULES: dict[str, str] = {s.name: s.module for s in RIG.services}
START_ORDER = start_order()
STOP_ORDER = stop_order()


def free_tcp_ports(count: int) -> list[int]:
    """``count`` distinct free TCP ports on 127.0.0.1.

    Every socket stays bound until all are chosen: the kernel may hand out
    a port again as soon as its socket closes, and two services of one rig
    given the same port fail with "Address already in use" (seen once in
    the suite: the controller's listener took the launcher's port)."""
    socks = [socket.socket(socket.AF_INET, socket.SOCK_STREAM) for _ in range(count)]
    try:
        for sock in socks:
            sock.bind(("127.0.0.1", 0))
        return [int(sock.getsockname()[1]) for sock in socks]
    finally:
        for sock in socks:
            sock.close()


def free_tcp_port() -> int:
    return free_tcp_ports(1)[0]


def can_port_for(rig_id: str) -> int:
    """A udp_multicast port of the rig's own (43113 is python-can's default)."""
    return 43200 + zlib.crc32(rig_id.encode()) % 20000


@dataclass
class RigPlan:
    """Everything needed to start one rig as local processes."""

    rig_id: str
    zenoh_port: int
    can_port: int
    service_ports: dict[str, int]
    common_env: dict[str, str]
    service_env: dict[str, dict[str, str]] = field(default_factory=dict)
    zenoh_scheme: str = "tcp"
    """``tcp``, or ``tls`` once :meth:`use_tls` gave every node its certificate."""

    @classmethod
    def local(
        cls,
        rig_id: str = "default",
        clock: str = "realtime",
        overrides: Mapping[str, Mapping[str, str]] | None = None,
        common: Mapping[str, str] | None = None,
    ) -> RigPlan:
        port, *ports = free_tcp_ports(1 + len(SERVICE_MODULES))
        service_ports = dict(zip(SERVICE_MODULES, ports, strict=True))
        env = {
            "RALF_RIG_ID": rig_id,
            "RALF_ZENOH_MODE": "peer",
            "RALF_CAN_INTERFACE": "udp_multicast",
            "RALF_CAN_CHANNEL": "239.74.163.2",
            "RALF_CAN_PORT": str(can_port_for(rig_id)),
            "RALF_CLOCK": clock,
        }
        env.update(common or {})
        plan = cls(rig_id=rig_id, zenoh_port=port, can_port=int(env["RALF_CAN_PORT"]), common_env=env, service_ports=service_ports)
        for name in SERVICE_MODULES:
            plan.service_env[name] = {**plan._own_endpoints(name), **dict((overrides or {}).get(name, {}))}
        return plan

    @property
    def zenoh_endpoint(self) -> str:
        """The launcher's own endpoint, the one every service and tool connects to."""
        return f"{self.zenoh_scheme}/127.0.0.1:{self.zenoh_port}"

    def _own_endpoints(self, service: str) -> dict[str, str]:
        return {
            "RALF_ZENOH_LISTEN": f"{self.zenoh_scheme}/127.0.0.1:{self.service_ports[service]}",
            "RALF_ZENOH_CONNECT": self.zenoh_endpoint,  # the launcher only: see the module's text
        }

    def use_tls(self, role_env: Mapping[str, Mapping[str, str]]) -> None:
        """Every link of the rig over mutual TLS: each node (the services and
        the ``launcher``) gets its role's variables from ``role_env``
        (``RALF_ZENOH_TLS_*``, its credentials) and every ``tcp/`` endpoint
        becomes ``tls/`` (one given with ``--set`` too)."""
        self.zenoh_scheme = "tls"
        for name in SERVICE_MODULES:
            env = self.service_env.setdefault(name, {})
            for var in ("RALF_ZENOH_LISTEN", "RALF_ZENOH_CONNECT"):
                endpoints = (e.strip() for e in env.get(var, "").split(","))
                env[var] = ",".join("tls/" + e.removeprefix("tcp/") if e.startswith("tcp/") else e for e in endpoints if e)
        for role in (*SERVICE_MODULES, "launcher"):
            self.service_env.setdefault(role, {}).update(role_env[role])

    def env_for(self, service: str) -> dict[str, str]:
        """The caller's environment (its ``RALF_*`` settings included, e.g.
        ``RALF_SEED=3 ralf-hil up``), then the rig's own transport and clock
        settings, then the ``--set`` overrides for this service."""
        env = dict(os.environ)
        env.update(self.common_env)
        env.update(self.service_env.get(service, {}))
        env["RALF_LAUNCHER_PID"] = str(os.getpid())  # the service ends when this process does (service_kit.runtime.follow_launcher)
        env.setdefault("PYTHONUNBUFFERED", "1")
        return env

    def command_for(self, service: str) -> list[str]:
        # -P: the service imports the installed packages, as ralf-hil did, not
        # a checkout that happens to be the working folder (whose modules may
        # differ from the install and keep a numba cache of their own).
        return [sys.executable, "-P", "-m", SERVICE_MODULES[service]]


@dataclass
class RigObserver:
    """The launcher's own zenoh peer: the listener the services connect to,
    and the collector of status, health and liveliness for the status line."""

    plan: RigPlan
    status: ControllerStatus | None = None
    health: dict[str, Health] = field(default_factory=dict)
    alive: dict[str, bool] = field(default_factory=dict)
    events: list[str] = field(default_factory=list)
    bad_messages: int = 0
    health_refused: int = 0
    """Health payloads naming another service than the key they came on."""

    def __post_init__(self) -> None:
        keys = Keys(self.plan.rig_id)
        config = zenoh.Config()
        config.insert_json5("mode", '"peer"')
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("listen/endpoints", json.dumps([self.plan.zenoh_endpoint]))
        config.insert_json5("scouting/gossip/autoconnect_strategy", PEER_AUTOCONNECT_STRATEGY)
        insert_access_from_env(config, self.plan.rig_id, {**self.plan.common_env, **self.plan.service_env.get("launcher", {})})
        init_zenoh_log()
        self.session = zenoh.open(config)
        self._lock = threading.Lock()
        self._subs = [
            self.session.declare_subscriber(keys.controller_status, self._on_status),
            self.session.declare_subscriber(keys.health_all, self._on_health),
            self.session.liveliness().declare_subscriber(keys.alive_all, self._on_alive, history=True),
        ]

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            status = decode(ControllerStatus, sample.payload.to_bytes())
        except ProtocolError:
            self.bad_messages += 1
            return
        with self._lock:
            self.status = status

    def _on_health(self, sample: zenoh.Sample) -> None:
        try:
            health = decode(Health, sample.payload.to_bytes())
        except ProtocolError:
            self.bad_messages += 1
            return
        service = health_key_service(str(sample.key_expr))  # filed by its key, not by its claim
        with self._lock:
            if health.service != service:
                self.health_refused += 1
                return
            self.health[service] = health

    def _on_alive(self, sample: zenoh.Sample) -> None:
        service = str(sample.key_expr).rsplit("/", 1)[-1]
        up = sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            if self.alive.get(service) != up:
                self.events.append(f"{time.strftime('%H:%M:%S')} {service} {'up' if up else 'lost'}")
            self.alive[service] = up

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self.session.close()


@dataclass
class ServiceProcess:
    name: str
    popen: subprocess.Popen[bytes]
    log_path: Path

    @property
    def returncode(self) -> int | None:
        return self.popen.poll()


def start_service(plan: RigPlan, name: str, log_dir: Path) -> ServiceProcess:
    log_dir.mkdir(parents=True, exist_ok=True)
    log_path = log_dir / f"{name}.log"
    with open(log_path, "wb") as log_file:
        popen = subprocess.Popen(
            plan.command_for(name),
            env=plan.env_for(name),
            stdout=log_file,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            # A session of its own: a terminal's Ctrl-C (SIGINT to the foreground
            # process group) reaches the launcher, which stops the services in
            # order, not each service halfway through its start-up.
            start_new_session=True,
        )
    return ServiceProcess(name=name, popen=popen, log_path=log_path)


def terminate(popen: subprocess.Popen[bytes], timeout_s: float = 10.0) -> int:
    """SIGTERM, wait, then SIGKILL if it does not stop; returns the exit code."""
    if popen.poll() is None:
        popen.send_signal(signal.SIGTERM)
        try:
            popen.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            popen.kill()
            popen.wait()
    return int(popen.returncode)


def stop_service(proc: ServiceProcess, timeout_s: float = 10.0) -> int:
    """SIGTERM, wait, then SIGKILL if it does not stop; returns the exit code."""
    return terminate(proc.popen, timeout_s)


def tail(path: Path, lines: int = 15) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""


@dataclass
class Supervision:
    """How a supervised rig run went (:func:`supervise`)."""

    procs: dict[str, ServiceProcess]
    exit_codes: dict[str, int] = field(default_factory=dict)
    failure: str = ""
    """Empty when the run ended as asked (duration reached, controller finished, stop)."""
    started: float = 0.0
    """``time.monotonic()`` at launch."""
    ready_at: float | None = None
    """When the controller's first tick was seen: every service had answered (tick 0 waits for them)."""
    ended_at: float = 0.0
    """When the run ended, before the services were stopped."""
    policy_grace_s: float | None = None
    """Set when a service died mid-run whose death the controller answers
    itself (:mod:`workbench.loss_grace`): the wall seconds it was given."""

    @property
    def startup_s(self) -> float | None:
        return None if self.ready_at is None else self.ready_at - self.started

    @property
    def control_s(self) -> float:
        """Wall seconds of control: from the first tick to the end."""
        return 0.0 if self.ready_at is None else self.ended_at - self.ready_at


def supervise(
    plan: RigPlan,
    log_dir: Path,
    status: Callable[[], ControllerStatus | None],
    *,
    run_for_s: float | None = None,
    timeout_s: float | None = None,
    startup_timeout_s: float | None = None,
    stop: threading.Event | None = None,
    on_poll: Callable[[Supervision, ControllerStatus | None], None] | None = None,
    poll_s: float = 0.2,
    stop_timeout_s: float = 10.0,
) -> Supervision:
    """The one supervise loop of the launcher (``ralf-hil up``, the bench and
    the experiments): start the services in :data:`START_ORDER`, watch them,
    end, and always stop them in :data:`STOP_ORDER`.

    The run ends when the controller exits (its run is over; non-zero is a
    failure), when another service dies (a failure; a death mid-run that the
    controller answers itself, the plant's, ends the run when the controller
    has, or after the grace :mod:`workbench.loss_grace` derives from its
    timeouts), ``run_for_s`` wall
    seconds after the controller's first tick (start-up is not counted),
    when ``stop`` is set, after ``timeout_s`` in all (a failure), or when no
    tick came within ``startup_timeout_s`` of the launch (a failure).
    ``status()`` gives the latest controller status (from the caller's
    observer); ``on_poll`` is called on every poll (live view, progress).
    """
    sup = Supervision(procs={}, started=time.monotonic())
    stop = stop or threading.Event()
    interrupted = False
    grace = controller_acts_on(plan.env_for("controller"), stop_timeout_s)
    acting_until: float | None = None
    try:
        for name in START_ORDER:
            sup.procs[name] = start_service(plan, name, log_dir)
        while True:
            now = time.monotonic()
            current = status()
            if sup.ready_at is None and current is not None and current.ticks > 0:
                sup.ready_at = now
            if on_poll is not None:
                on_poll(sup, current)
            dead = {p.name: p.returncode for p in sup.procs.values() if p.returncode is not None}
            lost = {name: code for name, code in dead.items() if name != "controller" and (code != 0 or "controller" not in dead)}
            if lost:  # a death by signal named, with the FMI call in progress where the log's faulthandler dump has one
                fmu = plan.env_for("plant").get("RALF_MODEL", "").removeprefix("fmu:") if "plant" in lost else ""
                sup.failure = ", ".join(death_line(name, code, sup.procs[name].log_path, fmu if name == "plant" else None) for name, code in lost.items())
                # The controller's own policy for a lost plant (or DSP) acts first, bounded (workbench/loss_grace.py)
                answered = sup.ready_at is not None and lost.keys() <= grace.keys()
                if acting_until is None and "controller" not in dead and answered:
                    acting_until = now + max(grace[name] for name in lost)
                    sup.policy_grace_s = acting_until - now
                elif acting_until is None or "controller" in dead:
                    if not answered and dead.get("controller", 0) != 0:  # died along, not as its policy's answer
                        sup.failure += ", " + death_line("controller", dead["controller"], sup.procs["controller"].log_path)
                    break
                elif now >= acting_until:
                    sup.failure += f"; the controller did not end its run within {sup.policy_grace_s:.1f} s of it"
                    break
            elif "controller" in dead:
                if dead["controller"] != 0:
                    sup.failure = death_line("controller", dead["controller"], sup.procs["controller"].log_path)
                break
            if stop.is_set():
                break
            if acting_until is not None:  # the controller ends its run within its timeouts: no other end meanwhile
                stop.wait(poll_s)
                continue
            if run_for_s is not None and sup.ready_at is not None and now - sup.ready_at >= run_for_s:
                break
            if timeout_s is not None and now - sup.started > timeout_s:
                sup.failure = f"no end after {timeout_s:.0f} s wall time ({'running' if sup.ready_at else 'no controller tick seen'})"
                break
            if startup_timeout_s is not None and sup.ready_at is None and now - sup.started > startup_timeout_s:
                sup.failure = f"no controller tick within {startup_timeout_s:.0f} s of the launch"
                break
            stop.wait(poll_s)
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        sup.ended_at = time.monotonic()
        if interrupted or stop.is_set():
            sup.exit_codes.update(stop_all(sup.procs, INTERRUPT_STOP_S))
        else:
            for name in STOP_ORDER:
                if name in sup.procs:
                    sup.exit_codes[name] = stop_service(sup.procs[name], stop_timeout_s)
                    if name == "controller":
                        time.sleep(0.3)  # its final status and health
    return sup


INTERRUPT_STOP_S = 1.2
"""After a Ctrl-C or a stop request: how long the services get, all at
once, to end on SIGTERM before SIGKILL (a service compiling its kernels
cannot answer until the compiler returns)."""


def stop_all(procs: Mapping[str, ServiceProcess], timeout_s: float = INTERRUPT_STOP_S) -> dict[str, int]:
    """SIGTERM every service at once (in :data:`STOP_ORDER`), wait up to
    ``timeout_s`` in all, SIGKILL the rest; their exit codes."""
    order = [name for name in STOP_ORDER if name in procs]
    for name in order:
        if procs[name].popen.poll() is None:
            procs[name].popen.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + timeout_s
    codes = {}
    for name in order:
        popen = procs[name].popen
        try:
            popen.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            popen.kill()
            popen.wait()
        codes[name] = int(popen.returncode)
    return codes


def plan_problems(plan: RigPlan) -> list[str]:
    """What would go wrong before anything starts: a ``RALF_*`` variable no
    program reads (a retired one named with its replacements). Two outputs
    naming one file are refused before this, in every clock
    (:func:`workbench.output_paths.output_clashes`)."""
    from protocol.settings import unknown_variables

    return [line.strip() for line in unknown_variables(plan.env_for("controller"))]
