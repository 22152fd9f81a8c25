"""``vgr doctor``: every check says what it found; a missing package or a foreign socket folder is a
problem (exit 1) with the fix, the device SDKs and ROS 2 only notes."""

from __future__ import annotations

import json

from engine.cli import doctor
from engine.cli.main import main


def test_doctor_reports_every_check_as_json(capsys):
    code = main(["doctor", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert doc["format"] == "vgr.doctor/1" and doc["exit_code"] == code
    names = [c["name"] for c in doc["checks"]]
    assert {"python", "packages", "shared memory", "private sockets", "cpu", "live view", "ros 2"} <= set(names)
    assert all(c["status"] in ("ok", "note", "problem") and c["found"] for c in doc["checks"])
    assert code == (1 if any(c["status"] == "problem" for c in doc["checks"]) else 0)


def test_a_missing_package_is_a_problem_with_its_install_command(monkeypatch):
    monkeypatch.setattr(doctor, "REQUIRED", (*doctor.REQUIRED, "no-such-package-xyz"))
    (packages, *_) = doctor.check_packages()
    assert packages.status == "problem" and packages.fix == "pip install no-such-package-xyz"


def test_a_socket_folder_others_can_open_is_a_problem(tmp_path, monkeypatch):
    folder = tmp_path / "vgr"
    folder.mkdir(mode=0o777)
    folder.chmod(0o777)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    check = doctor.check_private_sockets()
    assert check.status == "problem" and "0700" in check.found and check.fix


def test_small_shared_memory_and_a_taken_port_are_notes(tmp_path):
    import socket

    assert doctor.check_shared_memory(tmp_path / "none").status == "note"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        assert doctor.check_view_port(port).status == "note"
