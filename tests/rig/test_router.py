"""service_kit.router, the compose override's zenoh router, on the
configuration `ralf-hil credentials` writes: mutual TLS both ways (a client
with the run's certificate and its password opens a session; a wrong
password, a certificate of another authority, a plain TCP client, and a
client that does not trust the router's certificate are refused with a line
that says so), writes its ready file, stops on SIGTERM with exit 0; bad
input gets one line and exit 2. And a client waiting for its router logs
once, not at every try, and stops when asked."""

from __future__ import annotations

import json
import logging
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from protocol.errors import TransportError
from protocol.settings import CommonSettings, load_settings
from service_kit import transport
from service_kit.readiness import check
from service_kit.router import load_router_config
from service_kit.transport import open_zenoh
from workbench.cli import write_compose_access
from workbench.launcher import free_tcp_port

ROOT = Path(__file__).resolve().parents[2]


def _router_files(tmp_path: Path, port: int, folder: str = "secrets") -> tuple[Path, dict[str, str]]:
    files = write_compose_access(tmp_path / folder, "routed", mounted_at=str(tmp_path / folder))
    config = json.loads(files["router"].read_text())
    config["listen"]["endpoints"] = [f"tls/127.0.0.1:{port}"]
    files["router"].write_text(json.dumps(config))
    variables = dict(line.split("=", 1) for line in files["env"].read_text().splitlines())
    return files["router"], variables


def _client(port: int, user: str, password: str, tls: dict[str, str] | None = None, scheme: str = "tls") -> CommonSettings:
    """A client as compose starts one; ``tls``: its certificate variables of ralf.env (role PLANT), None: no TLS."""
    values = {"rig_id": "routed", "zenoh_mode": "client", "zenoh_connect": f"{scheme}/127.0.0.1:{port}", "zenoh_user": user, "zenoh_password": password}
    if tls is not None:
        values.update(
            zenoh_tls_ca_base64=tls["ZENOH_TLS_CA"],
            zenoh_tls_certificate_base64=tls["ZENOH_TLS_CERTIFICATE_PLANT"],
            zenoh_tls_key_base64=tls["ZENOH_TLS_KEY_PLANT"],
        )
    return load_settings(CommonSettings, values)


@pytest.mark.timeout(120)
def test_the_router_enforces_the_generated_credentials_and_stops_cleanly(tmp_path: Path) -> None:
    port = free_tcp_port()
    config, passwords = _router_files(tmp_path, port)
    ready = tmp_path / "ready"
    proc = subprocess.Popen(
        [sys.executable, "-m", "service_kit.router", str(config), "--ready-file", str(ready)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        while not check(ready)[0] and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert check(ready)[0], proc.stdout.read() if proc.poll() is not None and proc.stdout else "no ready file"
        session = open_zenoh(_client(port, "plant", passwords["ZENOH_PASSWORD_PLANT"], passwords), retry_for_s=10.0)
        session.close()
        _, other = _router_files(tmp_path, port, "other")  # another run's authority
        refused = {
            "a wrong password": _client(port, "plant", "not-the-password", passwords),
            "a certificate of another authority": _client(port, "plant", passwords["ZENOH_PASSWORD_PLANT"], other),
            # its own certificate is the run's, but it trusts another authority: it refuses the router
            "a client that does not trust the router": _client(
                port, "plant", passwords["ZENOH_PASSWORD_PLANT"], {**passwords, "ZENOH_TLS_CA": other["ZENOH_TLS_CA"]}
            ),
            "no TLS": _client(port, "plant", passwords["ZENOH_PASSWORD_PLANT"], None, scheme="tcp"),
        }
        for case, settings in refused.items():
            with pytest.raises(TransportError, match="refused for 0 s: .*accepts connections but refused the session"):
                open_zenoh(settings, retry_for_s=0.0)
                pytest.fail(f"{case}: the session opened")
    finally:
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out
    assert "listening on tls/127.0.0.1" in out and "ready in" in out
    assert not ready.exists()


def test_bad_router_configurations_are_one_line_and_exit_2(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no such file.*ralf-hil credentials"):
        load_router_config(tmp_path / "missing.json5")
    (tmp_path / "garbage.json5").write_text("{ mode: ")
    with pytest.raises(ValueError, match="not a zenoh configuration"):
        load_router_config(tmp_path / "garbage.json5")
    (tmp_path / "client.json5").write_text('{ mode: "client" }')
    with pytest.raises(ValueError, match="not 'router'"):
        load_router_config(tmp_path / "client.json5")
    config, _ = _router_files(tmp_path, free_tcp_port())
    (tmp_path / "secrets" / "zenoh-credentials.txt").unlink()  # the mounted credentials file is missing
    proc = subprocess.run([sys.executable, "-m", "service_kit.router", str(config)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "cannot start the router" in proc.stderr and "Traceback" not in proc.stderr
    missing = subprocess.run([sys.executable, "-m", "service_kit.router", str(tmp_path / "nope.json5")], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and missing.stderr.count("\n") == 1 and "no such file" in missing.stderr


def test_a_client_waiting_for_its_router_logs_once_not_at_every_try(caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(transport, "RETRY_LOG_EVERY_S", 1e9)
    settings = load_settings(CommonSettings, {"zenoh_mode": "client", "zenoh_connect": f"tcp/127.0.0.1:{free_tcp_port()}"})
    tries: list[float] = []
    with caplog.at_level(logging.WARNING, logger="service_kit.transport"), pytest.raises(TransportError, match="nothing answered"):
        open_zenoh(settings, retry_for_s=1.0, sleep=tries.append)
    assert len(tries) >= 1
    assert len(caplog.records) == 1 and "retrying for up to" in caplog.records[0].getMessage()


def test_a_stop_request_ends_the_wait_for_the_router() -> None:
    settings = load_settings(CommonSettings, {"zenoh_mode": "client", "zenoh_connect": f"tcp/127.0.0.1:{free_tcp_port()}"})
    stop = threading.Event()
    stop.set()
    with pytest.raises(TransportError, match="stopped while waiting"):
        open_zenoh(settings, retry_for_s=3600.0, stop=stop)


def test_zenoh_reads_the_router_file_the_override_opens(tmp_path: Path) -> None:
    config, _ = _router_files(tmp_path, free_tcp_port())
    assert json.loads(load_router_config(config).get_json("mode")) == "router"
    assert isinstance(zenoh.Config.from_file(str(config)), zenoh.Config)
