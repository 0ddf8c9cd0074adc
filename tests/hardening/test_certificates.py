"""A run's certificates (workbench.certificates) and the mutual TLS they
give the rig in peer mode, checked with ``cryptography``'s own verification
and against a real zenoh 1.10 node configured as ``ralf-hil up`` configures
a service: only a session with a certificate of the run's authority links,
and both ends of a link know the other's role. Loopback only, scouting off."""

from __future__ import annotations

import datetime
import ipaddress
import json
import time
from pathlib import Path

import pytest
import zenoh
from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.x509.oid import NameOID

from protocol.keys import Keys
from protocol.settings import CommonSettings
from service_kit.access import insert_access
from service_kit.transport import zenoh_config
from workbench.certificates import CA_FILE, RoleCertificate, write_role_certificates
from workbench.launcher import free_tcp_port, free_tcp_ports

pytestmark = pytest.mark.rig

RIG = "tls-test"


def _load(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def test_each_role_gets_a_certificate_of_the_runs_authority_and_the_authoritys_key_is_never_written(tmp_path: Path) -> None:
    now = datetime.datetime(2026, 12, 3, tzinfo=datetime.UTC)
    files = write_role_certificates(tmp_path, ("controller", "tool"), now=now)
    assert sorted(p.name for p in tmp_path.iterdir()) == [CA_FILE, "controller.key", "controller.pem", "tool.key", "tool.pem"]
    ca = _load(tmp_path / CA_FILE)
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    for role, f in files.items():
        cert = _load(f.certificate)
        cert.verify_directly_issued_by(ca)  # cryptography's own signature check
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
        names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert ipaddress.ip_address("127.0.0.1") in names.get_values_for_type(x509.IPAddress)
        assert cert.not_valid_before_utc < now < cert.not_valid_after_utc
        assert f.key.stat().st_mode & 0o077 == 0
    other = _load(write_role_certificates(tmp_path / "other", ("tool",))["tool"].certificate)
    with pytest.raises(InvalidSignature):  # another run's certificate is not this authority's
        other.verify_directly_issued_by(ca)


def _tls(files: RoleCertificate) -> tuple[str, str, str]:
    return (str(files.ca), str(files.certificate), str(files.key))


def _client(endpoint: str) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return config


def _links_after(session: zenoh.Session, wait_s: float = 1.0) -> list[str]:
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and not list(session.info.peers_zid()):
        time.sleep(0.05)
    return [str(link) for link in session.info.links()]


def test_only_a_certificate_of_the_runs_authority_links_and_both_ends_know_the_others_role(tmp_path: Path) -> None:
    files = write_role_certificates(tmp_path / "run", ("dsp", "tool"))
    strangers = write_role_certificates(tmp_path / "other-run", ("tool",))
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    settings = CommonSettings(
        rig_id=RIG,
        zenoh_listen=endpoint,
        zenoh_acl="on",
        zenoh_tls_ca=str(files["dsp"].ca),
        zenoh_tls_certificate=str(files["dsp"].certificate),
        zenoh_tls_key=str(files["dsp"].key),
    )
    node = zenoh.open(zenoh_config(settings))
    got: list[bytes] = []
    sub = node.declare_subscriber(Keys(RIG).controller_command, lambda s: got.append(s.payload.to_bytes()))
    try:
        refused = {
            "plain tcp": _client(endpoint.replace("tls/", "tcp/")),
            "another run's certificate": insert_access(_client(endpoint), RIG, tls=_tls(strangers["tool"])),
            "no certificate of its own": _client(endpoint),
        }
        refused["no certificate of its own"].insert_json5("transport/link/tls", json.dumps({"root_ca_certificate": str(files["tool"].ca)}))
        for what, config in refused.items():
            session = zenoh.open(config)
            try:
                assert _links_after(session) == [], what
                session.put(Keys(RIG).controller_command, what.encode())
            finally:
                session.close()
        tool = zenoh.open(insert_access(_client(endpoint), RIG, tls=_tls(files["tool"])))
        try:
            links = _links_after(tool, 20.0)
            assert links and all('auth_identifier: Some("dsp")' in link for link in links), links  # the opener knows whom it reached
            accepted = [str(link) for link in node.info.links()]
            assert accepted and all('auth_identifier: Some("tool")' in link for link in accepted), accepted
            deadline = time.monotonic() + 20.0
            while b"own" not in got and time.monotonic() < deadline:
                tool.put(Keys(RIG).controller_command, b"own")
                time.sleep(0.05)
        finally:
            tool.close()
    finally:
        sub.undeclare()
        node.close()
    assert b"own" in got and not set(got) - {b"own"}, got


def test_new_files_only_owner_only_folder_and_no_link_followed(tmp_path: Path) -> None:
    folder = tmp_path / "made"
    write_role_certificates(folder, ("tool",))
    assert folder.stat().st_mode & 0o077 == 0 and all(p.stat().st_mode & 0o077 == 0 for p in folder.iterdir())
    with pytest.raises(FileExistsError):  # a second authority never overwrites the first's files
        write_role_certificates(folder, ("tool",))
    trap = tmp_path / "trap"
    trap.mkdir()
    (trap / CA_FILE).symlink_to(tmp_path / "elsewhere.pem")
    with pytest.raises(FileExistsError):
        write_role_certificates(trap, ("tool",))
    assert not (tmp_path / "elsewhere.pem").exists()


@pytest.mark.parametrize("passwords", [False, True])
def test_zenoh_adds_a_link_claiming_a_linked_id_to_that_session_unless_the_user_names_differ(tmp_path: Path, passwords: bool) -> None:
    """Why a local rig keeps passwords beside its certificates (eclipse-zenoh 1.10): where
    the controller opened its link to the DSP, a session with the tool's certificate
    claiming the DSP's zenoh id that links to the controller is added to the DSP's
    session there (zenoh limits the links a session accepts, not those beside one it
    opened), and its interrupt passes under the DSP's rules; with each role's user name
    and password it is refused. When the first case fails, zenoh compares certificates too."""
    from service_kit.access import generate_credentials, write_credentials_file

    files = write_role_certificates(tmp_path / "run", ("controller", "dsp", "tool"))
    credentials = generate_credentials(("controller", "dsp", "tool"))
    dictionary = str(write_credentials_file(tmp_path / "credentials.txt", credentials)) if passwords else ""
    endpoint, dsp_endpoint = (f"tls/127.0.0.1:{port}" for port in free_tcp_ports(2))
    keys = Keys(RIG)

    def node(role: str, **where: str) -> zenoh.Config:
        auth = {"zenoh_user": role, "zenoh_password": credentials[role], "zenoh_credentials_file": dictionary} if passwords else {}
        f = files[role]
        tls = {"zenoh_tls_ca": str(f.ca), "zenoh_tls_certificate": str(f.certificate), "zenoh_tls_key": str(f.key)}
        return zenoh_config(CommonSettings(rig_id=RIG, zenoh_acl="on", **tls, **auth, **where))  # type: ignore[arg-type]

    dsp_zid = "a1b2c3d4e5f60718293a4b5c6d7e8f90"
    dsp_config = node("dsp", zenoh_listen=dsp_endpoint)
    dsp_config.insert_json5("id", json.dumps(dsp_zid))
    dsp = zenoh.open(dsp_config)
    controller = zenoh.open(node("controller", zenoh_listen=endpoint, zenoh_connect=dsp_endpoint))  # it opens the link
    got: list[bytes] = []
    sub = controller.declare_subscriber(keys.interrupt, lambda s: got.append(s.payload.to_bytes()))
    try:
        assert _links_after(dsp, 20.0)
        deadline = time.monotonic() + 20.0
        while b"real" not in got and time.monotonic() < deadline:  # the DSP's own interrupt, under its rules
            dsp.put(keys.interrupt, b"real")
            time.sleep(0.05)
        assert b"real" in got
        attack = _client(endpoint)
        attack.insert_json5("id", json.dumps(dsp_zid))
        auth = {"user": "tool", "password": credentials["tool"]} if passwords else {}
        tool = zenoh.open(insert_access(attack, RIG, tls=_tls(files["tool"]), **auth))
        try:
            linked = _links_after(tool, 2.0)
            for _ in range(20):
                tool.put(keys.interrupt, b"forged")
                time.sleep(0.05)
        finally:
            tool.close()
    finally:
        dsp.close()
        sub.undeclare()
        controller.close()
    if passwords:
        assert linked == [] and b"forged" not in got, linked
    else:
        assert linked and b"forged" in got, linked


def test_a_run_longer_than_the_default_validity_gets_certificates_that_cover_it(tmp_path: Path) -> None:
    """A soak run of 40 days (``--duration``, or the controller's ``RALF_DURATION_S``)
    gets certificates valid for twice its planned wall time and a day; a short or
    unbounded run the default 30 days; lockstep plans its wall time generously."""
    from workbench.certificates import LOCKSTEP_WALL_PER_SIM, VALID_FOR, planned_run_s, validity_for, write_role_certificates

    day = 86400.0
    assert validity_for(None) == validity_for(60.0) == validity_for(float("nan")) == VALID_FOR
    assert planned_run_s(40 * day, "realtime") == 40 * day
    assert planned_run_s(None, "realtime", str(40 * day)) == 40 * day
    assert planned_run_s(None, "lockstep", "100") == 100 * LOCKSTEP_WALL_PER_SIM
    assert planned_run_s(None, "realtime", None) is None and planned_run_s(None, "realtime", "not a number") is None
    soak = validity_for(planned_run_s(40 * day, "realtime"))
    assert soak == datetime.timedelta(days=81)
    now = datetime.datetime(2026, 12, 7, tzinfo=datetime.UTC)
    files = write_role_certificates(tmp_path, ["dsp"], valid_for=soak, now=now)
    for path in (files["dsp"].ca, files["dsp"].certificate):
        cert = x509.load_pem_x509_certificate(path.read_bytes())
        assert cert.not_valid_after_utc - now >= datetime.timedelta(seconds=40 * day)


def test_up_provisions_certificates_for_the_planned_run(tmp_path: Path) -> None:
    from workbench.cli import provision_access
    from workbench.launcher import RigPlan

    plan = RigPlan.local(rig_id="soak-certs")
    provision_access(plan, tmp_path / "access", run_s=50 * 86400.0)
    cert = x509.load_pem_x509_certificate((tmp_path / "access" / "controller.pem").read_bytes())
    assert cert.not_valid_after_utc - cert.not_valid_before_utc >= datetime.timedelta(days=100)
