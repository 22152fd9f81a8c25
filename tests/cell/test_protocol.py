"""The cell API's documents (engine.run.cell.protocol): requests checked, poses exact, replies valid JSON Schema."""

from __future__ import annotations

import json

import jsonschema
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from engine.run.cell import protocol
from engine.run.cell.codes import STATUS_NAMES, Status, code_of
from engine.transforms import T_from_Rt

SCHEMA = protocol.schema()


def validator(name: str) -> jsonschema.Draft202012Validator:
    return jsonschema.Draft202012Validator({"$ref": f"#/$defs/{name}", "$defs": SCHEMA["$defs"]})


def test_every_status_has_one_number_and_the_schema_lists_them_all() -> None:
    assert [code_of(name) for name in STATUS_NAMES] == list(range(len(STATUS_NAMES)))
    assert code_of("not a status") == Status.fault
    assert SCHEMA["$defs"]["reply"]["properties"]["status"]["enum"] == list(STATUS_NAMES)


def test_a_pose_document_round_trips_exactly() -> None:
    rng = np.random.default_rng(4)
    for _ in range(50):
        T = T_from_Rt(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-2, 2, 3))
        doc = protocol.pose_doc(T)
        validator("pose").validate(doc)
        assert doc["quat_xyzw"][3] >= 0
        np.testing.assert_allclose(protocol.pose_from_doc(json.loads(json.dumps(doc))), T, atol=1e-12)
        np.testing.assert_allclose(protocol.pose_from_doc({"matrix": T.tolist()}), T, atol=1e-12)


@pytest.mark.parametrize(
    ("doc", "says"),
    [
        ({"xyz_m": [0, 0, 0], "quat_xyzw": [0, 0, 0, 2]}, "unit quaternion"),
        ({"xyz_m": [0, 0], "quat_xyzw": [0, 0, 0, 1]}, "3 numbers"),
        ({"xyz_m": [0, 0, 0]}, "exactly xyz_m and quat_xyzw"),
        ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]]}, "rotation"),
        ({"matrix": [[1, 0, 0, 0]]}, "4 rows"),
        ({"xyz_m": ["a", 0, 0], "quat_xyzw": [0, 0, 0, 1]}, "pose"),
        ([1, 2, 3], "an object"),
    ],
)
def test_a_bad_pose_is_refused_with_its_reason(doc: object, says: str) -> None:
    with pytest.raises(protocol.InvalidRequest, match=says):
        protocol.pose_from_doc(doc)


@pytest.mark.parametrize(
    ("command", "payload", "says"),
    [
        ("locate", b"{", "not JSON"),
        ("locate", b"[1]", "JSON object"),
        ("locate", b"{}", "needs an 'id'"),
        ("locate", b'{"id": "a b"}', "1-64 characters"),
        ("locate", b'{"id": "x", "api": 2}', "api 2"),
        ("locate", b'{"id": "x", "count": NaN}', "not a number"),
        ("move", b"{}", "unknown command"),
        ("status", b"\xff", "not JSON"),
        ("status", b" " * (protocol.MAX_REQUEST_BYTES + 1), "at most"),
    ],
)
def test_a_malformed_request_is_refused_with_its_reason(command: str, payload: bytes, says: str) -> None:
    with pytest.raises(protocol.InvalidRequest, match=says):
        protocol.parse_request(command, payload)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300), st.sampled_from(protocol.COMMANDS))
def test_any_bytes_give_a_request_or_a_refusal_whose_reply_is_valid(payload: bytes, command: str) -> None:
    try:
        protocol.parse_request(command, payload)
    except protocol.InvalidRequest as exc:
        reply = protocol.invalid("sim", command, None, str(exc))
        validator("reply").validate(reply)
        assert reply["code"] == Status.invalid_request
        json.loads(protocol.encode(reply))  # strict JSON


def test_a_reply_with_a_result_is_valid_and_strict_json() -> None:
    T = np.eye(4)
    part = {"correction": protocol.pose_doc(T), "translation_mm": 0.0, "rotation_deg": 0.0, "targets": {}}
    result = {"frame": "base", "requested": 1, "found": 1, "pose": protocol.pose_doc(T), "parts": [part]}
    reply = protocol.reply_doc(
        "sim", "locate", "p-1", "ok", "located", cycle=3, result=result, timing_ms={"total": 1.0}
    )
    validator("reply").validate(reply)
    broken = dict(reply, result={"frame": "base"})
    with pytest.raises(jsonschema.ValidationError):
        validator("reply").validate(broken)
    with pytest.raises(ValueError, match="Out of range float"):
        protocol.encode(dict(reply, message=float("nan")))
