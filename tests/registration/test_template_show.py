"""``vgr template show``: lines a person reads by default, the JSON with --json."""

from __future__ import annotations

import json
from pathlib import Path

from engine.cli.main import main

TEMPLATE = Path(__file__).resolve().parents[2] / "recipes/templates/eye_in_hand.vgrtpl"


def test_show_prints_sizes_and_the_photo_pose_for_people_and_json_for_scripts(capsys):
    assert main(["template", "show", str(TEMPLATE)]) == 0
    text = capsys.readouterr().out
    assert (
        text.startswith("template 'eye_in_hand': cloud, ")
        and "photo pose T_base_tcp: xyz (-490.0, -140.0, 450.0) mm" in text
    )
    assert "{" not in text.splitlines()[0]
    assert main(["template", "show", str(TEMPLATE), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["name"] == "eye_in_hand" and len(doc["T_base_tcp_photo"]) == 4
