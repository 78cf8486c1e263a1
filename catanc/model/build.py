"""From a valid spec to its planning problem: the checks of meaning, then :class:`Problem`.

:func:`build_problem` checks what the pydantic models cannot see on their
own (names, the DAG, subchain paths, selectors, rate bounds across
constraints, executors, the deploy section) and reports every problem at once.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace

from catanc.errors import Diagnostic, FieldPath, SpecError, close_matches, did_you_mean, format_path
from catanc.model import graph
from catanc.model.problem import Chain, Executor, PeriodTerm, Problem, ResponseBound, ResponseTerm, Stage, Subchain
from catanc.spec.deploy_checks import deploy_problems
from catanc.spec.executors import ProcessThreads, executor_groups, spec_processes
from catanc.spec.language import (
    ChainConstraint,
    ChainsConstraint,
    ChainSelector,
    ChainsTerm,
    ChainTerm,
    NodeTerm,
    RateConstraint,
    Spec,
    parse_arrow,
)

MAX_SELECTOR_PATHS = 10_000
"""A selector matching more paths than this is an error, not a slow solve."""


def build_problem(spec: Spec) -> Problem:
    """Check the spec's meaning and build its :class:`Problem`; raise :class:`SpecError`."""
    return _Builder(spec).build()


def spec_dag(spec: Spec) -> graph.Dag:
    """The spec's DAG (edges to unknown nodes are left out)."""
    return graph.build_dag(
        list(spec.nodes), [(a, b) for a, b in spec.edge_pairs if a in spec.nodes and b in spec.nodes]
    )


def collapse(path: Iterable[str], spec: Spec, membership: dict[str, str]) -> tuple[Stage, ...]:
    """A path's stages: runs of one subchain merge; rate-less unscheduled nodes drop out.

    A path may enter a subchain after its first node (nav2d's NC -> LP) or
    leave it before its last (nav2d's scan -> GL): the stage is still the
    whole subchain, triggered at its head and timed as one run, which is the
    worst case the model assumes everywhere.
    """
    stages: list[Stage] = []
    for node in path:
        if node in membership:
            stage = Stage(membership[node])
            if not stages or stages[-1] != stage:
                stages.append(stage)
        elif spec.nodes[node].rate_hz is not None:
            stages.append(Stage(node, fixed=True))
    return tuple(stages)


def inside_hops_ms(spec: Spec, nodes: Iterable[str]) -> float:
    """A subchain's hops: one per edge inside it, each as the spec's ``hops_ms`` gives it (none: 0)."""
    hops = {parse_arrow(key): ms for key, ms in spec.hops_ms.items()}
    return math.fsum(hops.get(pair, 0.0) for pair in itertools.pairwise(nodes))


def runtime_delays_ms(spec: Spec, nodes: Sequence[str]) -> float:
    """What a run of a subchain of ``nodes`` waits for the runtime, beyond its nodes' compute: its head's
    dispatch (the spec's ``dispatch_ms``) and one hop per edge inside it (``hops_ms``)."""
    return math.fsum((spec.dispatch_ms.get(nodes[0], 0.0) if nodes else 0.0, inside_hops_ms(spec, nodes)))


