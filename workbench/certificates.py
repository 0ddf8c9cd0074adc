"""A run's own certificate authority: one certificate per role, for zenoh's
mutual TLS (``transport/link/tls`` with ``enable_mtls``).

With mutual TLS both ends of a zenoh link prove who they are: each shows a
certificate signed by the run's authority, and each end learns the other's
certificate name (its common name, the role: ``controller``, ``dsp``...).
The access rules (:mod:`service_kit.access`) name roles by certificate, so
they hold on the end that opened a link as on the end that accepted it,
and a session cannot pass for another by claiming its zenoh id.

:func:`write_role_certificates` makes the authority, signs one key pair per
role and forgets the authority's own key: nobody can sign another
certificate for the run afterwards. Keys are written owner-only. Made with
``cryptography`` (elliptic curve P-256, SHA-256 signatures).
"""

from __future__ import annotations

import datetime
import ipaddress
import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

LOOPBACK_NAMES: tuple[str, ...] = ("127.0.0.1", "::1", "localhost")
"""The host names a local rig's certificates are valid for (zenoh checks the
name it connected to against the acceptor's certificate)."""

VALID_FOR = datetime.timedelta(days=30)
"""How long a run's certificates are valid at least, from 5 minutes before
they are made (a run outliving them can no longer link anew); a longer
planned run gets certificates that cover it (:func:`validity_for`)."""

LOCKSTEP_WALL_PER_SIM = 10.0
"""A lockstep run's planned wall time per simulated second, for the
certificates' validity (lockstep runs as fast as the host allows, on a
loaded host slower than real time; an overestimate costs nothing)."""


def validity_for(run_s: float | None) -> datetime.timedelta:
    """How long a run's certificates must be valid: :data:`VALID_FOR`, or
    twice the run's planned wall time and a day, whichever is longer, so a
    node that drops out late in a long run still links anew. ``None``: a
    run of unplanned length (until stopped) gets :data:`VALID_FOR`."""
    if run_s is None or not math.isfinite(run_s) or run_s <= 0:
        return VALID_FOR
    return max(VALID_FOR, datetime.timedelta(seconds=2 * run_s) + datetime.timedelta(days=1))


def planned_run_s(duration_s: float | None, clock: str, controller_duration_s: str | None = None) -> float | None:
    """A run's planned wall time, for :func:`validity_for`: ``--duration``
    (wall seconds in real time, simulated in lockstep), else the
    controller's ``RALF_DURATION_S`` (simulated); None when neither bounds it."""
    sim = duration_s
    if sim is None and controller_duration_s:
        try:
            sim = float(controller_duration_s)
        except ValueError:
            return None
    if sim is None:
        return None
    return sim * LOCKSTEP_WALL_PER_SIM if clock == "lockstep" else sim


CA_FILE = "ca.pem"


@dataclass(frozen=True)
class RoleCertificate:
    """The three files a session of one role needs: the run's authority, its
    own certificate and its private key."""

    ca: Path
    certificate: Path
    key: Path

    def env(self) -> dict[str, str]:
        """The settings that make a session use these files (``RALF_ZENOH_TLS_*``)."""
        return {"RALF_ZENOH_TLS_CA": str(self.ca), "RALF_ZENOH_TLS_CERTIFICATE": str(self.certificate), "RALF_ZENOH_TLS_KEY": str(self.key)}


def _subject_names(hosts: Iterable[str]) -> list[x509.GeneralName]:
    names: list[x509.GeneralName] = []
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return names


def _write_new(path: Path, data: bytes) -> None:
    """Write a file that must not exist yet (nor be a link), owner-only."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)


def write_role_certificates(
    directory: str | Path,
    roles: Iterable[str],
    hosts: Iterable[str] = LOOPBACK_NAMES,
    valid_for: datetime.timedelta = VALID_FOR,
    now: datetime.datetime | None = None,
    hosts_of: Mapping[str, Iterable[str]] | None = None,
) -> dict[str, RoleCertificate]:
    """A fresh authority (``ca.pem``) and, per role, ``ROLE.pem`` (common
    name = the role, valid for ``hosts``, for both ends of a link) and
    ``ROLE.key``. ``hosts_of``: other host names for some roles (none: a
    certificate that only opens links, as a client of a router does).
    Every file is new (an existing file or a link in its
    place is an error, never overwritten) and owner-only; a folder made
    here is too. The authority's key is never written."""
    out_dir = Path(directory)
    out_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
    start = (now or datetime.datetime.now(datetime.UTC)) - datetime.timedelta(minutes=5)  # a peer's clock a little behind
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "ralf-hil run authority")])
    ca = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(start + valid_for)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .sign(ca_key, hashes.SHA256())
    )
    ca_path = out_dir / CA_FILE
    _write_new(ca_path, ca.public_bytes(serialization.Encoding.PEM))
    hosts = tuple(hosts)
    usage = x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH])
    files: dict[str, RoleCertificate] = {}
    for role in roles:
        key = ec.generate_private_key(ec.SECP256R1())
        builder = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, role)]))
            .issuer_name(ca_name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(start)
            .not_valid_after(start + valid_for)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(usage, critical=False)
        )
        names = _subject_names(hosts_of[role] if hosts_of is not None and role in hosts_of else hosts)
        if names:
            builder = builder.add_extension(x509.SubjectAlternativeName(names), critical=False)
        cert = builder.sign(ca_key, hashes.SHA256())
        cert_path, key_path = out_dir / f"{role}.pem", out_dir / f"{role}.key"
        _write_new(cert_path, cert.public_bytes(serialization.Encoding.PEM))
        _write_new(key_path, key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
        files[role] = RoleCertificate(ca=ca_path, certificate=cert_path, key=key_path)
    return files
