"""Recipe and DAG validation: every bad recipe gives a located, actionable error; good ones pass."""

from __future__ import annotations

import textwrap

import pytest
from recipe_helpers import header, stages

from engine.errors import RecipeError
from engine.graph import build_graph
from engine.plugin_manager import load_registry
from engine.recipe.model import load_recipe

GOOD = """\
vgr: 1
name: chain
seed: 3
plugins: [stage_fixtures]
vars: {count: 5}
stages:
  src: {type: t_counter, params: {n: "${count}"}}
  mid: {type: t_relay, inputs: {in: src.out}}
  sink: {type: t_collector, inputs: {in: mid.out}}
"""


def at(text: str, line: int, token: str) -> str:
    """``r.yaml:LINE:COL:`` with COL the 1-based column where *token* first appears on *line* of
    *text* (dedented as problems_of does): where an error about that key must point."""
    row = textwrap.dedent(text).splitlines()[line - 1]
    assert token in row, f"{token!r} is not on line {line}: {row!r}"
    return f"r.yaml:{line}:{row.index(token) + 1}: "


def problems_of(text: str, overrides: list[str] | None = None) -> list[str]:
    with pytest.raises(RecipeError) as info:
        loaded = load_recipe("r.yaml", overrides, text=textwrap.dedent(text))
        build_graph(loaded, load_registry(loaded.recipe.plugins))
    return [str(p) for p in info.value.problems]


def test_good_recipe_builds_a_topological_graph():
    loaded = load_recipe("r.yaml", text=GOOD)
    g = build_graph(loaded, load_registry(loaded.recipe.plugins))
    assert g.order == ["src", "mid", "sink"]
    assert g.nodes["src"].params.n == 5  # ${count} keeps the var's type
    assert [(e.src, e.dst) for e in g.edges] == [("src", "mid"), ("mid", "sink")]


def test_yaml_syntax_error_has_line_and_column():
    (p,) = problems_of("vgr: 1\nname: x\nstages:\n  a: {type: t_counter\n  b: 1\n")
    assert p.startswith("r.yaml:5:") and "YAML syntax error" in p


def test_duplicate_keys_are_errors_not_silently_overwritten():
    text = GOOD + "  sink: {type: t_collector, inputs: {in: src.out}}\n"
    (p,) = problems_of(text)
    assert p.startswith(at(text, 10, "sink:") + "stages.sink:") and "duplicate key 'sink'" in p


def test_unknown_top_level_key_suggests_the_right_one():
    (p,) = problems_of(GOOD.replace("seed: 3", "sed: 3"))
    assert p == "r.yaml:3:1: sed: unknown key 'sed' (did you mean 'seed'?)"


def test_unknown_stage_type_suggests_nearest():
    text = GOOD.replace("type: t_relay", "type: t_rely")
    (p,) = problems_of(text)
    assert p == at(text, 8, "type:") + "stages.mid.type: unknown stage type 't_rely' (did you mean 't_relay'?)"


def test_unknown_parameter_suggests_nearest():
    text = GOOD.replace("params: {n:", "params: {m:")
    (p,) = problems_of(text)
    assert p.startswith(at(text, 7, "m:") + "stages.src.params.m: unknown key 'm'"), p


def test_wrong_parameter_type_is_reported_with_value():
    text = GOOD.replace('"${count}"', "lots")
    (p,) = problems_of(text)
    assert p.startswith(at(text, 7, "n:") + "stages.src.params.n: "), p
    assert "valid integer" in p and "'lots'" in p


def test_missing_required_parameter():
    text = GOOD + "  scaled: {type: t_needs_param, inputs: {in: src.out}}\n"
    (p,) = problems_of(text)
    # no `params:` key to point at: the error points at the stage
    assert p == at(text, 10, "scaled:") + "stages.scaled.params.factor: missing required key 'factor'", p


def test_parameter_constraint_violation():
    text = """\
    name: x
    stages:
      a: {type: synthetic_cloud, params: {n_points: 0}}
    """
    (p,) = problems_of(text)
    assert p.startswith(at(text, 3, "n_points:") + "stages.a.params.n_points: "), p
    assert "greater than or equal to 1" in p and "(got 0)" in p


def test_missing_input_wiring():
    text = GOOD.replace("inputs: {in: mid.out}", "inputs: {}")
    (p,) = problems_of(text)
    assert p.startswith(at(text, 9, "inputs:") + "stages.sink.inputs: "), p
    assert "input port 'in' (Request) is not wired" in p


def test_unknown_source_stage_and_port_suggest_names():
    text = GOOD.replace("src.out", "srcc.out").replace("mid.out", "mid.outt")
    stage, port = problems_of(text)
    assert stage == at(text, 8, "in:") + "stages.mid.inputs.in: no stage named 'srcc' (did you mean 'src'?)"
    assert port.startswith(at(text, 9, "in:") + "stages.sink.inputs.in: ")
    assert "has no output 'outt'" in port and "did you mean 'out'" in port