class _Builder:
    """Accumulates diagnostics while building; one instance per call."""

    def __init__(self, spec: Spec) -> None:
        self.spec = spec
        self.errors: list[Diagnostic] = []
        self.warnings: list[Diagnostic] = []
        self.node_names = list(spec.nodes)
        self.dag: graph.Dag | None = None
        self.membership: dict[str, str] = {}
        self.chains: list[Chain] = []
        self.chain_index: dict[tuple[str, ...], int] = {}

    # -- reporting

    def _diagnostic(self, path: FieldPath, message: str, *, at_key: bool = False) -> Diagnostic:
        source = self.spec.source
        location = source.locate(path, at_key=at_key) if source is not None else None
        return Diagnostic(location, format_path(path), message)

    def error(self, path: FieldPath, message: str, *, at_key: bool = False) -> None:
        self.errors.append(self._diagnostic(path, message, at_key=at_key))

    def warn(self, path: FieldPath, message: str) -> None:
        self.warnings.append(self._diagnostic(path, message))

    def line_of(self, path: FieldPath) -> str:
        source = self.spec.source
        return f" (line {source.locate(path).line})" if source is not None else ""

    def where(self, path: FieldPath) -> str:
        """``edges[4] on line 10`` (or just the field path without a source)."""
        source = self.spec.source
        line = f" on line {source.locate(path).line}" if source is not None else ""
        return f"{format_path(path)}{line}"

    def known(self, name: str, path: FieldPath, what: str = "node") -> bool:
        choices = self.node_names if what == "node" else list(self.spec.subchains)
        if name in choices:
            return True
        self.error(path, f"unknown {what} {name!r}{did_you_mean(name, choices)}")
        return False

    # -- passes

    def build(self) -> Problem:
        self.check_edges()
        self.check_hops()
        self.check_dispatch()
        self.check_subchains()
        self.check_settings()
        subchains = self.subchain_bounds()
        self.check_rate_params(subchains)
        executors = self.check_executors(subchains)
        subchains = _with_serial(subchains, executors)
        response_terms, period_terms = self.objective_terms()
        bounds = self.response_bounds()
        if self.errors:
            raise SpecError(self.errors)
        if not self.spec.objective:
            self.warn(("objective",), "the objective is empty: every plan scores 0, so any feasible plan is chosen")
        fixed = {
            name: 1000.0 / node.rate_hz
            for name, node in self.spec.nodes.items()
            if not node.scheduled and node.rate_hz is not None
        }
        return Problem(
            app=self.spec.app,
            subchains=subchains,
            fixed_periods_ms=fixed,
            chains=tuple(self.chains),
            response_terms=tuple(response_terms),
            period_terms=tuple(period_terms),
            response_bounds=tuple(bounds),
            warnings=tuple(self.warnings),
            executors=executors,
            slack=self.spec.schedule.slack,
        )

    def check_edges(self) -> None:
        seen: dict[tuple[str, str], int] = {}
        all_known = True
        for index, (a, b) in enumerate(self.spec.edge_pairs):
            path: FieldPath = ("edges", index)
            pair = isinstance(self.spec.edges[index], list)  # point at the name itself where it has its own place
            ok_a = self.known(a, (*path, 0) if pair else path)
            ok_b = self.known(b, (*path, 1) if pair else path)
            all_known = all_known and ok_a and ok_b
            if (a, b) in seen:
                first = ("edges", seen[(a, b)])
                self.error(path, f"duplicate edge {a} -> {b} (same as {self.where(first)})")
            seen.setdefault((a, b), index)
        dag = spec_dag(self.spec)
        cycles = graph.find_cycles(dag)
        for cycle in cycles:
            closing = max(seen[(a, b)] for a, b in itertools.pairwise(cycle))
            self.error(("edges", closing), f"cycle {' -> '.join(cycle)}: the app graph must be acyclic")
        if all_known and not cycles:
            self.dag = dag

    def check_hops(self) -> None:
        """Every measured hop names an edge of the spec, once (its value's range is the language's)."""
        edges = set(self.spec.edge_pairs)
        first: dict[tuple[str, str], str] = {}
        for key in self.spec.hops_ms:
            path: FieldPath = ("hops_ms", key)
            a, b = parse_arrow(key)
            unknown = [name for name in (a, b) if name not in self.spec.nodes]
            if unknown:
                for name in unknown:
                    hint = did_you_mean(name, self.node_names)
                    self.error(path, f"unknown node {name!r}{hint}", at_key=True)
            elif (a, b) in first:
                self.error(path, f"edge {a} -> {b} again (as {first[(a, b)]!r})", at_key=True)
            elif (a, b) not in edges:
                hint = f"the edge runs {b} -> {a}" if (b, a) in edges else "edges name the hops a spec may give"
                self.error(path, f"no edge {a} -> {b} in edges ({hint})", at_key=True)
            first.setdefault((a, b), key)

    def check_dispatch(self) -> None:
        """Every measured dispatch names the head of a subchain: only heads are triggered."""
        heads = {nodes[0]: name for name, nodes in self.spec.subchains.items() if nodes}
        for node in self.spec.dispatch_ms:
            path: FieldPath = ("dispatch_ms", node)
            if node not in self.spec.nodes:
                self.error(path, f"unknown node {node!r}{did_you_mean(node, self.node_names)}", at_key=True)
            elif node not in heads:
                within = [name for name, nodes in self.spec.subchains.items() if node in nodes]
                where = (
                    f"subchain {within[0]!r} is headed by {self.spec.subchains[within[0]][0]!r}"
                    if within
                    else ("it is in no subchain")
                )
                self.error(
                    path,
                    f"{node!r} heads no subchain ({where}): a dispatch is the delay of catanc's trigger to a head; "
                    "a later node's delay is its edge's hop (hops_ms)",
                    at_key=True,
                )

    def check_subchains(self) -> None:
        spec = self.spec
        first_path: dict[str, FieldPath] = {}
        # Nodes a subchain meant to list, though it names them wrongly (a typo) or
        # under a duplicated key: both already reported, so no "in no subchain" twin.
        meant: set[str] = set()
        shadowed = spec.source.shadowed if spec.source is not None else {}
        for dropped_path, value in shadowed.items():
            if dropped_path[:1] == ("subchains",) and isinstance(value, list):
                meant.update(str(item) for item in value)
        for sub_name, nodes in spec.subchains.items():
            for index, node in enumerate(nodes):
                path: FieldPath = ("subchains", sub_name, index)
                if not self.known(node, path):
                    meant.update(close_matches(node, self.node_names))
                    continue
                if node in first_path:
                    other = first_path[node]
                    owner = other[1]
                    where = "earlier in this subchain" if owner == sub_name else f"already in subchain {owner!r}"
                    self.error(path, f"node {node!r} is {where}{self.line_of(other)}; a node belongs to one subchain")
                    continue
                first_path[node] = path
                if not spec.nodes[node].scheduled:
                    self.error(path, f"node {node!r} is unscheduled (scheduled: false) and cannot be in a subchain")
                    continue
                self.membership[node] = sub_name
                if index > 0 and spec.nodes[node].is_batch:
                    self.error(path, f"batch node {node!r} must be the first node of its subchain")
            if self.dag is not None and all(n in spec.nodes for n in nodes) and len(set(nodes)) == len(nodes):
                missing = graph.first_missing_edge(self.dag, nodes)
                if missing is not None:
                    a, b = missing
                    self.error(
                        ("subchains", sub_name),
                        f"subchain {sub_name!r} is not a path in the DAG: there is no edge {a} -> {b}",
                        at_key=True,
                    )
        for name, node_spec in spec.nodes.items():
            if node_spec.scheduled and name not in first_path and name not in meant:
                self.error(
                    ("nodes", name),
                    f"scheduled node {name!r} is in no subchain (add it to one, e.g. `{name}: [{name}]`, "
                    "or set scheduled: false)",
                    at_key=True,
                )

    def check_settings(self) -> None:
        spec = self.spec
        if spec.schedule.order is not None:
            seen: set[str] = set()
            for index, name in enumerate(spec.schedule.order):
                path: FieldPath = ("schedule", "order", index)
                if self.known(name, path, "subchain") and name in seen:
                    self.error(path, f"subchain {name!r} is listed twice")
                seen.add(name)
        for name in spec.schedule.priorities:
            self.known(name, ("schedule", "priorities", name), "subchain")
        for name in spec.baseline.priorities:
            self.known(name, ("baseline", "priorities", name), "subchain")
        for name in spec.baseline.rates_hz:
            path = ("baseline", "rates_hz", name)
            if self.known(name, path) and not spec.nodes[name].scheduled:
                self.error(path, f"node {name!r} is unscheduled; its rate is its own rate_hz")
        for name in spec.deploy:
            self.known(name, ("deploy", name))
        for path, message in deploy_problems(spec):
            self.error(path, message)

    def subchain_bounds(self) -> tuple[Subchain, ...]:
        """Subchains with rate bounds from every node constraint on their nodes."""
        spec = self.spec
        bounds: dict[str, tuple[float, float, FieldPath | None]] = dict.fromkeys(spec.subchains, (0.0, math.inf, None))
        free: dict[str, tuple[float, float]] = dict.fromkeys(spec.subchains, (0.0, math.inf))  # Hz, lists aside
        offered: dict[str, tuple[FieldPath, tuple[float, ...], str]] = {}  # subchain -> its 2+ offered rates, node
        for index, constraint in enumerate(spec.constraints):
            if not isinstance(constraint, RateConstraint):
                continue
            path: FieldPath = ("constraints", index, "node")
            node = constraint.node
            if not self.known(node, path):
                continue
            if not spec.nodes[node].scheduled:
                self.error(path, f"node {node!r} is unscheduled: its rate is fixed by its own rate_hz")
                continue
            if node not in self.membership:
                continue  # already reported: the node is in no (valid) subchain
            sub = self.membership[node]
            if len(constraint.offered_hz) > 1 and sub in offered:
                self.error(
                    ("constraints", index, "rate_hz"),
                    f"subchain {sub!r} already takes offered rates from {self.where(offered[sub][0])}: "
                    "give one list, the rates its driver offers",
                )
                continue
            low, high, origin = bounds[sub]
            new_low, new_high = constraint.bounds_hz
            low2, high2 = max(low, new_low), min(high, new_high)
            if low2 > high2 and origin is not None:
                self.error(
                    ("constraints", index),
                    f"contradicts {self.where(origin)}: subchain {sub!r} would need "
                    f"a rate >= {low2:g} Hz and <= {high2:g} Hz",
                )
                continue
            bounds[sub] = (low2, high2, ("constraints", index))
            if len(constraint.offered_hz) < 2:
                low, high = free[sub]
                free[sub] = (max(low, constraint.min_rate_hz or 0.0), min(high, constraint.max_rate_hz or math.inf))
            else:
                offered[sub] = (("constraints", index, "rate_hz"), constraint.offered_hz, node)
        for sub, (path, rates, _) in offered.items():
            self.check_offered(sub, path, rates)
        combinations = math.prod(len(rates) for _, rates, _ in offered.values())
        if combinations > OFFERED_COMBINATIONS_AT_MOST:
            path = max(path for path, _, _ in offered.values())
            self.error(
                path,
                f"{combinations} combinations of offered rates across subchains {', '.join(map(repr, offered))}: "
                f"Stage II plans each one, at most {OFFERED_COMBINATIONS_AT_MOST}: list only the rates worth trying",
            )
        subchains = []
        for name, nodes in spec.subchains.items():
            if not all(n in spec.nodes for n in nodes):
                continue
            low, high, _ = bounds[name]
            head = spec.nodes[nodes[0]]
            subchains.append(
                Subchain(
                    name=name,
                    nodes=tuple(nodes),
                    node_compute_ms=tuple(spec.nodes[n].mean_compute_ms for n in nodes),
                    node_speedups=tuple(spec.nodes[n].threads.speedups for n in nodes),
                    hops_ms=runtime_delays_ms(spec, nodes),
                    batch=head.is_batch,
                    min_period_ms=1000.0 / high if high < math.inf else 0.0,
                    max_period_ms=1000.0 / low if low > 0 else math.inf,
                    offered_hz=offered[name][1] if name in offered else (),
                    offered_by=offered[name][2] if name in offered else "",
                    free_period_range_ms=_periods_of(*free[name]),
                )
            )
        return tuple(subchains)

    def check_offered(self, sub: str, path: FieldPath, rates: tuple[float, ...]) -> None:
        """Every offered rate of subchain ``sub`` (listed at ``path``) within the bounds its other constraints set."""
        others = [
            (index, constraint.bounds_hz)
            for index, constraint in enumerate(self.spec.constraints)
            if isinstance(constraint, RateConstraint)
            and len(constraint.offered_hz) < 2  # a second list is an error of its own
            and self.membership.get(constraint.node) == sub
        ]
        for position, rate in enumerate(rates):
            index, (low, high) = next(((i, b) for i, b in others if not b[0] <= rate <= b[1]), (-1, (0.0, 0.0)))
            if index >= 0:
                self.error(
                    (*path, position),
                    f"offered rate {rate:g} Hz breaks {self.where(('constraints', index))} (subchain {sub!r} at "
                    f"{_rate_range(low, high)}): remove it from the list, or widen that bound",
                )

    def check_rate_params(self, subchains: tuple[Subchain, ...]) -> None:
        """Warn, once per subchain, where the plan sets a rate parameter that nothing caps.

        A driver offers few rates (a camera's modes, a lidar's scan rates): a plan free to pick any
        rate picks one it does not offer, which the driver then snaps to (or refuses).
        """
        for sub in subchains:
            if sub.min_period_ms > 0:  # a cap, a fixed rate or offered rates
                continue
            node = next((n for n in sub.nodes if n in self.spec.deploy and self.spec.deploy[n].rate_param), None)
            if node is None:
                continue
            self.warn(
                ("deploy", node, "rate_param"),
                f"the plan may set {node}'s {self.spec.deploy[node].rate_param} to any rate, as nothing caps "
                f"subchain {sub.name}'s: if its driver takes only some rates, list them "
                f"({{node: {node}, rate_hz: [15, 30]}}); else cap it ({{node: {node}, max_rate_hz: ...}})",
            )

    def check_executors(self, subchains: tuple[Subchain, ...]) -> tuple[Executor, ...]:
        """The executors: the ``executors:`` entries (known, scheduled nodes, each in one entry) joined with the
        processes that run their nodes in one thread (:mod:`catanc.spec.executors`); each must keep up with its
        rate floors, and an entry must stay inside its nodes' processes."""
        checked = self.check_executor_entries()
        processes = spec_processes(self.spec)
        checked = self.check_entries_in_processes(checked, processes)
        by_name = {sub.name: sub for sub in subchains}
        order = list(self.spec.subchains)
        source = self.spec.source
        executors = []
        for group in executor_groups(self.spec, checked):
            if not all(node in self.membership for node in group.nodes):
                continue  # reported already: a node in no (valid) subchain
            owners = sorted(dict.fromkeys(self.membership[node] for node in group.nodes), key=order.index)
            at_key = group.origin[0] == "executors"
            where = str(source.locate(group.origin, at_key=at_key)) if source is not None else ""
            process = group.process
            executor = Executor(
                group.name,
                group.nodes,
                tuple(owners),
                where,
                declared=format_path(group.origin),
                process=process.key if process is not None else None,
                why=process.reason if process is not None else "",
            )
            if all(owner in by_name for owner in owners):
                self.check_executor_load(executor, group.origin, by_name)
            executors.append(executor)
        return tuple(executors)

    def check_executor_entries(self) -> dict[str, list[str]]:
        """The ``executors:`` entries whose nodes are known, scheduled, in a subchain and in no other entry."""
        spec = self.spec
        first_path: dict[str, FieldPath] = {}
        checked = {}
        for name, nodes in spec.executors.items():
            ok = True
            for index, node in enumerate(nodes):
                path: FieldPath = ("executors", name, index)
                if not self.known(node, path):
                    ok = False
                    continue
                if node in first_path:
                    other = first_path[node]
                    where = "earlier in this executor" if other[1] == name else f"already in executor {other[1]!r}"
                    self.error(path, f"node {node!r} is {where}{self.line_of(other)}; a node runs in one thread")
                    ok = False
                    continue
                first_path[node] = path
                if not spec.nodes[node].scheduled:
                    self.error(
                        path,
                        f"node {node!r} is unscheduled (scheduled: false): it runs on its own clock, "
                        "so the scheduler cannot serialise it with the executor's other nodes",
                    )
                    ok = False
                elif node not in self.membership:
                    ok = False  # reported already: in no (valid) subchain
            if ok:
                checked[name] = nodes
        return checked

    def check_entries_in_processes(
        self, entries: dict[str, list[str]], processes: Sequence[ProcessThreads]
    ) -> dict[str, list[str]]:
        """The entries that agree with the processes: a thread runs in one process, and a process whose
        nodes share one thread is not split between two entries."""
        process_of = {node: process for process in processes for node in process.nodes}
        inside: dict[str, str] = {}  # one-thread process -> the first entry inside it
        agreed = {}
        for name, nodes in entries.items():
            problem = self._entry_problem(name, nodes, process_of, inside)
            if problem is not None:
                self.error(*problem)
                continue
            agreed[name] = nodes
        return agreed

    def _entry_problem(
        self, name: str, nodes: Sequence[str], process_of: Mapping[str, ProcessThreads], inside: dict[str, str]
    ) -> tuple[FieldPath, str] | None:
        """Why an ``executors:`` entry contradicts the deploy section's processes, at which of its fields."""
        placed = [(index, node, process_of[node]) for index, node in enumerate(nodes) if node in process_of]
        single = next((process for _, _, process in placed if process.one_thread), None)
        if single is not None:
            stray = next(((index, node) for index, node in enumerate(nodes) if node not in single.scheduled), None)
            if stray is not None:
                index, node = stray
                runs = f"runs in process {process_of[node].key!r}" if node in process_of else "has no deploy entry"
                member = next(node for node in nodes if node in single.scheduled)
                return (
                    ("executors", name, index),
                    f"node {node!r} {runs}, but {member!r} runs in process {single.key!r}, whose nodes "
                    f"{', '.join(single.scheduled)} share one thread ({single.reason}): an executor's thread runs "
                    f"in one process; list only the nodes of {single.key!r}, or give {node!r} deploy.{node}.process: "
                    f"{single.key}",
                )
            first = inside.setdefault(single.key, name)
            if first != name:
                return (
                    ("executors", name),
                    f"executors {first!r} and {name!r} both list nodes of process {single.key!r}, whose nodes "
                    f"{', '.join(single.scheduled)} share one thread ({single.reason}): one entry for them all, "
                    "or none (the process makes them one executor)",
                )
            return None
        if len({process.key for _, _, process in placed}) > 1:
            _, first_node, first_process = placed[0]
            index, node, process = next(item for item in placed if item[2].key != first_process.key)
            return (
                ("executors", name, index),
                f"node {node!r} runs in process {process.key!r} and {first_node!r} in {first_process.key!r}: an "
                f"executor's thread runs in one process; list nodes of one process, or give both one "
                "deploy.<node>.process",
            )
        return None

    def check_executor_load(self, executor: Executor, origin: FieldPath, by_name: Mapping[str, Subchain]) -> None:
        """One thread gives at most 100% of a core: the executor's nodes at their rate floors must fit.

        Each node runs once per run of its subchain, at a period of at most the
        subchain's longest allowed period; with its most threads it takes
        ``c_j / speedup_max``.  No core count changes this, so it is a spec error.
        """
        loads = []
        for node in executor.nodes:
            sub = by_name[self.membership[node]]
            if sub.max_period_ms == math.inf or sub.batch:
                continue
            position = sub.nodes.index(node)
            fastest = sub.node_compute_ms[position] / max(sub.node_speedups[position])
            loads.append((node, 1000.0 / sub.max_period_ms, fastest / sub.max_period_ms))
        total = math.fsum(load for _, _, load in loads)
        if total <= 1.0:
            return
        parts = ", ".join(f"{node} at >= {rate:g} Hz needs {load:.0%}" for node, rate, load in loads)
        if executor.process is None or origin[0] == "executors":
            what = f"executor {executor.name!r}"
            fix = "lower a min_rate_hz, or split the executor"
        else:
            nodes = ", ".join(executor.nodes)
            what = f"process {executor.process!r} runs {nodes} in one thread ({executor.why}), so it"
            fix = "lower a min_rate_hz, or move a node to a process of its own"
        self.error(
            origin,
            f"{what} cannot keep up with its rate floors: {parts} of its one thread, {total:.0%} in all; a "
            f"single-threaded executor runs one callback at a time on any number of cores ({fix})",
            at_key=origin[0] == "executors",
        )

    # -- chains

    def add_chain(self, nodes: tuple[str, ...]) -> int:
        """Index of the chain over ``nodes``, collapsing it on first sight."""
        if nodes not in self.chain_index:
            head = self.spec.nodes[nodes[0]]
            head_period = None
            if head.scheduled and head.batch_output_rate_hz is not None:
                head_period = 1000.0 / head.batch_output_rate_hz
            self.chain_index[nodes] = len(self.chains)
            self.chains.append(Chain(nodes, collapse(nodes, self.spec, self.membership), head_period))
        return self.chain_index[nodes]

    def explicit_chain(self, nodes: list[str], path: FieldPath) -> list[int]:
        """The one chain an explicit ``chain: [...]`` names, if it is a DAG path."""
        ok = all([self.known(node, (*path, index)) for index, node in enumerate(nodes)])  # noqa: C419 - report every name
        if not ok or self.dag is None:
            return []
        missing = graph.first_missing_edge(self.dag, nodes)
        if missing is not None:
            a, b = missing
            self.error(path, f"not a path in the DAG: there is no edge {a} -> {b}")
            return []
        return [self.add_chain(tuple(nodes))]

    def selected_chains(self, selector: ChainSelector, path: FieldPath) -> list[int]:
        """Every chain a selector matches (an error when none, or far too many)."""
        named: list[tuple[str, FieldPath]] = []
        if selector.from_ is not None:
            named.append((selector.from_, (*path, "from")))
        if isinstance(selector.through, str):
            named.append((selector.through, (*path, "through")))
        else:
            named.extend((node, (*path, "through", i)) for i, node in enumerate(selector.through))
        if selector.to is not None:
            named.append((selector.to, (*path, "to")))
        ok = all([self.known(node, where) for node, where in named])  # noqa: C419 - report every name
        if not ok or self.dag is None:
            return []
        starts = [selector.from_] if selector.from_ is not None else graph.sources(self.dag)
        ends = [selector.to] if selector.to is not None else graph.sinks(self.dag)
        through = selector.through_nodes
        count = graph.count_paths(self.dag, starts, through, ends)
        if count == 0:
            self.error(path, f"selector {_describe_selector(selector)} matches no path in the DAG")
            return []
        if count > MAX_SELECTOR_PATHS:
            self.error(
                path,
                f"selector {_describe_selector(selector)} matches {count:,} paths (more than "
                f"{MAX_SELECTOR_PATHS:,}); narrow it with from/through/to",
            )
            return []
        return [self.add_chain(nodes) for nodes in graph.iter_paths(self.dag, starts, through, ends)]

    def chains_of(
        self, entry: ChainTerm | ChainConstraint | ChainsTerm | ChainsConstraint, path: FieldPath
    ) -> list[int]:
        if isinstance(entry, (ChainTerm, ChainConstraint)):
            return self.explicit_chain(entry.chain, (*path, "chain"))
        return self.selected_chains(entry.chains, (*path, "chains"))

    def objective_terms(self) -> tuple[list[ResponseTerm], list[PeriodTerm]]:
        response_terms: list[ResponseTerm] = []
        period_terms: list[PeriodTerm] = []
        for index, term in enumerate(self.spec.objective):
            path: FieldPath = ("objective", index)
            if isinstance(term, NodeTerm):
                node_path = (*path, "node")
                if not self.known(term.node, node_path):
                    continue
                if not self.spec.nodes[term.node].scheduled:
                    self.error(
                        node_path, f"node {term.node!r} is unscheduled: its period is fixed, a term on it has no effect"
                    )
                elif term.node in self.membership:
                    period_terms.append(PeriodTerm(self.membership[term.node], term.node, term.weight, path))
                continue
            for chain in self.chains_of(term, path):
                response_terms.append(ResponseTerm(chain, term.weight, path))
        return response_terms, period_terms

    def response_bounds(self) -> list[ResponseBound]:
        bounds: list[ResponseBound] = []
        for index, constraint in enumerate(self.spec.constraints):
            if isinstance(constraint, RateConstraint):
                continue
            path: FieldPath = ("constraints", index)
            for chain in self.chains_of(constraint, path):
                bounds.append(ResponseBound(chain, constraint.max_response_ms, path))
        return bounds


