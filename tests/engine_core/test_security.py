"""Who can reach a run: nobody by default, only the recipe's certificates with `security:`.

The intruder is what the issue's attacker had: a plain zenoh-python session on the same machine,
with or without certificates, trying to find the run (liveliness), read its data, call its
services and stop it (``_control``).
"""

from __future__ import annotations

import json
import os
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
from process_helpers import env, free_port, start, vgr

from engine.security.certs import Identity, common_name, write_bundle
from engine.transport.endpoints import private_socket_dir

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(180)]

SPLIT = """
name: split
plugins: [stage_fixtures]
seed: 5
{head}
stages:
  src:   {{type: t_counter, process: producer, params: {{n: {n}, rate_hz: {rate}}}}}
  relay: {{type: t_relay, process: producer, inputs: {{in: src.out}}}}
  echo:  {{type: t_echo, process: producer}}
  call:  {{type: t_caller, process: consumer, inputs: {{in: relay.out}}, uses: {{svc: echo.echo}}}}
  sink:  {{type: t_collector, process: consumer, inputs: {{in: call.out}}, params: {{output: "{out}"}}}}
"""

INTRUDER = r"""
import json, os, sys, threading, time, zenoh  # noqa: F401 (zenoh imports threading late)
conf, prefix = json.loads(sys.argv[1]), sys.argv[2]
if len(sys.argv) > 3:  # become another user once the libraries are loaded (the venv may be root's)
    os.setuid(int(sys.argv[3]))
cfg = zenoh.Config()
for k, v in conf.items():
    cfg.insert_json5(k, json.dumps(v))
s = zenoh.open(cfg)
got = []
sub = s.declare_subscriber(
    prefix + "/**", lambda x: got.append(str(x.key_expr)), allowed_origin=zenoh.Locality.REMOTE
)
try:
    q = s.declare_queryable(prefix + "/echo/srv/echo", lambda q: q.reply(q.key_expr, b"forged"))
except Exception:
    q = None
time.sleep(1.5)
peers = len(list(s.info.peers_zid()))
replies = sum(  # the run's replies, not the forged queryable's own
    r.ok is not None and r.ok.payload.to_bytes() != b"forged" for r in s.get(prefix + "/echo/srv/echo", timeout=1.0)
)
s.put(prefix + "/_control", json.dumps({"stop": "intruder", "process": "producer"}))
tokens = [str(r.ok.key_expr) for r in s.liveliness().get(prefix + "/**", timeout=1.0) if r.ok is not None]
info = sum(r.ok is not None for r in s.get(prefix + "/_info/*", timeout=1.0))  # engine.transport.discovery
print(json.dumps({"peers": peers, "samples": len(got), "replies": replies, "tokens": tokens, "info": info}))
s.close()
"""


def intruders(tries: dict[str, dict[str, object]], prefix: str = "vgr/split", user: int | None = None) -> dict:
    """Run one intruder per entry of *tries* (name -> zenoh config), all at once, in children (as
    *user* when given), and return what each saw."""
    procs = {
        what: subprocess.Popen(
            [sys.executable, "-c", INTRUDER, json.dumps(conf), prefix, *([] if user is None else [str(user)])],
            env=env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for what, conf in tries.items()
    }
    seen = {}
    for what, p in procs.items():
        out, err = p.communicate(timeout=60)
        assert p.returncode == 0, err
        seen[what] = json.loads(out.strip().splitlines()[-1])
    return seen


def intrude(conf: dict[str, object], prefix: str = "vgr/split", user: int | None = None) -> dict[str, object]:
    return intruders({"one": conf}, prefix, user)["one"]


def wait_listening(host: str, port: int, timeout_s: float = 30.0) -> None:
    """Return once something accepts TCP connections on host:port (a run's TLS listener is up)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            socket.create_connection((host, port), timeout=1.0).close()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def plain_peer(connect: list[str]) -> dict[str, object]:
    return {"mode": "peer", "scouting/multicast/enabled": True, "connect/endpoints": connect}


def finish(*procs: subprocess.Popen[str]) -> list[str]:
    outs = []
    for p in procs:
        out, _ = p.communicate(timeout=90)
        assert p.returncode == 0, out
        outs.append(out)
    return outs


def _listening_sockets(pid: int) -> list[str]:
    """Listening TCP/UDP/unix sockets held by *pid* (from /proc)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = []
    for table in ("tcp", "tcp6"):
        for line in Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:  # LISTEN
                found.append(f"{table} {f[1]}")
    for table in ("udp", "udp6"):
        for line in Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]:
            f = line.split()
            if f[9] in inodes:
                found.append(f"{table} {f[1]}")
    for line in Path(f"/proc/{pid}/net/unix").read_text().splitlines()[1:]:
        f = line.split()
        if int(f[3], 16) & 0x10000 and f[6] in inodes:  # __SO_ACCEPTCON: a listening socket
            found.append(f"unix {f[7] if len(f) > 7 else ''}")
    return found


