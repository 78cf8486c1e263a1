"""The emit stage: a plan as the files a team deploys and commits.

:func:`emit` is pure: ``{relative path: text}`` for the five files of
the output folder (docs/guide/deploying.md), and ``cie_thread_configurator.yaml`` where the
spec maps nodes to ROS 2 callback groups.  Writing, dry-running and comparing them is
:mod:`catanc.artifacts.output`'s job.  Every file is deterministic: sorted names,
the table's fixed float precision, ``\\n`` line endings, a final newline,
and a header naming the catanc version, the command that regenerates it
and the spec's sha256 (never a time, host or absolute path).
"""

from __future__ import annotations

import json
import re
import shlex
from collections.abc import Iterable
from functools import cache
from typing import TYPE_CHECKING, Any

import jinja2
import yaml

from catanc.artifacts.deploy import Process, callback_groups, non_ros_threads, processes
from catanc.artifacts.provenance import Provenance
from catanc.artifacts.runtime_table import PARAMS_FILE, runtime_json
from catanc.errors import ExitCode
from catanc.explain.analysis import explain_plan
from catanc.explain.markdown import render_markdown

if TYPE_CHECKING:
    from catanc.model.problem import Problem
    from catanc.planning.types import Plan
    from catanc.spec.language import Spec
    from catanc.spec.machine import MachineUse

FILES = ("PLAN.md", "launch.py", "launch.sh", "params.yaml", "runtime.json")
"""The output folder holds exactly these (docs/guide/deploying.md), and THREAD_CONFIGURATOR where the spec asks."""
THREAD_CONFIGURATOR = "cie_thread_configurator.yaml"
"""callback_isolated_executor's thread settings, written when the spec names callback groups."""
GENERATED = frozenset({*FILES, THREAD_CONFIGURATOR})
"""Every name catanc writes into an output folder: one it wrote before is never someone else's file."""

EXECUTABLE = frozenset({"launch.sh"})

STOP_GRACE_S = 2
"""Seconds launch.sh gives its processes after forwarding a signal, before SIGKILL: a node shuts down in less,
and its whole tree is gone within 3 s."""


def emit(
    spec: Spec,
    problem: Problem,
    plan: Plan,
    provenance: Provenance,
    machine: MachineUse | None = None,
    *,
    cpus: tuple[int, ...] | None = None,
) -> dict[str, str]:
    """The output folder's files for ``plan``: ``{relative path: text}``.

    ``machine``: the profile ``spec``'s schedule costs were raised with (``compile --machine``); the
    table records it under ``machine`` and its spec holds the costs used.  ``cpus``: the CPUs plan
    cores run on (``compile --cpus``; core ``i`` on ``cpus[i]``): every CPU list is theirs, and the
    table lists them under ``cpus`` for the enforcer.
    """
    deployed = processes(spec, plan, cpus)
    report = explain_plan(spec, problem, plan, machine)
    started = [process for process in deployed if process.argv]
    on = cpus[: plan.cores] if cpus is not None else None
    context: dict[str, Any] = {"app": spec.app, "cores": plan.cores, "header": provenance.header, "cpus": on}
    files = {
        "runtime.json": runtime_json(
            spec,
            problem,
            plan,
            provenance,
            [process.table_entry() for process in deployed],
            machine=machine,
            cpus=cpus,
        ),
        "params.yaml": _render("params.yaml.j2", context, params=ros_parameters(deployed)),
        "launch.sh": _render(
            "launch.sh.j2",
            context,
            started=started,
            top_static_priority=max((process.static_priority for process in started), default=0),
            exit_no_privilege=int(ExitCode.NO_PRIVILEGE),
            grace_s=STOP_GRACE_S,
            params_file=PARAMS_FILE,
        ),
        "launch.py": _render(
            "launch.py.j2",
            context,
            launched=[process for process in deployed if process.package is not None or process.argv],
            params_file=PARAMS_FILE,
        ),
        "PLAN.md": _render("PLAN.md.j2", context, report=render_markdown(report).rstrip()),
    }
    groups = callback_groups(spec, plan, cpus)
    if groups:
        files[THREAD_CONFIGURATOR] = _render(
            f"{THREAD_CONFIGURATOR}.j2",
            context,
            groups=groups,
            threads=non_ros_threads(spec, plan, cpus),
            machine=machine,
        )
    return dict(sorted(files.items()))


def ros_parameters(deployed: Iterable[Process]) -> dict[str, Any]:
    """``{"/Operator": {"ros__parameters": {...}}}`` for every process that is a ROS node (``/**/Operator`` with
    ``any_namespace``)."""
    return {ros.params_key: {"ros__parameters": ros.params} for process in deployed for ros in process.ros_nodes}


# --------------------------------------------------------------------------- templates


def _render(name: str, context: dict[str, Any], **values: Any) -> str:
    text = _environment().get_template(name).render(**context, **values)
    return text if text.endswith("\n") else text + "\n"


@cache
def _environment() -> jinja2.Environment:
    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("catanc.templates", ""),
        undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
        trim_blocks=True,
        lstrip_blocks=True,
        autoescape=False,
    )
    environment.filters.update(
        comment=comment,
        shquote=shlex.quote,
        pyrepr=python_literal,
        cpu_list=cpu_list,
        to_yaml=to_yaml,
    )
    return environment


def comment(text: str, marker: str) -> str:
    """Every line of ``text`` as a comment."""
    return "\n".join(f"{marker} {line}".rstrip() for line in text.splitlines())


def python_literal(value: str) -> str:
    """A string as a Python literal, double-quoted like the rest of launch.py."""
    return json.dumps(value, ensure_ascii=False)


def cpu_list(cpus: Iterable[int]) -> str:
    """``(0, 1)`` -> ``0,1``, as taskset -c reads it."""
    return ",".join(str(cpu) for cpu in cpus)


class _ParamsDumper(yaml.SafeDumper):
    """Block mappings, flow lists (``cpus: [0, 1]``), as ROS parameter files are usually written."""


def _flow_list(dumper: yaml.SafeDumper, items: list[Any]) -> yaml.Node:
    return dumper.represent_sequence("tag:yaml.org,2002:seq", items, flow_style=True)


RCL_BOOLEANS = frozenset(
    [
        "Y",
        "y",
        "yes",
        "Yes",
        "YES",
        "true",
        "True",
        "TRUE",
        "on",
        "On",
        "ON",
        "N",
        "n",
        "no",
        "No",
        "NO",
        "false",
        "False",
        "FALSE",
        "off",
        "Off",
        "OFF",
    ]
)
"""Plain scalars rcl_yaml_param_parser reads as booleans (more than YAML 1.1's: ``y``, ``n``)."""

PLAIN_STRING = re.compile(r"[A-Za-z_/][A-Za-z0-9_./-]*")


def _string(dumper: yaml.SafeDumper, text: str) -> yaml.Node:
    """Quote every string rcl_yaml_param_parser could read as a bool, an int or a double."""
    plain = PLAIN_STRING.fullmatch(text) and text not in RCL_BOOLEANS
    plain = plain and text.lower() not in ("inf", "infinity", "nan")
    return dumper.represent_scalar("tag:yaml.org,2002:str", text, style=None if plain else '"')


_ParamsDumper.add_representer(list, _flow_list)
_ParamsDumper.add_representer(str, _string)


def to_yaml(data: dict[str, Any]) -> str:
    text: str = yaml.dump(
        data, Dumper=_ParamsDumper, sort_keys=True, default_flow_style=False, allow_unicode=True, width=10_000
    )
    return text
