"""Every message type encodes to the bytes, and decodes to the values, it did when each class
hand-wrote its protobuf copying: message_wire_golden.json (see message_wire_samples.py) holds the
serialisation and the decoded fields (types, dtypes, shapes, contents) the hand-written code gave."""

from __future__ import annotations

import json

import pytest
from message_wire_samples import GOLDEN, samples, wire_form

from engine.messages import BUILTIN_MESSAGE_TYPES, codec
from plugins.builtin import vgr_message_types

SAMPLES = samples()
EXPECTED = json.loads(GOLDEN.read_text())


def test_every_registered_message_type_has_samples():
    sampled = {type(msg) for msg in SAMPLES.values()}
    missing = [cls.TYPE for cls in (*BUILTIN_MESSAGE_TYPES, *vgr_message_types()) if cls not in sampled]
    assert not missing, f"no sample of {missing} in message_wire_samples.py"
    assert set(SAMPLES) == set(EXPECTED), "samples and message_wire_golden.json name different messages"


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_wire_bytes_and_decoded_values_are_unchanged(name):
    got, want = wire_form(SAMPLES[name]), EXPECTED[name]
    for key in ("proto_hex", "bulk_hex", "payload_hex"):
        assert got[key] == want[key], f"{name}: {key} differs"
    for key in ("decoded_handed_over", "decoded_whole", "decoded_split"):
        assert got[key] == want[key], f"{name}: {key} differs"


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_the_two_parts_of_an_encoding_join_to_the_payload(name):
    """engine.messages.codec.encode_parts, written straight into shared memory, gives the golden payload."""
    head, bulk = codec.encode_parts(SAMPLES[name])
    assert (head if bulk is None else head + bytes(bulk)).hex() == EXPECTED[name]["payload_hex"]
    assert bulk is None or SAMPLES[name].BULK is not None
