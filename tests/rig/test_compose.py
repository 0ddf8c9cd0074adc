"""docker-compose.yml, tested as far as a machine without a Docker engine
allows: it parses, names real commands and valid settings, and the three
services started as local processes with exactly the compose environment
(router host mapped to a local zenoh router) run the rig and stop cleanly."""

from __future__ import annotations

import base64
import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
import yaml
import zenoh

from protocol.keys import Keys
from protocol.messages import ControllerStatus, decode
from protocol.settings import ControllerSettings, DspSettings, PlantSettings
from service_kit.readiness import parse_ready_line
from workbench.launcher import free_tcp_port

ROOT = Path(__file__).resolve().parents[2]
MODELS = {"dsp": DspSettings, "plant": PlantSettings, "controller": ControllerSettings}
COMMANDS = {"ralf-dsp": "dsp_service", "ralf-plant": "plant_emulator", "ralf-controller": "controller"}


def _compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def test_compose_file_describes_router_and_three_services() -> None:
    doc = _compose()
    services = doc["services"]
    assert set(services) == {"zenoh-router", "dsp", "plant", "controller", "live"}
    live = services["live"]  # the live view: only with --profile live, as the tool role, the host's loopback only
    assert live["profiles"] == ["live"] and live["command"] == ["ralf-hil", "live"] and live["environment"]["RALF_ZENOH_USER"] == "tool"
    assert live["environment"]["LIVE_ADDRESS"] == "0.0.0.0:8765" and live["ports"] == ["127.0.0.1:${LIVE_PORT:-8765}:8765"]
    assert live["environment"]["RALF_ZENOH_TLS_KEY_BASE64"].startswith("${ZENOH_TLS_KEY_TOOL:?")  # the tool's own certificate
    assert live["build"]["dockerfile"] == "Dockerfile.tools" and "COPY workbench " in (ROOT / "Dockerfile.tools").read_text()
    router = services["zenoh-router"]
    assert router["image"].startswith("eclipse/zenoh")
    # the router reads the configuration `ralf-hil credentials` writes into ./secrets
    assert router["command"][:2] == ["-c", "/etc/ralf/zenoh-router.json5"] and "./secrets:/etc/ralf:ro" in router["volumes"]
    from workbench.cli import COMPOSE_PASSWORD_VARS

    for name in MODELS:
        env = services[name]["environment"]
        assert env["RALF_ZENOH_USER"] == name and env["RALF_ZENOH_PASSWORD"].startswith("${" + COMPOSE_PASSWORD_VARS[name] + ":?")
        # mutual TLS: the run's authority, the role's own certificate and key (base64, from ralf.env)
        suffix = COMPOSE_PASSWORD_VARS[name].removeprefix("ZENOH_PASSWORD_")
        assert env["RALF_ZENOH_TLS_CA_BASE64"].startswith("${ZENOH_TLS_CA:?")
        assert env["RALF_ZENOH_TLS_CERTIFICATE_BASE64"].startswith("${ZENOH_TLS_CERTIFICATE_" + suffix + ":?")
        assert env["RALF_ZENOH_TLS_KEY_BASE64"].startswith("${ZENOH_TLS_KEY_" + suffix + ":?")
    for name, model in MODELS.items():
        svc = services[name]
        assert svc["command"][0] in COMMANDS
        assert COMMANDS[svc["command"][0]] == {"dsp": "dsp_service", "plant": "plant_emulator", "controller": "controller"}[name]
        env = svc["environment"]
        assert env["RALF_ZENOH_MODE"] == "client"
        assert env["RALF_ZENOH_CONNECT"] == "tls/zenoh-router:7447"
        for var in env:
            field = var.removeprefix("RALF_").lower()
            assert field in model.model_fields, f"{name}: {var} is not a setting of {model.__name__}"
        pem = base64.b64encode(b"-----BEGIN CERTIFICATE-----\n").decode()  # the values compose puts there
        model(**{k.removeprefix("RALF_").lower(): pem if k.startswith("RALF_ZENOH_TLS_") else v for k, v in env.items()})  # values validate
        assert "zenoh-router" in svc["depends_on"]


def test_dockerfile_copies_only_what_the_services_need() -> None:
    text = (ROOT / "Dockerfile").read_text()
    assert "FROM python:3.11" in text
    copied = set(re.findall(r"^COPY (\w+) ", text, flags=re.M))
    assert copied == {"protocol", "service_kit", "plant_emulator", "controller", "dsp_service"}
    assert re.search(r"pip install \"?\.", text)


def _override() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.python-router.yml").read_text())


def test_every_service_has_a_healthcheck_and_the_controller_starts_after_plant_and_dsp() -> None:
    services = _compose()["services"]
    for name in MODELS:
        svc = services[name]
        # the project's own cheap check, on the ready file the service writes
        assert svc["healthcheck"]["test"] == ["CMD", "python", "-m", "service_kit.readiness", svc["environment"]["RALF_READY_FILE"]]
    assert services["controller"]["depends_on"]["dsp"]["condition"] == "service_healthy"
    assert services["controller"]["depends_on"]["plant"]["condition"] == "service_healthy"
    assert "wget" in services["zenoh-router"]["healthcheck"]["test"]


