"""engine.plain_data.read_document: a JSON or YAML file a user named is read, or refused with a
ValueError naming the file; never another exception, never a silent empty result for a broken file."""

from __future__ import annotations

import contextlib
import json
import tempfile
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.plain_data import read_document


@pytest.mark.parametrize("kind", ["json", "yaml"])
def test_a_document_is_read_as_plain_data(tmp_path: Path, kind: str) -> None:
    doc = {"format": "x/1", "samples": [{"q1_deg": 1.5, "label": "a"}], "n": 3}
    path = tmp_path / f"doc.{kind}"
    path.write_text(json.dumps(doc), encoding="utf-8")  # JSON is YAML too
    assert read_document(path, kind) == doc


@pytest.mark.parametrize("kind", ["json", "yaml"])
def test_a_missing_file_is_named_with_what_it_should_be(tmp_path: Path, kind: str) -> None:
    path = tmp_path / "nowhere" / "model.yaml"
    with pytest.raises(ValueError, match=f"robot model file {path} does not exist"):
        read_document(path, kind, "robot model file")


@pytest.mark.parametrize(("kind", "text"), [("json", '{"a": [1, 2'), ("yaml", "a: [1, 2\nb: {")])
def test_a_broken_file_says_which_and_in_what_syntax(tmp_path: Path, kind: str, text: str) -> None:
    path = tmp_path / "broken.txt"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ValueError, match=f"samples {path} is not valid {kind.upper()}: "):
        read_document(path, kind, "samples")


@settings(max_examples=150, deadline=None)
@given(data=st.binary(max_size=300), kind=st.sampled_from(["json", "yaml"]))
def test_any_bytes_are_read_or_refused_with_a_value_error(data: bytes, kind: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "f"
        path.write_bytes(data)
        with contextlib.suppress(ValueError):  # any other exception fails the test
            read_document(path, kind)