def _with_serial(subchains: tuple[Subchain, ...], executors: tuple[Executor, ...]) -> tuple[Subchain, ...]:
    """Each subchain with the positions of its nodes that share an executor (Eq. 1 adds them up)."""
    result = []
    for sub in subchains:
        serial = tuple(
            positions
            for executor in executors
            if len(positions := tuple(i for i, node in enumerate(sub.nodes) if node in executor.nodes)) >= 2
        )
        result.append(replace(sub, serial=serial) if serial else sub)
    return tuple(result)


def _describe_selector(selector: ChainSelector) -> str:
    parts = []
    if selector.from_ is not None:
        parts.append(f"from: {selector.from_}")
    if selector.through_nodes:
        parts.append(f"through: {', '.join(selector.through_nodes)}")
    if selector.to is not None:
        parts.append(f"to: {selector.to}")
    return "{" + "; ".join(parts) + "}"


OFFERED_COMBINATIONS_AT_MOST = 256
"""The most combinations of offered rates a spec may ask Stage II to plan (each one a fixed-rate plan)."""


def _periods_of(low_hz: float, high_hz: float) -> tuple[float, float]:
    """The period range ``(min, max)`` (ms) of a rate range (Hz)."""
    return (1000.0 / high_hz if high_hz < math.inf else 0.0, 1000.0 / low_hz if low_hz > 0 else math.inf)


def _rate_range(low_hz: float, high_hz: float) -> str:
    """``>= 20 Hz``, ``<= 10 Hz``, ``[10, 20] Hz`` or ``exactly 10 Hz``."""
    if low_hz == high_hz:
        return f"exactly {low_hz:g} Hz"
    if high_hz == math.inf:
        return f">= {low_hz:g} Hz"
    if low_hz <= 0:
        return f"<= {high_hz:g} Hz"
    return f"[{low_hz:g}, {high_hz:g}] Hz"
