"""Development certificates for a secured recipe: one CA, one certificate per process and observer.

``vgr certs make RECIPE --out DIR`` writes, into a new (or empty) folder:

- ``ca.pem`` (the CA's certificate) and ``ca.key`` (its private key: keep it off the cell, it can
  sign new identities);
- ``<name>.pem`` / ``<name>.key`` for every process of the recipe and every observer named in its
  ``security.observers``: an ECDSA P-256 key and a certificate whose Common Name is the name (zenoh's
  access control matches subjects by ``cert_common_names``) and whose subject alternative names are
  ``localhost``, ``127.0.0.1``, ``::1`` and every host the recipe names in that process's ``listen``
  endpoints (zenoh checks the listener's name on connect), plus any ``--host`` given.

Private keys are written with mode 0600. Everything is made with the ``cryptography`` package
(X.509 per RFC 5280). A plant with its own PKI does not use this module: it issues the same
certificates (CN = process name, SANs = the hosts) and names them in the recipe's ``security:``
block (docs/security.md).
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from engine.files import create_new

DEFAULT_DAYS = 365
LOCAL_NAMES = ("localhost", "127.0.0.1", "::1")


@dataclass(frozen=True)
class Identity:
    """Who gets a certificate: a recipe process or a read-only observer, and the hosts it serves."""

    name: str
    hosts: tuple[str, ...] = ()


def _key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _name(common_name: str) -> x509.Name:
    return x509.Name(
        [x509.NameAttribute(NameOID.ORGANIZATION_NAME, "vgr"), x509.NameAttribute(NameOID.COMMON_NAME, common_name)]
    )


def _san(hosts: Iterable[str]) -> x509.SubjectAlternativeName:
    names: list[x509.GeneralName] = []
    for h in dict.fromkeys(hosts):  # ordered, no repeats
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            names.append(x509.DNSName(h))
    return x509.SubjectAlternativeName(names)


def _validity(days: int) -> tuple[datetime.datetime, datetime.datetime]:
    now = datetime.datetime.now(datetime.UTC)
    return now - datetime.timedelta(minutes=5), now + datetime.timedelta(days=days)


def make_ca(common_name: str, days: int = DEFAULT_DAYS) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    key = _key()
    start, end = _validity(days)
    cert = (
        x509.CertificateBuilder()
        .subject_name(_name(common_name))
        .issuer_name(_name(common_name))
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(end)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True
        )  # key_cert_sign, crl_sign
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    return cert, key


def make_leaf(
    identity: Identity, ca_cert: x509.Certificate, ca_key: ec.EllipticCurvePrivateKey, days: int = DEFAULT_DAYS
) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    """A certificate for *identity*, usable as TLS server and client (zenoh peers are both)."""
    key = _key()
    start, end = _validity(days)
    cert = (
        x509.CertificateBuilder()
        .subject_name(_name(identity.name))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(end)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.KeyUsage(True, False, False, False, False, False, False, False, False), critical=True)
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False
        )
        .add_extension(_san((*LOCAL_NAMES, *identity.hosts)), critical=False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    return cert, key


def _write(path: Path, data: bytes, private: bool) -> None:
    """Create *path* (never replace one, never through a link), 0600 for private keys."""
    with create_new(path, 0o600 if private else 0o644) as f:
        f.write(data)


def _pem(cert: x509.Certificate) -> bytes:
    return cert.public_bytes(serialization.Encoding.PEM)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def write_bundle(out: Path, identities: list[Identity], *, ca_name: str, days: int = DEFAULT_DAYS) -> list[Path]:
    """Write a CA and a certificate per identity into *out* (created; must be new or empty).
    Returns the files written. Raises FileExistsError when *out* holds files."""
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise FileExistsError(f"{out} exists and is not an empty folder: certificates are only written to a new one")
    if out.exists() and (out.stat().st_uid not in (os.geteuid(), 0) or out.stat().st_mode & 0o022):
        raise PermissionError(
            f"{out} belongs to another user or others may write it: they could replace the CA and keys "
            "after they are made; use a new folder of your own"
        )
    out.mkdir(parents=True, exist_ok=True, mode=0o700)
    ca_cert, ca_key = make_ca(ca_name, days)
    written = [out / "ca.pem", out / "ca.key"]
    _write(written[0], _pem(ca_cert), private=False)
    _write(written[1], _key_pem(ca_key), private=True)
    for ident in identities:
        cert, key = make_leaf(ident, ca_cert, ca_key, days)
        pem, kfile = out / f"{ident.name}.pem", out / f"{ident.name}.key"
        _write(pem, _pem(cert), private=False)
        _write(kfile, _key_pem(key), private=True)
        written += [pem, kfile]
    return written


def common_name(cert_file: Path) -> str:
    """The Common Name of the certificate in *cert_file* (PEM); ValueError when it has none."""
    cert = x509.load_pem_x509_certificate(cert_file.read_bytes())
    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    if not names:
        raise ValueError(f"{cert_file}: the certificate has no Common Name")
    return str(names[0].value)


def signed_by(cert_file: Path, ca_file: Path) -> bool:
    """Whether the certificate in *cert_file* was issued and signed by the CA in *ca_file*."""
    cert = x509.load_pem_x509_certificate(cert_file.read_bytes())
    ca = x509.load_pem_x509_certificate(ca_file.read_bytes())
    try:
        cert.verify_directly_issued_by(ca)
    except (ValueError, TypeError, Exception):  # InvalidSignature is not a ValueError
        return False
    return True
