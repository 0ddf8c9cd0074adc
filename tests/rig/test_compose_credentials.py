"""`ralf-hil credentials`: the compose rig's authority and certificates (the
router's valid for its names, the clients' for none), certificates that
cover the planned run, owner-only files made fresh each time, and the
inline (base64) TLS settings the services read from compose's environment.
The links themselves (mutual TLS both ways through the router) are held by
tests/rig/test_router.py and tests/rig/test_compose.py."""

from __future__ import annotations

import base64
import datetime
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import NameOID

from protocol.errors import ConfigError
from protocol.settings import CommonSettings, load_settings
from service_kit.transport import zenoh_config
from workbench.certificates import VALID_FOR
from workbench.cli import COMPOSE_PASSWORD_VARS, write_compose_access

ROOT = Path(__file__).resolve().parents[2]
ROLES = tuple(COMPOSE_PASSWORD_VARS)


def _cert(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def _names(cert: x509.Certificate) -> set[str]:
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return set()
    return {str(n.value) for n in san}


def _env(path: Path) -> dict[str, str]:
    return dict(line.split("=", 1) for line in path.read_text().splitlines())


def test_the_router_and_each_role_get_a_certificate_of_one_fresh_authority(tmp_path: Path) -> None:
    files = write_compose_access(tmp_path / "secrets", router_hosts=("dsp-host.lab", "10.0.0.7"))
    out = tmp_path / "secrets"
    ca = _cert(out / "ca.pem")
    for role in ("router", *ROLES):
        cert = _cert(out / f"{role}.pem")
        cert.verify_directly_issued_by(ca)
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
    # the router is valid for its service name, the host's loopback and the names given; a client for none
    assert _names(_cert(out / "router.pem")) == {"zenoh-router", "localhost", "127.0.0.1", "::1", "dsp-host.lab", "10.0.0.7"}
    assert all(_names(_cert(out / f"{role}.pem")) == set() for role in ROLES)
    router = files["router"].read_text()
    assert '"tls/0.0.0.0:7447"' in router and '"enable_mtls": true' in router and '"cert_common_names"' in router and '"usernames"' not in router


def test_the_certificates_cover_the_planned_run(tmp_path: Path) -> None:
    made = datetime.datetime.now(datetime.UTC)
    write_compose_access(tmp_path / "default")
    assert _cert(tmp_path / "default" / "router.pem").not_valid_after_utc - made >= VALID_FOR - datetime.timedelta(minutes=6)
    run_s = 90 * 86400.0  # a 90-day soak run
    write_compose_access(tmp_path / "soak", run_s=run_s)
    wanted = made + datetime.timedelta(seconds=2 * run_s) + datetime.timedelta(days=1) - datetime.timedelta(minutes=6)
    for name in ("ca.pem", "router.pem", *(f"{r}.pem" for r in ROLES)):
        assert _cert(tmp_path / "soak" / name).not_valid_after_utc >= wanted, name
    # the command line: --duration, and the date it prints
    proc = subprocess.run(
        [sys.executable, "-m", "workbench", "credentials", "--out", str(tmp_path / "cli"), "--duration", str(run_s)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    until = _cert(tmp_path / "cli" / "ca.pem").not_valid_after_utc
    assert until >= wanted and f"valid until {until:%Y-%m-%d %H:%M} UTC" in " ".join((proc.stdout + proc.stderr).split())
    bad = subprocess.run(
        [sys.executable, "-m", "workbench", "credentials", "--out", str(tmp_path / "x"), "--duration", "-5"], capture_output=True, text=True, timeout=120
    )
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "Traceback" not in bad.stderr


def test_every_file_is_owner_only_and_a_second_run_replaces_them(tmp_path: Path) -> None:
    out = tmp_path / "secrets"
    write_compose_access(out)
    first = (out / "ca.pem").read_bytes()
    assert stat.S_IMODE(out.stat().st_mode) == 0o700
    assert {stat.S_IMODE(p.stat().st_mode) for p in out.iterdir()} == {0o600}
    victim = tmp_path / "victim"
    victim.write_text("keep me\n")
    (out / "ralf.env").unlink()
    (out / "ralf.env").symlink_to(victim)  # a link planted where a file is written: replaced, never followed
    write_compose_access(out)
    assert victim.read_text() == "keep me\n" and not (out / "ralf.env").is_symlink()
    assert (out / "ca.pem").read_bytes() != first  # a new authority
    (out / "tool.env").unlink()
    (out / "tool.env").mkdir()
    proc = subprocess.run([sys.executable, "-m", "workbench", "credentials", "--out", str(out)], capture_output=True, text=True, timeout=120)
    said = proc.stdout + proc.stderr
    assert proc.returncode == 2 and "is in the way" in said and "Traceback" not in said


def test_ralf_env_gives_each_service_its_certificate_inline(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "secrets"
    write_compose_access(out)
    env = _env(out / "ralf.env")
    assert base64.b64decode(env["ZENOH_TLS_CA"]) == (out / "ca.pem").read_bytes()
    for role, var in COMPOSE_PASSWORD_VARS.items():
        suffix = var.removeprefix("ZENOH_PASSWORD_")
        assert base64.b64decode(env[f"ZENOH_TLS_CERTIFICATE_{suffix}"]) == (out / f"{role}.pem").read_bytes()
        assert base64.b64decode(env[f"ZENOH_TLS_KEY_{suffix}"]) == (out / f"{role}.key").read_bytes()
    for name in [k for k in os.environ if k.startswith("RALF_")]:
        monkeypatch.delenv(name)
    settings = load_settings(
        CommonSettings,
        {
            "zenoh_mode": "client",
            "zenoh_connect": "tls/zenoh-router:7447",
            "zenoh_tls_ca_base64": env["ZENOH_TLS_CA"],
            "zenoh_tls_certificate_base64": env["ZENOH_TLS_CERTIFICATE_DSP"],
            "zenoh_tls_key_base64": env["ZENOH_TLS_KEY_DSP"],
        },
    )
    tls = settings.zenoh_tls()
    assert tls is not None and tls[1] and tls[0][2] == env["ZENOH_TLS_KEY_DSP"]
    assert env["ZENOH_TLS_KEY_DSP"] not in repr(settings) and env["ZENOH_TLS_KEY_DSP"] not in settings.model_dump_json()  # never shown or recorded
    zenoh_config(settings)  # zenoh takes the *_base64 options
    tool = _env(out / "tool.env")
    assert tool["RALF_ZENOH_CONNECT"] == "tls/127.0.0.1:7447" and Path(tool["RALF_ZENOH_TLS_KEY"]) == (out / "tool.key").resolve()


@pytest.mark.parametrize(
    ("values", "said"),
    [
        ({"zenoh_tls_key_base64": "not base64!"}, "RALF_ZENOH_TLS_KEY_BASE64: Value error, not base64"),
        ({"zenoh_tls_key_base64": base64.b64encode(b"plain text").decode()}, "RALF_ZENOH_TLS_KEY_BASE64: Value error, base64, but not of a PEM file"),
        ({"zenoh_tls_certificate_base64": "", "zenoh_tls_key_base64": ""}, "RALF_ZENOH_TLS_CERTIFICATE_BASE64, RALF_ZENOH_TLS_KEY_BASE64 not set"),
        ({"zenoh_tls_ca": "/etc/hostname"}, "both as files (RALF_ZENOH_TLS_CA) and inline"),
        ({"zenoh_connect": "tcp/zenoh-router:7447"}, "every zenoh endpoint must be tls/"),
    ],
)
def test_bad_inline_tls_settings_are_one_clear_line(values: dict[str, str], said: str, monkeypatch: pytest.MonkeyPatch) -> None:
    for name in [k for k in os.environ if k.startswith("RALF_")]:
        monkeypatch.delenv(name)
    pem = base64.b64encode(b"-----BEGIN CERTIFICATE-----\nAA==\n-----END CERTIFICATE-----\n").decode()
    base = {
        "zenoh_mode": "client",
        "zenoh_connect": "tls/zenoh-router:7447",
        "zenoh_tls_ca_base64": pem,
        "zenoh_tls_certificate_base64": pem,
        "zenoh_tls_key_base64": pem,
    }
    with pytest.raises(ConfigError, match=said.replace("(", r"\(").replace(")", r"\)")):
        load_settings(CommonSettings, {**base, **values})