def test_port_type_mismatch_is_rejected():
    text = header("x", plugins=["stage_fixtures"]) + stages("""
      a: {type: synthetic_cloud}
      b: {type: t_collector, inputs: {in: a.cloud}}
    """)
    (p,) = problems_of(text)
    assert p == (
        at(text, 5, "in:") + "stages.b.inputs.in: type mismatch: a.cloud produces PointCloud, input 'in' needs Request"
    )


def test_cycles_are_rejected_with_the_cycle_spelled_out():
    text = header("loop", plugins=["stage_fixtures"]) + stages("""
      a: {type: t_merge, inputs: {a: src.out, b: c.out}}
      b: {type: t_relay, inputs: {in: a.out}}
      c: {type: t_relay, inputs: {in: b.out}}
      src: {type: t_counter}
    """)
    (p,) = problems_of(text)
    # located at the wiring that closes the loop (b's input from a), with the loop spelled out
    assert p.startswith(at(text, 5, "in:") + "stages.b.inputs.in: data cycle: a -> b -> c -> a"), p


def test_service_wiring_errors():
    text = header("svc", plugins=["stage_fixtures"]) + stages("""
      src: {type: t_counter}
      echo: {type: t_echo}
      call: {type: t_caller, inputs: {in: src.out}, uses: {svc: echo.ecko}}
    """)
    (p,) = problems_of(text)
    assert p.startswith(at(text, 6, "svc:") + "stages.call.uses.svc: "), p
    assert "offers no service 'ecko'" in p and "did you mean 'echo'" in p
    unwired = text.replace("uses: {svc: echo.ecko}", "uses: {}")
    (p,) = problems_of(unwired)
    assert p.startswith(at(unwired, 6, "uses:") + "stages.call.uses: "), p
    assert "service client 'svc'" in p and "not wired" in p


def test_overrides_apply_and_bad_overrides_are_named():
    loaded = load_recipe("r.yaml", ["src.n=7", "seed=11", "vars.count=2"], text=GOOD)
    assert loaded.recipe.seed == 11
    assert loaded.recipe.stages["src"].params["n"] == 7
    (p,) = problems_of(GOOD, ["srx.n=1"])
    assert "<command line>" in p and "did you mean 'src'" in p
    (p,) = problems_of(GOOD, ["no_equals_sign"])
    assert "stage.param=value" in p


def test_unknown_variable_is_located():
    text = GOOD.replace("${count}", "${cnt}")
    (p,) = problems_of(text)
    assert p == at(text, 7, "n:") + "stages.src.params.n: unknown variable ${cnt} (did you mean 'count'?)"


@pytest.mark.parametrize(
    "text,needle",
    [
        ("", "empty file"),
        ("- a\n- b\n", "got a list"),
        ("name: x\nstages: {}\n", "at least one stage"),
        ("name: 'bad name'\nstages: {a: {type: t_counter}}\n", "letters, digits"),
        ("vgr: 2\nname: x\nstages: {a: {type: t_counter}}\n", "format 2 is not supported"),
    ],
)
def test_structural_errors(text, needle):
    probs = problems_of(text)
    assert any(needle in p for p in probs), probs


def test_all_problems_are_reported_at_once():
    bad = GOOD.replace("seed: 3", "seed: x").replace("t_relay", "t_rely")
    with pytest.raises(RecipeError) as info:
        load_recipe("r.yaml", text=bad)
    assert len(info.value.problems) == 1  # model errors stop before the graph...
    loaded = load_recipe("r.yaml", text=GOOD.replace("t_relay", "t_rely").replace("mid.out", "mid.nope"))
    with pytest.raises(RecipeError) as info:
        build_graph(loaded, load_registry(loaded.recipe.plugins))
    assert len(info.value.problems) == 1  # ...and a stage of unknown type does not cascade


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(RecipeError, match="recipe file not found"):
        load_recipe(tmp_path / "nope.yaml")


def test_service_and_data_edges_forming_a_wait_cycle_are_rejected():
    ok = header("waitloop", plugins=["stage_fixtures"]) + stages("""
      src: {type: t_counter}
      rs: {type: t_relay_service, inputs: {in: src.out}}
      call: {type: t_caller, inputs: {in: src.out}, uses: {svc: rs.echo}}
    """)
    loaded = load_recipe("r.yaml", text=textwrap.dedent(ok))
    build_graph(loaded, load_registry(loaded.recipe.plugins))  # no cycle: fine
    text = ok.replace("inputs: {in: src.out}, uses", "inputs: {in: rs.out}, uses")
    (p,) = problems_of(text)
    assert p.startswith(at(text, 6, "svc:") + "stages.call.uses.svc: "), p
    assert "wait cycle (deadlock risk)" in p and "rs" in p and "call" in p