def test_the_dsp_sits_in_another_network_than_the_cabinet() -> None:
    """As on another host: the DSP reaches the rig only through the router;
    the CAN bus (udp_multicast, TTL 1) spans only the cabinet's segment."""
    doc = _compose()
    assert set(doc["networks"]) == {"cabinet", "lab"}
    nets = {name: set(svc["networks"]) for name, svc in doc["services"].items()}
    assert nets == {"zenoh-router": {"cabinet", "lab"}, "dsp": {"lab"}, "plant": {"cabinet"}, "controller": {"cabinet"}, "live": {"cabinet"}}
    for name in ("plant", "controller"):
        assert doc["services"][name]["environment"]["RALF_CAN_UDP"] == "ttl=1"


def test_the_override_replaces_only_the_router_on_the_same_config() -> None:
    base, override = _compose()["services"]["zenoh-router"], _override()["services"]
    assert set(override) == {"zenoh-router"}
    router = override["zenoh-router"]
    assert router["image"] == _compose()["services"]["dsp"]["image"]
    assert router["command"][:3] == ["python", "-m", "service_kit.router"]
    assert router["command"][3] == base["command"][base["command"].index("-c") + 1]
    # strings: an override's string test replaces the base's (podman-compose appends lists)
    assert isinstance(base["healthcheck"]["test"], str) and isinstance(router["healthcheck"]["test"], str)
    assert router["healthcheck"]["test"].split()[-1] == router["command"][router["command"].index("--ready-file") + 1]


def test_the_image_warms_all_four_kernels_as_the_run_user_from_its_home() -> None:
    lines = [line.strip() for line in (ROOT / "Dockerfile").read_text().splitlines() if line.strip() and not line.startswith("#")]
    user = lines.index("USER ralf")
    home = lines.index("WORKDIR /home/ralf")
    (warm,) = [i for i, line in enumerate(lines) if "warm_up" in line]
    assert user < warm and home < warm
    for module in ("dsp_service.kernel", "plant_emulator.model.period_kernel", "controller.fast_tick", "dsp_service.arx_kernel"):
        assert f"from {module} import warm_up" in lines[warm]


def test_the_build_context_leaves_secrets_and_local_state_out() -> None:
    ignored = {line.strip() for line in (ROOT / ".dockerignore").read_text().splitlines() if line.strip() and not line.startswith("#")}
    assert {"secrets/", ".venv/", ".git/", "**/*.env", "**/zenoh-credentials.txt"} <= ignored
    assert "COPY . " not in (ROOT / "Dockerfile").read_text()


