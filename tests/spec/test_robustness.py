"""Whatever the input, the loader returns a Spec or raises SpecError (never anything else)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.errors import SpecError
from catanc.model.load import parse_spec
from catanc.spec.language import Spec

SPECS = sorted((Path(__file__).parents[2] / "specs").glob("*.yaml"))

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.sampled_from(["catan", "nodes", "compute_ms", "LM", "scan", "a -> b", "1", "modes", "from"]),
)
documents = st.recursive(
    scalars,
    lambda children: st.one_of(
        st.lists(children, max_size=5),
        st.dictionaries(
            st.one_of(st.text(max_size=10), st.sampled_from(["catan", "app", "nodes", "edges"])), children, max_size=5
        ),
    ),
    max_leaves=30,
)


def check_outcome(text: str) -> None:
    try:
        spec = parse_spec(text, "fuzz.yaml")
    except SpecError as exc:
        assert exc.diagnostics
        lines = len(text.splitlines()) + 1  # YAML breaks lines at \r, NEL, U+2028/9 too, as splitlines does
        for diagnostic in exc.diagnostics:
            assert diagnostic.message
            if diagnostic.location is not None:
                assert diagnostic.location.file == "fuzz.yaml"
                assert 1 <= diagnostic.location.line <= lines
        return
    assert isinstance(spec, Spec)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(max_size=200))
def test_arbitrary_text(text: str) -> None:
    check_outcome(text)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(documents)
def test_arbitrary_yaml_documents(document: Any) -> None:
    check_outcome(yaml.safe_dump(document))


def _paths(data: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    found = [prefix]
    if isinstance(data, dict):
        for key, value in data.items():
            found += _paths(value, (*prefix, key))
    elif isinstance(data, list):
        for index, value in enumerate(data):
            found += _paths(value, (*prefix, index))
    return found


def _mutate(data: Any, path: tuple[Any, ...], action: str, value: Any) -> Any:
    if not path:
        return value if action == "replace" else data
    parent = data
    for key in path[:-1]:
        parent = parent[key]
    last = path[-1]
    if action == "delete":
        del parent[last]
    elif action == "replace":
        parent[last] = value
    elif action == "duplicate" and isinstance(parent, list):
        parent.insert(last, parent[last])
    elif action == "rename" and isinstance(parent, dict):
        parent[f"{last}x"] = parent.pop(last)
    return data


@pytest.mark.slow
@pytest.mark.skipif(not SPECS, reason="no example specs")
@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_mutated_example_specs(data: st.DataObject) -> None:
    path = data.draw(st.sampled_from(SPECS))
    document = yaml.safe_load(path.read_text())
    for _ in range(data.draw(st.integers(1, 3))):
        target = data.draw(st.sampled_from(_paths(document)))
        action = data.draw(st.sampled_from(["delete", "replace", "duplicate", "rename"]))
        document = _mutate(document, target, action, data.draw(documents))
    check_outcome(yaml.safe_dump(document, sort_keys=False))


@pytest.mark.parametrize(
    "payload",
    [
        "!!python/object/apply:builtins.exec [\"open('{canary}', 'w').write('x')\"]",
        "!!python/object/new:builtins.exec [\"open('{canary}', 'w').write('x')\"]",
        "!!python/name:builtins.exec",
        "!custom {{a: 1}}",
        "!!set {{a, b}}",
        "!!binary aGVsbG8=",
    ],
)
def test_yaml_tags_are_never_executed(payload: str, tmp_path: Path) -> None:
    canary = tmp_path / "canary"
    text = f"catan: 1\napp: {payload.format(canary=canary)}\nnodes: {{a: {{compute_ms: 1}}}}\n"
    with pytest.raises(SpecError) as info:
        parse_spec(text, "evil.yaml")
    assert not canary.exists()
    assert "unsupported YAML tag" in str(info.value)
    assert info.value.diagnostics[0].location is not None
    assert info.value.diagnostics[0].location.line == 2


def test_alias_bomb_is_rejected() -> None:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 9)]
    with pytest.raises(SpecError) as info:
        parse_spec("\n".join(lines), "bomb.yaml")
    assert "expands to more than" in str(info.value)


def test_merge_keys_are_resolved() -> None:
    text = """
catan: 1
app: merge
nodes:
  a: &base {compute_ms: 1, threads: {max: 2}}
  b: &b {<<: *base, compute_ms: 2}
  c: *b
edges: [[a, b], [b, c]]
subchains: {s: [a, b, c]}
"""
    spec = parse_spec(text)
    assert spec.nodes["b"].threads.max == 2
    assert spec.nodes["b"].mean_compute_ms == 2
    assert spec.nodes["c"] == spec.nodes["b"]
