"""``vgr gap --camera IMAGES --board SPEC`` end to end: the report document against its JSON Schema,
the exit codes (the robot ``vgr gap``'s table), refusals as ``vgr.invalid/1`` with exit code 2 (a
wrong board spec, an empty folder, unreadable images, too few views, robot options mixed in)."""

from __future__ import annotations

import json
import string

import jsonschema
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from engine.cli.main import main
from plugins.calibration.boards.detections_file import detections_document, write_detections
from plugins.camera.board_spec import parse_board
from plugins.model_gap.camera.report import VERDICT_EXIT_CODES, schema
from plugins.model_gap.cli import EXIT_CODES
from plugins.sim.model_gap.camera_views import SIM_BOARD, simulate_detections

SCHEMA = schema()


@pytest.fixture(scope="module")
def detections_files(tmp_path_factory):
    """detections.json files of simulated views: a hidden tilted sensor, nothing hidden, 5 views."""
    folder = tmp_path_factory.mktemp("camera_gap")
    board = parse_board(SIM_BOARD)
    files = {}
    for name, effect, n in (("tilted", "tilted", 20), ("none", None, 20), ("few", None, 5)):
        views, _ = simulate_detections(effect, scale=4.0, seed=3, n_views=n)
        files[name] = folder / f"{name}.json"
        write_detections(files[name], detections_document(board, views))
    return files


def run_json(capsys, *argv: str) -> tuple[int, dict]:
    code = main(["gap", *argv, "--json"])
    out = capsys.readouterr().out
    return code, json.loads(out)  # strict JSON on stdout, whatever the outcome


def test_the_exit_codes_are_the_robot_gaps():
    assert VERDICT_EXIT_CODES == EXIT_CODES


def test_a_hidden_tilt_is_named_in_a_report_that_follows_its_schema(detections_files, capsys, tmp_path):
    code, doc = run_json(
        capsys, "--camera", str(detections_files["tilted"]), "--board", SIM_BOARD, "--report", str(tmp_path / "r")
    )
    jsonschema.validate(doc, SCHEMA)
    assert code == 0 and doc["exit_code"] == 0 and doc["verdict"] == "explained"
    assert doc["named"] == ["tilted"] and doc["effects_added"][0]["coefficients"].keys() == {"tauX", "tauY"}
    assert doc["heldout_rms_after_px"] < 0.8 * doc["heldout_rms_before_px"]
    assert doc["camera_after"]["free_coefficients"] == ["k1", "k2", "tauX", "tauY"]
    on_disk = json.loads((tmp_path / "r" / "camera_gap_report.json").read_text())
    jsonschema.validate(on_disk, SCHEMA)
    assert on_disk["files"]["detections"].endswith("detections.json")
    assert json.loads((tmp_path / "r" / "detections.json").read_text())["format"] == "vgr.board_detections/1"


def test_nothing_hidden_exits_0_with_no_gap_and_the_terminal_says_so(detections_files, capsys):
    code = main(["gap", "--camera", str(detections_files["none"]), "--board", SIM_BOARD])
    out = capsys.readouterr().out
    assert code == 0 and "verdict: no_gap" in out and "held-out reprojection RMS" in out


def invalid(capsys, *argv: str) -> dict:
    code, doc = run_json(capsys, *argv)
    assert code == 2 and doc["format"] == "vgr.invalid/1" and doc["exit_code"] == 2, doc
    return doc


def test_too_few_views_empty_folder_unreadable_images_are_refused(detections_files, capsys, tmp_path):
    assert "at least 6" in invalid(capsys, "--camera", str(detections_files["few"]), "--board", SIM_BOARD)["error"]
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "holds no images" in invalid(capsys, "--camera", str(empty), "--board", SIM_BOARD)["error"]
    broken = tmp_path / "broken"
    broken.mkdir()
    for k in range(3):
        (broken / f"im_{k}.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(k, 200)))
    assert "found in none" in invalid(capsys, "--camera", str(broken), "--board", SIM_BOARD)["error"]
    assert "no such file" in invalid(capsys, "--camera", str(tmp_path / "nope"), "--board", SIM_BOARD)["error"]


def test_robot_options_and_a_missing_board_are_refused(detections_files, capsys):
    f = str(detections_files["none"])
    assert "--model" in invalid(capsys, "--camera", f, "--board", SIM_BOARD, "--model", "ur5e")["error"]
    assert "--noise-mm" in invalid(capsys, "--camera", f, "--board", SIM_BOARD, "--noise-mm", "0.1")["error"]
    assert "--board" in invalid(capsys, "--camera", f)["error"]
    assert "--folds" in invalid(capsys, "--camera", f, "--board", SIM_BOARD, "--folds", "1")["error"]
    assert "--model and --data" in invalid(capsys, "--report", "x")["error"]


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(spec=st.one_of(
    st.text(string.ascii_letters + string.digits + ":x.", max_size=30),
    st.builds(lambda c, r, s: f"chessboard:{c}x{r}:{s}mm", st.integers(-3, 40), st.integers(-3, 40), st.integers(0, 99)),
))  # fmt: skip
def test_any_other_board_spec_is_refused_as_invalid_json(detections_files, capsys, spec):
    if spec.strip() and spec == SIM_BOARD:
        return
    doc = invalid(capsys, "--camera", str(detections_files["none"]), "--board", spec)
    assert "board" in doc["error"].lower()