@pytest.mark.parametrize("module", ["plant_emulator", "controller", "dsp_service"])
def test_each_service_runs_without_the_launcher(module: str) -> None:
    """What the image holds is enough: the service starts (--help) with the
    launcher package and the plotting/terminal extras made unimportable."""
    code = (
        "import sys, runpy\n"
        "for name in ('workbench', 'matplotlib', 'rich'):\n"
        "    sys.modules[name] = None\n"
        f"sys.argv = ['{module}', '--help']\n"
        f"runpy.run_module('{module}', run_name='__main__')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "RALF_" in proc.stdout or "usage" in proc.stdout.lower()


def test_console_scripts_are_declared() -> None:
    import tomllib

    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    for command, module in COMMANDS.items():
        assert scripts[command] == f"{module}.__main__:main"


@pytest.mark.timeout(120)
def test_services_run_with_the_compose_environment(tmp_path: Path) -> None:
    doc = _compose()
    port = free_tcp_port()
    rig_id = f"compose-{uuid.uuid4().hex[:6]}"
    # The router as compose runs it: the configuration `ralf-hil credentials`
    # writes (authentication of every client, the rig's access rules), on loopback.
    from workbench.cli import write_compose_access

    files = write_compose_access(tmp_path / "secrets", rig_id)
    router_cfg = zenoh.Config.from_file(str(files["router"]))
    router_cfg.insert_json5("listen/endpoints", json.dumps([f"tls/127.0.0.1:{port}"]))
    router_cfg.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(files["credentials"])))
    secrets = tmp_path / "secrets"  # the container's /etc/ralf
    for option, name in (("root_ca_certificate", "ca.pem"), ("listen_certificate", "router.pem"), ("listen_private_key", "router.key")):
        router_cfg.insert_json5(f"transport/link/tls/{option}", json.dumps(str(secrets / name)))
    passwords = dict(line.split("=", 1) for line in files["env"].read_text().splitlines())
    router = zenoh.open(router_cfg)
    statuses: queue.Queue[ControllerStatus] = queue.Queue()
    sub = router.declare_subscriber(Keys(rig_id).controller_status, lambda s: statuses.put(decode(ControllerStatus, s.payload.to_bytes())))
    procs: dict[str, subprocess.Popen[bytes]] = {}
    can_port = str(40000 + uuid.uuid4().int % 20000)  # this rig's own CAN "wire"
    try:
        for name in ("dsp", "plant", "controller"):
            svc = doc["services"][name]
            env = {k: v for k, v in os.environ.items() if not k.startswith("RALF_")}
            env.update({k: re.sub(r"\$\{(\w+)(:\?[^}]*)?\}", lambda m: passwords[m.group(1)], str(v)) for k, v in svc["environment"].items()})
            env["RALF_ZENOH_CONNECT"] = env["RALF_ZENOH_CONNECT"].replace("zenoh-router:7447", f"127.0.0.1:{port}")  # a name of the router's certificate
            env["RALF_RIG_ID"] = rig_id
            env["RALF_CAN_PORT"] = can_port
            env["RALF_READY_FILE"] = str(tmp_path / f"{name}.ready")  # the container's /tmp/ralf-ready
            cmd = svc["command"]
            exe = shutil.which(cmd[0]) or ""
            argv = [exe, *cmd[1:]] if exe else [sys.executable, "-m", COMMANDS[cmd[0]], *cmd[1:]]
            log = open(tmp_path / f"{name}.log", "wb")
            procs[name] = subprocess.Popen(argv, env=env, stdout=log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 60
        last = None
        while time.monotonic() < deadline:
            try:
                last = statuses.get(timeout=1.0)
            except queue.Empty:
                continue
            if last.interrupts >= 5:
                break
        logs = {n: (tmp_path / f"{n}.log").read_text(errors="replace") for n in procs}
        assert last is not None and last.interrupts >= 5, logs
        for name, svc in doc["services"].items():
            if name in procs:  # the compose healthcheck's command, on this process's ready file
                test = [a.replace(svc["environment"]["RALF_READY_FILE"], str(tmp_path / f"{name}.ready")) for a in svc["healthcheck"]["test"][1:]]
                assert subprocess.run([sys.executable, *test[1:]], capture_output=True, timeout=60).returncode == 0, name
        for name in procs:
            ready = parse_ready_line((tmp_path / f"{name}.log").read_text(errors="replace"))
            assert ready is not None, logs[name]
    finally:
        for name in ("controller", "plant", "dsp"):
            if name in procs and procs[name].poll() is None:
                procs[name].send_signal(signal.SIGTERM)
        codes = {}
        for name, p in procs.items():
            try:
                codes[name] = p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                codes[name] = "killed"
        sub.undeclare()
        router.close()
    assert codes == {"dsp": 0, "plant": 0, "controller": 0}, {n: (tmp_path / f"{n}.log").read_text(errors="replace")[-2000:] for n in procs}
    assert not any((tmp_path / f"{n}.ready").exists() for n in procs)  # removed at exit


@pytest.mark.skipif(shutil.which("docker-compose") is None, reason="docker-compose (Debian's package) is not installed; .ci/run installs it")
def test_docker_compose_itself_accepts_the_file_with_generated_credentials(tmp_path: Path) -> None:
    """A real compose parser (``docker-compose config``), not only YAML: the
    file resolves with the env file ``ralf-hil credentials`` writes, and
    refuses to resolve without it (the passwords are mandatory)."""
    out = tmp_path / "secrets"
    assert subprocess.run([sys.executable, "-m", "workbench", "credentials", "--out", str(out)], capture_output=True, check=False).returncode == 0
    compose = ["docker-compose", "-f", str(ROOT / "docker-compose.yml")]
    ok = subprocess.run([*compose, "--env-file", str(out / "ralf.env"), "config"], capture_output=True, text=True, check=False)
    assert ok.returncode == 0, ok.stderr
    resolved = yaml.safe_load(ok.stdout)
    assert set(resolved["services"]) == {"zenoh-router", "dsp", "plant", "controller", "live"}
    assert all(svc["environment"]["RALF_ZENOH_PASSWORD"] for name, svc in resolved["services"].items() if name != "zenoh-router")
    controller = resolved["services"]["controller"]
    assert controller["depends_on"]["plant"]["condition"] == "service_healthy" and "healthcheck" in controller
    both = [*compose, "-f", str(ROOT / "docker-compose.python-router.yml"), "--env-file", str(out / "ralf.env"), "config"]
    merged = subprocess.run(both, capture_output=True, text=True, check=False)
    assert merged.returncode == 0, merged.stderr
    router = yaml.safe_load(merged.stdout)["services"]["zenoh-router"]
    assert "service_kit.router" in router["command"] and "service_kit.readiness" in str(router["healthcheck"]["test"])
    bare = subprocess.run([*compose, "config"], capture_output=True, text=True, check=False, env={**os.environ, "ZENOH_PASSWORD_DSP": ""})
    assert bare.returncode != 0 and "ralf-hil credentials" in bare.stderr