def test_a_single_process_run_opens_no_listener_and_cannot_be_found(tmp_path):
    recipe = tmp_path / "one.yaml"
    recipe.write_text(
        "name: one\nplugins: [stage_fixtures]\nstages:\n"
        "  src: {type: t_counter, params: {n: 400, rate_hz: 100}}\n"
        "  sink: {type: t_collector, inputs: {in: src.out}}\n"
    )
    p = subprocess.Popen(
        vgr("run", str(recipe), "--no-progress"), env=env(), cwd=tmp_path, stdout=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + 60
    while not list((tmp_path / "runs").glob("*/*.mcap")) and time.monotonic() < deadline and p.poll() is None:
        time.sleep(0.05)
    assert p.poll() is None, "the run ended before it could be looked at"
    listening = _listening_sockets(p.pid)
    seen = intrude(plain_peer([]), prefix="vgr/one")  # multicast scouting on, as an attacker would
    finish(p)  # exit 0
    assert listening == [], listening
    # scouting may meet other zenoh sessions on this machine (other programs, other tests): what
    # matters is that nothing of the run reaches it
    seen.pop("peers")
    assert seen == {"samples": 0, "replies": 0, "tokens": [], "info": 0}


def test_processes_of_one_host_meet_on_private_sockets_that_other_users_cannot_open(tmp_path):
    recipe = tmp_path / "split.yaml"
    recipe.write_text(SPLIT.format(head="", n=300, rate=100, out=tmp_path / "rows.json"))
    consumer = start(recipe, "consumer", tmp_path)
    producer = start(recipe, "producer", tmp_path)
    folder = private_socket_dir() / "split"
    deadline = time.monotonic() + 30
    while len(list(folder.glob("*.sock"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    sockets = sorted(p.name for p in folder.glob("*.sock"))
    while not (folder / "producer.links").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert (folder / "producer.links").exists()
    links = subprocess.run(  # the socket the producer takes links on (engine.transport.local_link), as nobody
        [sys.executable, "-c", LINK_INTRUDER, str(folder / "producer.links"), "65534"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    seen = intrude(plain_peer([f"unixsock-stream/{folder / 'producer.sock'}"]), user=65534)  # user nobody
    finish(consumer, producer)
    assert links.stdout.strip() == "refused", links.stdout + links.stderr
    assert sockets == ["consumer.sock", "producer.sock"]
    assert stat.S_IMODE(private_socket_dir().stat().st_mode) == 0o700
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert seen == {"peers": 0, "samples": 0, "replies": 0, "tokens": [], "info": 0}
    rows = json.loads((tmp_path / "rows.json").read_text())
    assert len(rows) == 300 and all(r["args"]["served_by"] == "echo" for r in rows)


LINK_INTRUDER = """
import os, socket, sys
os.setuid(int(sys.argv[2]))
s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
try:
    s.connect(sys.argv[1])
    print("connected")
except PermissionError:
    print("refused")
"""


def secured_recipe(tmp_path: Path, observers: tuple[str, ...] = ("watcher",), n: int = 400) -> Path:
    port = free_port()
    head = (
        f"security: {{certs: certs, observers: {list(observers)}}}\n"
        "processes:\n"
        f'  producer: {{listen: ["tls/127.0.0.1:{port}"]}}\n'
        f'  consumer: {{connect: ["tls/127.0.0.1:{port}"], listen: []}}\n'
    )
    recipe = tmp_path / "split.yaml"
    recipe.write_text(SPLIT.format(head=head, n=n, rate=100, out=tmp_path / "rows.json"))
    return recipe


def tls_peer(certs: Path, name: str | None, connect: str, ca: Path | None = None) -> dict[str, object]:
    tls: dict[str, object] = {"root_ca_certificate": str(ca or certs / "ca.pem")}
    if name is not None:
        tls |= {
            "connect_private_key": str(certs / f"{name}.key"),
            "connect_certificate": str(certs / f"{name}.pem"),
            "enable_mtls": True,
        }
    return {
        "mode": "peer",
        "scouting/multicast/enabled": False,
        "connect/endpoints": [connect],
        "transport/link/tls": tls,
    }


def test_a_secured_run_admits_only_its_certificates_and_observers_only_read(tmp_path):
    recipe = secured_recipe(tmp_path)
    made = subprocess.run(
        vgr("certs", "make", str(recipe), "--out", str(tmp_path / "certs")),
        env=env(),
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert made.returncode == 0, made.stdout + made.stderr
    ok = subprocess.run(vgr("validate", str(recipe)), env=env(), cwd=tmp_path, capture_output=True, text=True)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    other = tmp_path / "other"  # a CA the recipe does not trust, with a certificate named like a process
    write_bundle(other, [Identity("consumer")], ca_name="another CA")
    endpoint = next(line for line in recipe.read_text().splitlines() if "tls/" in line).split('"')[1]
    consumer = start(recipe, "consumer", tmp_path)
    producer = start(recipe, "producer", tmp_path)
    certs = tmp_path / "certs"
    host, port = endpoint.removeprefix("tls/").rsplit(":", 1)
    wait_listening(host, int(port))
    tries = {
        "plain tcp": plain_peer([endpoint.replace("tls/", "tcp/")]),
        "tls without a certificate": tls_peer(certs, None, endpoint),
        "another CA's consumer": tls_peer(other, "consumer", endpoint, ca=certs / "ca.pem"),
        "observer": tls_peer(certs, "watcher", endpoint),
    }
    watch = subprocess.Popen(  # the observer's certificate lets vgr topics list the secured run
        vgr(
            "topics",
            "list",
            "--json",
            "--run-id",
            "split",
            "--discovery-timeout",
            "4",
            "--connect",
            endpoint,
            "--certs",
            str(certs),
            "--identity",
            "watcher",
        ),
        env=env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    seen = intruders(tries)
    listed, why = watch.communicate(timeout=60)
    finish(consumer, producer)
    for what in ("plain tcp", "tls without a certificate", "another CA's consumer"):
        assert seen[what] == {"peers": 0, "samples": 0, "replies": 0, "tokens": [], "info": 0}, what
    assert watch.returncode == 0, why
    assert "/relay/out" in listed
    obs = seen["observer"]
    assert obs["peers"] == 1 and obs["samples"] > 0 and obs["tokens"], obs  # it may watch...
    assert obs["info"] == 1  # ...and read the description of the process it reached (topics, schemas)...
    assert obs["replies"] == 0  # ...but neither call (nor answer) a service nor stop the run:
    rows = json.loads((tmp_path / "rows.json").read_text())
    assert len(rows) == 400 and all(r["command"] == "echo" and r["args"]["served_by"] == "echo" for r in rows)
    log = next(tmp_path.glob("runs/*-split-consumer/run.log")).read_text()
    assert "over a unix socket" not in log  # every message took TLS and the access-control list


def test_validate_names_what_is_wrong_with_the_certificates(tmp_path):
    recipe = secured_recipe(tmp_path, observers=())
    certs = tmp_path / "certs"
    write_bundle(certs, [Identity("producer"), Identity("consumer")], ca_name="test CA")

    def validate() -> str:
        r = subprocess.run(vgr("validate", str(recipe)), env=env(), cwd=tmp_path, capture_output=True, text=True)
        return " ".join(f"{r.returncode} {r.stdout}{r.stderr}".split())  # rich wraps long lines

    assert validate().startswith("0 ")
    (certs / "consumer.key").chmod(0o644)
    assert "can be read by other users" in validate()
    (certs / "consumer.key").chmod(0o600)
    (certs / "producer.pem").write_bytes((certs / "consumer.pem").read_bytes())
    assert "is the certificate of 'consumer', not of process 'producer'" in validate()
    (certs / "producer.pem").unlink()
    out = validate()
    assert out.startswith("2 ") and "producer.pem does not exist" in out
    recipe.write_text(recipe.read_text().replace("tls/", "tcp/"))
    assert "endpoints must be tls or quic: tcp/127.0.0.1" in validate()


def test_certs_make_writes_one_identity_per_process_and_never_into_a_used_folder(tmp_path):
    recipe = secured_recipe(tmp_path)
    out = tmp_path / "certs"
    r = subprocess.run(
        vgr("certs", "make", str(recipe), "--out", str(out), "--host", "cell-3.plant"),
        env=env(),
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    names = {p.stem for p in out.glob("*.pem")}
    assert names == {"ca", "producer", "consumer", "watcher"}
    assert all(common_name(out / f"{n}.pem") == n for n in ("producer", "consumer", "watcher"))
    assert all(stat.S_IMODE(k.stat().st_mode) == 0o600 for k in out.glob("*.key"))
    from cryptography import x509

    san = x509.load_pem_x509_certificate((out / "producer.pem").read_bytes()).extensions.get_extension_for_class(
        x509.SubjectAlternativeName
    )
    assert "cell-3.plant" in san.value.get_values_for_type(x509.DNSName)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    again = subprocess.run(
        vgr("certs", "make", str(recipe), "--out", str(out)), env=env(), capture_output=True, text=True
    )
    assert again.returncode == 2 and "not an empty folder" in again.stdout
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_certificates_another_user_could_replace_are_refused(tmp_path):
    """A CA or key in a folder someone else owns or may write could be swapped for theirs: validate
    says so; certs make refuses such a folder before writing into it."""
    from engine.security.tls import foreign_write_access

    certs = tmp_path / "certs"
    write_bundle(certs, [Identity("producer")], ca_name="test CA")
    assert foreign_write_access(certs) == [] and foreign_write_access(certs / "ca.pem") == []
    certs.chmod(0o777)
    assert "can be written by its group or by others" in " ".join(foreign_write_access(certs))
    certs.chmod(0o700)
    if os.geteuid() != 0:
        pytest.skip("making a folder of another user needs root")
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    os.chown(theirs, 65534, 65534)
    with pytest.raises(PermissionError, match="belongs to another user"):
        write_bundle(theirs, [Identity("producer")], ca_name="test CA")
    os.chown(certs / "ca.pem", 65534, 65534)
    assert "belongs to user 65534" in " ".join(foreign_write_access(certs / "ca.pem"))


def test_the_live_view_of_a_secured_run_needs_its_own_token(tmp_path):
    recipe = secured_recipe(tmp_path, observers=())
    write_bundle(tmp_path / "certs", [Identity("producer"), Identity("consumer")], ca_name="test CA")
    r = subprocess.run(
        vgr("run", str(recipe), "--process", "producer", "--view", "0", "--json"),
        env=env(),
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "--view-token-file" in r.stderr + r.stdout, r.stdout + r.stderr
    assert json.loads(r.stdout.strip().splitlines()[-1])["outcome"] == "invalid"
    assert not (tmp_path / "runs").exists()  # refused before anything was made
