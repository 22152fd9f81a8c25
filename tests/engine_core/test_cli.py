"""The vgr command line: plugins, graph, validate, run, exit codes."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from engine.cli.main import main


def test_plugins_lists_every_stage_type_with_ports_and_params(capsys):
    assert main(["plugins", "--json"]) == 0
    described = {d["type"]: d for d in json.loads(capsys.readouterr().out)}
    sc = described["synthetic_cloud"]
    assert sc["outputs"] == {"cloud": "PointCloud", "events": "Event"} and sc["role"] == "source"
    assert sc["params"]["n_points"]["default"] == 2000 and sc["plugin"] == "builtin"
    assert described["transform_cloud"]["inputs"] == {"cloud": "PointCloud"}


def test_plugins_loads_extra_modules(capsys):
    assert main(["plugins", "--plugin", "stage_fixtures", "--json"]) == 0
    types = {d["type"]: d for d in json.loads(capsys.readouterr().out)}
    assert types["t_caller"]["uses"] == {"svc": "Request -> Request"}
    assert types["t_echo"]["services"] == {"echo": "Request -> Request"}


def test_graph_prints_mermaid_and_dot(capsys):
    assert main(["graph", "recipes/demo.yaml"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("flowchart LR") and "source -->|cloud → cloud: PointCloud| move" in text
    assert main(["graph", "recipes/demo.yaml", "--format", "dot"]) == 0
    assert '"move" -> "stats"' in capsys.readouterr().out


def test_validate_exit_codes(tmp_path, capsys):
    assert main(["validate", "recipes/demo.yaml"]) == 0
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nstages:\n  a: {type: synthetic_clout}\n")
    assert main(["validate", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:3:" in err and "did you mean 'synthetic_cloud'" in err


def test_run_demo_with_override_and_json_summary(capsys):
    assert main(["run", "recipes/demo.yaml", "-p", "source.frames=3", "--no-progress", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["ok"] is True
    by = {s["name"]: s for s in summary["stages"]}
    assert by["stats"]["messages_in"] == 3 and by["source"]["messages_out"] == 3


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["run", "nope.yaml"], "nope.yaml: recipe file not found"),
        (["run", "recipes/demo.yaml", "-p", "bogus.x=1"], "-p bogus.x=1: no stage named 'bogus' to override"),
    ],
)
def test_run_refuses_bad_input_with_exit_2(argv, says, capsys):
    assert main([*argv, "--no-progress"]) == 2
    out = capsys.readouterr()
    assert says in out.err  # the reason, located, on stderr: not just the exit code


def test_every_lazily_loaded_verb_is_defined_by_its_module(capsys):
    """verb_modules() names each verb's module (the engine's and the plugins' through the hook
    vgr_cli_verbs): loading it must define that verb (not a placeholder)."""
    from engine.cli.main import build_parser, verb_modules

    modules = verb_modules()
    assert {"replay", "calibrate", "gap", "template", "teach"} <= set(modules)
    for verb, (module, _) in modules.items():
        parser = build_parser(verb)
        sub = next(a for a in parser._actions if a.dest == "verb")
        assert sub.choices[verb].add_help, f"{verb}: {module} does not define it"
        with pytest.raises(SystemExit) as e:
            parser.parse_args([verb, "--help"])
        assert e.value.code == 0
        assert f"vgr {verb}" in capsys.readouterr().out


@given(st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=1, max_size=6), st.booleans())
def test_a_long_option_takes_a_negative_number_list_as_its_value(values, with_equals):
    from engine.cli.arguments import split_negative_values
    from engine.cli.main import build_parser

    text = ",".join(repr(v) if v < 0 else repr(-v - 1.0) for v in values)  # starts with "-"
    argv = ["teach", "install", "r.yaml", *([f"--pose={text}"] if with_equals else ["--pose", text])]
    assert build_parser("teach").parse_args(split_negative_values(argv)).pose == text


@pytest.mark.parametrize("tool", [["--tool-mm", "-30", "20", "120"], ["--tool-mm=-30", "20", "120"]])
@pytest.mark.parametrize("noise", [["--noise-mm", "-1e-3"], ["--noise-mm=-1e-3"]])
def test_several_value_options_take_leading_negative_numbers_with_or_without_equals(tool, noise):
    from engine.cli.arguments import split_negative_values
    from engine.cli.main import build_parser

    parser = build_parser("calibrate")
    args = parser.parse_args(
        split_negative_values(["calibrate", "kinematics", "c.csv", "--model", "ur5e", *tool, *noise])
    )
    assert (args.tool_mm, args.noise_mm) == ([-30.0, 20.0, 120.0], -1e-3)
    prior = [a.replace("tool", "tcp-prior") for a in tool]
    args = parser.parse_args(split_negative_values(["calibrate", "vive-desk", "desk.json", *prior]))
    assert args.tcp_prior_mm == [-30.0, 20.0, 120.0]


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "r.yaml", "--no-progress", "-p", "a.b=-1"],  # not a long option's value
        ["run", "r.yaml", "--json", "--run-id", "x"],  # not a number
        ["run", "r.yaml", "--run-id=-x"],  # not a number
        ["run", "r.yaml", "-p", "-1"],  # a short option's value is argparse's to take
    ],
)
def test_other_arguments_are_left_as_they_are(argv):
    from engine.cli.arguments import split_negative_values

    assert split_negative_values(argv) == argv


def _verbs() -> list[str]:
    from engine.cli.main import OWN_VERBS, verb_modules

    return [*OWN_VERBS, *verb_modules()]


@pytest.mark.parametrize("verb", _verbs())
def test_help_texts_are_plain_text_without_markup(verb, capsys):
    with pytest.raises(SystemExit) as exc:
        main([verb, "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith("usage: vgr"), text[:200]
    for markup in ("``", ":mod:", ":func:", ":class:", ":meth:"):
        assert markup not in text, f"vgr {verb} --help shows {markup!r}:\n{text}"


def test_a_plugin_adds_a_verb_through_the_hook_and_may_not_take_an_engine_verb(monkeypatch, tmp_path, capsys):
    """A third-party verb arrives through vgr_cli_verbs, its module imported only when it runs; a
    plugin claiming `replay` is refused with exit 2, naming the plugin."""
    import sys

    from engine import plugin_manager
    from engine.hookspecs import CliVerb, hookimpl

    (tmp_path / "hello_verb.py").write_text(
        "def add_verbs(sub):\n"
        "    p = sub.add_parser('hello', help='say hello')\n"
        "    p.set_defaults(func=lambda args: print('hello from a plugin') or 3)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))

    class Plugin:
        def __init__(self):
            self.verbs = [CliVerb("hello", "say hello", "hello_verb")]

        @hookimpl
        def vgr_cli_verbs(self):
            return self.verbs

    made = plugin_manager._plugin_manager

    def with_plugin(extra, entry_points):
        pm = made(extra, entry_points)
        pm.register(plugin, name="hello-plugin")
        return pm

    plugin = Plugin()
    monkeypatch.setattr(plugin_manager, "_plugin_manager", with_plugin)
    assert main(["hello"]) == 3 and "hello from a plugin" in capsys.readouterr().out
    assert "hello_verb" in sys.modules
    plugin.verbs = [CliVerb("replay", "mine", "hello_verb")]
    assert main(["replay", "x.mcap"]) == 2
    assert "verb 'replay' is provided twice" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["run", "--help"], ["replay", "--help"], ["validate", "--help"], ["play", "--help"]])
def test_every_verb_help_ends_with_the_exit_code_table(argv, capsys):
    from engine.cli.main import main

    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "exit codes (the same for every verb): 0 ok; 1" in text and "130 interrupted" in text


def test_a_closed_stdout_ends_quietly():
    """`vgr graph ... | head`: the reader is gone before vgr writes (here `true`, which reads nothing)."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    cmd = f"set -o pipefail; {sys.executable} -m engine.cli.main graph recipes/eye_in_hand_dock.yaml | true"
    done = subprocess.run(["bash", "-c", cmd], cwd=root, capture_output=True, text=True, timeout=120)
    assert "Traceback" not in done.stderr and "BrokenPipeError" not in done.stderr, done.stderr
    assert done.returncode == 1  # the output could not be written: not ok, quietly
