"""What would close the peer-mode identity gap (docs/reliability.md, "Open"): with mutual TLS,
both ends of a zenoh link know the other's certificate name, so access rules keyed by
``cert_common_names`` alone (no zenoh ids) hold on the connector's end too, and a session that
takes a gone node's zenoh id gets only its own certificate's rules. Three peers on loopback,
one CA and one certificate per role made with ``cryptography``; the rig itself does not use
TLS yet."""

from __future__ import annotations

import datetime
import ipaddress
import json
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh

from workbench.launcher import free_tcp_port

pytestmark = pytest.mark.rig

x509 = pytest.importorskip("cryptography.x509")


def _pki(directory: Path, names: tuple[str, ...]) -> None:
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    now = datetime.datetime.now(datetime.UTC)

    def write_key(key: Any, path: Path) -> None:
        path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "rig ca")])
    ca = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=1))
        .not_valid_after(now + datetime.timedelta(hours=1))
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    (directory / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    for name in names:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
            .issuer_name(ca_name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=1))
            .not_valid_after(now + datetime.timedelta(hours=1))
            .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
            .sign(ca_key, hashes.SHA256())
        )
        (directory / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        write_key(key, directory / f"{name}.key")


DECLARATIONS = ["declare_subscriber", "declare_queryable", "query", "declare_liveliness_subscriber", "liveliness_query"]


def _allow(rule_id: str, flow: str, messages: list[str], keys: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "flows": [flow], "messages": messages, "key_exprs": keys}


def _acl(peers: dict[str, tuple[list[str], list[str]]]) -> dict[str, Any]:
    """Deny by default; certificate name -> (keys it may put here, keys it receives from here)."""
    rules, policies = [_allow("declarations", "egress", DECLARATIONS, ["**"])], []
    for name, (sends, receives) in peers.items():
        own = [_allow(f"{name} declares", "ingress", DECLARATIONS, ["**"])]
        own += [_allow(f"{name} sends", "ingress", ["put"], sends)] if sends else []
        own += [_allow(f"{name} receives", "egress", ["put"], receives)] if receives else []
        rules += own
        policies.append({"rules": ["declarations", *(r["id"] for r in own)], "subjects": [name]})
    subjects = [{"id": name, "cert_common_names": [name]} for name in peers]
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def _session(pki: Path, name: str, endpoint: str, *, listen: bool, acl: dict[str, Any] | None = None, zid: str = "") -> zenoh.Session:
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    tls = {
        "root_ca_certificate": str(pki / "ca.pem"),
        "enable_mtls": True,
        "listen_private_key": str(pki / f"{name}.key"),
        "listen_certificate": str(pki / f"{name}.pem"),
        "connect_private_key": str(pki / f"{name}.key"),
        "connect_certificate": str(pki / f"{name}.pem"),
    }
    config.insert_json5("transport/link/tls", json.dumps(tls))
    config.insert_json5("listen/endpoints" if listen else "connect/endpoints", json.dumps([endpoint]))
    if acl is not None:
        config.insert_json5("access_control", json.dumps(acl))
    if zid:
        config.insert_json5("id", json.dumps(zid))
    return zenoh.open(config)


def _until(cond: Callable[[], bool], timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.02)
    return cond()


def test_mutual_tls_names_both_ends_of_a_link(tmp_path: Path) -> None:
    _pki(tmp_path, ("controller", "dsp", "tool"))
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    got: dict[str, list[tuple[str, bytes]]] = {"controller": [], "dsp": []}
    lock = threading.Lock()

    def into(who: str) -> Callable[[zenoh.Sample], None]:
        def on(sample: zenoh.Sample) -> None:
            with lock:
                got[who].append((str(sample.key_expr), sample.payload.to_bytes()))

        return on

    def seen(who: str, key: str, payload: bytes) -> bool:
        with lock:
            return (key, payload) in got[who]

    controller_rules = _acl({"dsp": (["r/interrupt"], ["r/status"]), "tool": (["r/command"], [])})
    controller = _session(tmp_path, "controller", endpoint, listen=True, acl=controller_rules)
    dsp_zid = "a1b2c3d4e5f60718293a4b5c6d7e8f90"
    try:
        controller.declare_subscriber("r/**", into("controller"))
        dsp = _session(tmp_path, "dsp", endpoint, listen=False, acl=_acl({"controller": (["r/status"], ["r/interrupt"])}), zid=dsp_zid)
        try:
            dsp.declare_subscriber("r/status", into("dsp"))
            links = list(dsp.info.links())
            assert links and all('auth_identifier: Some("controller")' in str(link) for link in links), [str(x) for x in links]
            # each end applies the other's certificate's rules: the acceptor's for the DSP, and the
            # connector's (the DSP's) for the controller, which it knows only by its certificate
            assert _until(lambda: (dsp.put("r/interrupt", b"real"), seen("controller", "r/interrupt", b"real"))[1])
            assert _until(lambda: (controller.put("r/status", b"status"), seen("dsp", "r/status", b"status"))[1])
        finally:
            dsp.close()
        # the DSP has gone; a tool's certificate claiming its zenoh id gets the tool's rules only
        tool = _session(tmp_path, "tool", endpoint, listen=False, zid=dsp_zid)
        try:
            assert _until(lambda: (tool.put("r/interrupt", b"forged"), tool.put("r/command", b"own"), seen("controller", "r/command", b"own"))[2])
        finally:
            tool.close()
        assert not seen("controller", "r/interrupt", b"forged")  # put before each command that arrived, on the same link
    finally:
        controller.close()
