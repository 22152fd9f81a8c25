"""Random and garbled recipes only ever yield a validation error: never a crash, never a hang."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from engine.errors import RecipeError
from engine.graph import build_graph
from engine.plugin_manager import load_registry
from engine.recipe.model import load_recipe

REGISTRY = load_registry(["stage_fixtures"])

VALID = """\
vgr: 1
name: fuzz
seed: 3
plugins: [stage_fixtures]
vars: {count: 5}
stages:
  src: {type: t_counter, params: {n: "${count}"}}
  mid: {type: t_relay, inputs: {in: src.out}, params: {fail_at: -1}}
  echo: {type: t_echo}
  call: {type: t_caller, inputs: {in: mid.out}, uses: {svc: echo.echo}}
  sink: {type: t_collector, inputs: {in: call.out}}
"""


def check(text: str, overrides: list[str] | None = None) -> None:
    try:
        loaded = load_recipe("fuzz.yaml", overrides, text=text)
        build_graph(loaded, REGISTRY)
    except RecipeError as exc:
        assert exc.problems and all(str(p) for p in exc.problems)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(max_size=400))
def test_random_text(text):
    check(text)


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_mutated_valid_recipe(data):
    text = VALID
    for _ in range(data.draw(st.integers(1, 4))):
        op = data.draw(st.sampled_from(["delete", "insert", "replace", "swap_lines"]))
        i = data.draw(st.integers(0, len(text)))
        if op == "delete":
            j = data.draw(st.integers(i, min(len(text), i + 20)))
            text = text[:i] + text[j:]
        elif op == "insert":
            text = text[:i] + data.draw(st.text(alphabet=":{}[],.-$ \n\t'\"&*!|>#abc0123", max_size=8)) + text[i:]
        elif op == "replace":
            text = (
                text[:i] + data.draw(st.sampled_from(["src", "out", "in", "1", "-", "}", ": ", "null"])) + text[i + 1 :]
            )
        else:
            lines = text.splitlines(keepends=True)
            a, b = data.draw(st.integers(0, len(lines) - 1)), data.draw(st.integers(0, len(lines) - 1))
            lines[a], lines[b] = lines[b], lines[a]
            text = "".join(lines)
    check(text)


scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(allow_nan=True), st.text(max_size=12))
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=12,
)
stage_spec = st.fixed_dictionaries(
    {},
    optional={
        "type": st.sampled_from(
            ["t_counter", "t_relay", "t_collector", "t_echo", "t_caller", "t_merge", "nope", "t_needs_param"]
        ),
        "params": st.dictionaries(st.sampled_from(["n", "fail_at", "factor", "x", "forever"]), values, max_size=3),
        "inputs": st.dictionaries(
            st.sampled_from(["in", "a", "b", "zz"]),
            st.sampled_from(["src.out", "a.out", "b.out", "x", "src.", ".out", "a.b.c"]),
            max_size=3,
        ),
        "uses": st.dictionaries(
            st.sampled_from(["svc", "q"]), st.sampled_from(["echo.echo", "src.out", "e"]), max_size=2
        ),
        "process": st.sampled_from(["main", "other", "bad name!"]),
    },
)
recipes = st.fixed_dictionaries(
    {},
    optional={
        "vgr": st.sampled_from([1, 2, "1", None]),
        "name": st.sampled_from(["r", "bad name", "", None]),
        "seed": values,
        "plugins": st.just(["stage_fixtures"]),
        "vars": st.dictionaries(st.text(max_size=5), values, max_size=3),
        "stages": st.dictionaries(
            st.sampled_from(["src", "a", "b", "echo", "sink", "bad.name", "1x"]), stage_spec, max_size=5
        )
        | values,
        "zenoh": values,
        "clock": st.sampled_from(["wall", "sim", "moon"]),
    },
)


@settings(max_examples=400, deadline=None)
@given(
    recipes,
    st.lists(st.sampled_from(["src.n=3", "vars.count=x", "seed=abc", "a.b.c=1", "=", "x"]), max_size=2),
)
def test_structured_random_recipes(data, overrides):
    import yaml

    check(yaml.safe_dump(data, sort_keys=False), overrides)


@pytest.mark.timeout(20)
def test_pathological_yaml_does_not_hang():
    bomb = (
        "a: &a ["
        + ",".join(["x"] * 50)
        + "]\n"
        + "".join(f"b{i}: &b{i} [*{'a' if i == 0 else f'b{i - 1}'}]\n" for i in range(50))
    )
    check(bomb + "name: x\nstages: {}\n")
    check("name: " + "[" * 5000 + "]" * 5000)


@pytest.mark.timeout(20)
def test_billion_laughs_alias_expansion_is_not_exponential():
    lines = ["l0: &l0 [x, x]"] + [f"l{i}: &l{i} [*l{i - 1}, *l{i - 1}]" for i in range(1, 40)]
    check("\n".join(lines) + "\nname: x\nstages: {a: {type: t_counter, params: {n: *l39}}}\n")
