"""The recipe's ``security:`` block: which certificates each process uses, checked before a run.

With the block, every process of the recipe talks zenoh over TLS or QUIC only, with mutual TLS
(each side shows a certificate signed by the recipe's CA; the Common Name is the process's name),
and with an access-control list, default deny, built from the graph (engine.transport.acl). Without it, a
single-process run opens no listener and processes on one host talk over unix sockets in a folder
only their user can open (engine.transport.endpoints.private_socket_dir). docs/security.md has the threat
model.

Example::

    security:
      certs: certs/            # ca.pem, <process>.pem / <process>.key (`vgr certs make` writes them)
      observers: [dashboard]   # certificates (CN) that may subscribe, read-only

Paths are relative to the recipe's folder. ``ca`` and ``processes.<name>.cert|key`` name files
elsewhere (a plant's own PKI).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

#: endpoint protocols that carry TLS (zenoh's ``tls`` over TCP, ``quic`` over UDP)
SECURE_PROTOCOLS = ("tls", "quic")


class IdentityFiles(BaseModel):
    model_config = ConfigDict(extra="forbid")

    cert: str
    key: str


class SecuritySettings(BaseModel):
    """TLS/mTLS and access control for every process of the recipe."""

    model_config = ConfigDict(extra="forbid")

    certs: str = Field("certs", description="folder with ca.pem and <process>.pem/.key (relative to the recipe)")
    ca: str | None = Field(None, description="the CA certificate (default: <certs>/ca.pem)")
    processes: dict[str, IdentityFiles] = Field(
        default_factory=dict, description="certificate and key of a process, when not <certs>/<process>.pem/.key"
    )
    observers: list[str] = Field(
        default_factory=list, description="Common Names of certificates that may subscribe to the run, read-only"
    )

    controllers: list[str] = Field(
        default_factory=list,
        description="Common Names of certificates that may call a cell service's API (vgr serve): robot controllers",
    )

    @field_validator("observers", "controllers")
    @classmethod
    def _observer_names(cls, v: list[str]) -> list[str]:
        bad = [n for n in v if not n or "/" in n or n.startswith(("_", "."))]
        if bad:
            raise ValueError(f"names {bad} must be plain certificate Common Names")
        return v


@dataclass(frozen=True)
class ProcessIdentity:
    """The files one process presents and trusts, resolved to absolute paths."""

    process: str
    ca: Path
    cert: Path
    key: Path


def folder_identity(folder: Path, name: str, ca: Path | None = None) -> ProcessIdentity:
    """*name*'s files in a `vgr certs make` folder: ``<name>.pem``, ``<name>.key`` and ``ca.pem``
    (unless *ca* names another CA certificate)."""
    return ProcessIdentity(name, ca or folder / "ca.pem", folder / f"{name}.pem", folder / f"{name}.key")


def identity(sec: SecuritySettings, process: str, base: Path, certs_dir: str | None = None) -> ProcessIdentity:
    """Where *process*'s CA, certificate and key are (*certs_dir*: a command-line override)."""
    folder = (base / (certs_dir or sec.certs)).resolve()
    ca = (base / sec.ca).resolve() if sec.ca and not certs_dir else None
    ident = folder_identity(folder, process, ca)
    own = sec.processes.get(process)
    if own is not None and not certs_dir:  # the process's own files, the CA as for the others
        return replace(ident, cert=(base / own.cert).resolve(), key=(base / own.key).resolve())
    return ident


def tls_entries(ident: ProcessIdentity) -> dict[str, Any]:
    """zenoh configuration entries (path -> value) for a session that speaks TLS or QUIC only, with
    mutual TLS as *ident*."""
    return {"transport/link/tls": tls_config(ident), "transport/link/protocols": list(SECURE_PROTOCOLS)}


def tls_config(ident: ProcessIdentity) -> dict[str, object]:
    """zenoh's ``transport/link/tls`` section for *ident*: mTLS, the same identity both ways."""
    return {
        "root_ca_certificate": str(ident.ca),
        "listen_private_key": str(ident.key),
        "listen_certificate": str(ident.cert),
        "enable_mtls": True,
        "connect_private_key": str(ident.key),
        "connect_certificate": str(ident.cert),
        "verify_name_on_connect": True,
    }


def insecure_endpoints(endpoints: list[str]) -> list[str]:
    return [e for e in endpoints if e.partition("/")[0] not in SECURE_PROTOCOLS]


def identity_problems(ident: ProcessIdentity) -> list[str]:
    """What is wrong with *ident*'s files: missing, not a certificate of this process, not signed
    by the CA, a private key others can read. Empty when they can be used."""
    from engine.security.certs import common_name, signed_by  # cryptography is only loaded when checking

    problems = [
        f"{what} {p} does not exist"
        for what, p in (("CA", ident.ca), ("certificate", ident.cert), ("key", ident.key))
        if not p.is_file()
    ]
    if problems:
        return problems
    try:
        cn = common_name(ident.cert)
    except ValueError as exc:
        return [str(exc)]
    if cn != ident.process:
        problems.append(
            f"{ident.cert} is the certificate of {cn!r}, not of process {ident.process!r} (its Common Name)"
        )
    if not signed_by(ident.cert, ident.ca):
        problems.append(f"{ident.cert} is not signed by the CA {ident.ca}")
    if ident.key.stat().st_mode & 0o077:
        problems.append(f"{ident.key}: the private key can be read by other users (chmod 600 it)")
    files = (ident.ca, ident.cert, ident.key)
    for path in dict.fromkeys((*files, *(f.parent for f in files))):
        problems += foreign_write_access(path)
    return problems


def foreign_write_access(path: Path) -> list[str]:
    """Who else could replace *path* (a certificate, a key or their folder): owned by another user
    than this one (root excepted), or writable by its group or by others. A user who can write the
    CA or a key can put in their own and be trusted."""
    st = path.stat()
    me = os.geteuid()
    problems = []
    if st.st_uid not in (me, 0):
        problems.append(f"{path} belongs to user {st.st_uid}, not to this user ({me}): they could swap in their own CA")
    if st.st_mode & 0o022:
        problems.append(f"{path} can be written by its group or by others (chmod go-w it): they could swap in theirs")
    return problems
