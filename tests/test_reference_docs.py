"""docs/reference/ against the code it describes: runtime.json's fields, the machine profile's fields, and the wire
protocol's messages, limits and ring layout.  Each page fails here when the code gains something it does not
document, or when it documents something the code does not have."""

from __future__ import annotations

import json
import re
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel

from catanc.artifacts import runtime_table
from catanc.artifacts.compile import Options, compile_spec
from catanc.runtime.protocol import endpoints, ring
from catanc.runtime.protocol import messages as protocol
from catanc.spec.machine import MACHINE_FORMAT, MachineProfile

ROOT = Path(__file__).resolve().parent.parent
REFERENCE = ROOT / "docs" / "reference"


def table_rows(page: Path) -> Iterator[list[str]]:
    """The cells of every markdown table row of ``page`` (header and separator rows left out)."""
    for line in page.read_text().splitlines():
        if line.startswith("|") and not line.startswith("|---"):
            cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
            if cells[0] not in ("field", "offset", "name", "datagram"):
                yield cells


def documented_fields(page: Path) -> set[str]:
    """Every field a table of ``page`` names in its first column (one or more paths in backticks)."""
    return {path for cells in table_rows(page) for path in re.findall(r"`([^`]+)`", cells[0])}


# --------------------------------------------------------------------------- runtime.json

NAMED = {"plan.subchains": "<subchain>", "plan.clocks": "<node>"}
"""Objects keyed by names from the spec, and the placeholder docs/reference/runtime-json.md writes for a name."""
LEAVES = {"spec", "processes[].ros_nodes"}
"""Objects documented as one field: the spec (docs/reference/spec.md), a process's ROS nodes -> their DAG nodes."""

TYPED = {
    "generated_by": runtime_table.GeneratedBy,
    "plan": runtime_table.PlanPayload,
    "plan.subchains.<subchain>": runtime_table.SubchainEntry,
    "plan.cores[]": runtime_table.CoreEntry,
    "plan.clocks.<node>": runtime_table.ClockEntry,
    "plan.chains[]": runtime_table.ChainEntry,
    "processes[]": runtime_table.ProcessEntry,
}
"""Where each of the writer's typed dictionaries sits in a table."""


def json_fields(value: Any, path: str, found: dict[str, bool]) -> None:
    """Every field path under ``path`` into ``found`` (path -> whether it is a leaf); :data:`LEAVES` are leaves."""
    if isinstance(value, dict) and path not in LEAVES:
        if path:
            found[path] = False
        for key, item in value.items():
            name = NAMED[path] if path in NAMED else str(key)
            json_fields(item, f"{path}.{name}" if path else name, found)
    elif isinstance(value, list) and value and isinstance(value[0], dict):
        found[path] = False
        for item in value:
            json_fields(item, f"{path}[]", found)
    else:
        found.setdefault(path, True)


@pytest.fixture(scope="module")
def runtime_fields(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bool]:
    """The fields of every committed runtime.json, of one compiled with --machine and --cpus, and of the writer's
    typed dictionaries (a field no committed table happens to have)."""
    found: dict[str, bool] = {}
    for table in sorted(ROOT.glob("out/**/runtime.json")):
        json_fields(json.loads(table.read_text()), "", found)
    profile = tmp_path_factory.mktemp("machine") / "rig.yaml"
    profile.write_text(
        f"format: {MACHINE_FORMAT}\nmachine: {{host: rig}}\nswitch_ms: 0.05\nhop_ms: 0.2\nwake_ms: 0.02\n"
        "overhead: [0.03, 0.0]\nrt: {runtime_us: 950000, period_us: 1000000}\n"
    )
    target = compile_spec(ROOT / "specs" / "face_tracking.yaml", 2, options=Options(machine=profile, cpus=(2, 3)))
    json_fields(json.loads(target.files["runtime.json"]), "", found)
    for where, typed in TYPED.items():
        for key in typed.__annotations__:
            found.setdefault(f"{where}.{key}", True)
    return found


def test_runtime_json_page_documents_every_field_the_writer_makes(runtime_fields: dict[str, bool]) -> None:
    documented = documented_fields(REFERENCE / "runtime-json.md")
    missing = sorted(path for path, leaf in runtime_fields.items() if leaf and path not in documented)
    assert not missing, f"runtime.json fields missing from docs/reference/runtime-json.md: {missing}"


def test_runtime_json_page_names_no_field_the_writer_lacks(runtime_fields: dict[str, bool]) -> None:
    unknown = sorted(documented_fields(REFERENCE / "runtime-json.md") - set(runtime_fields))
    assert not unknown, f"docs/reference/runtime-json.md names fields no table has: {unknown}"


def test_runtime_json_page_states_the_format() -> None:
    assert f"`{runtime_table.RUNTIME_FORMAT}`" in (REFERENCE / "runtime-json.md").read_text()


# --------------------------------------------------------------------------- the machine profile


def model_fields(model: type[BaseModel], prefix: str = "") -> set[str]:
    """Every field path of a pydantic model, nested models' fields included."""
    fields = set()
    for name, info in model.model_fields.items():
        path = f"{prefix}{name}"
        fields.add(path)
        if isinstance(info.annotation, type) and issubclass(info.annotation, BaseModel):
            fields |= model_fields(info.annotation, f"{path}.")
    return fields


def test_machine_page_documents_exactly_the_profile_fields() -> None:
    documented = documented_fields(REFERENCE / "machine.md")
    assert documented == model_fields(MachineProfile), "docs/reference/machine.md against MachineProfile"
    assert f"`{MACHINE_FORMAT}`" in (REFERENCE / "machine.md").read_text()


# --------------------------------------------------------------------------- the protocol

PROTOCOL_PAGE = REFERENCE / "protocol.md"
SAMPLE_WORDS = {
    "NODE": "LM",
    "NEXT_NODE": "LP",
    "PID": "41",
    "TID": "42",
    "SEQ": "7",
    "SLOTS": "64",
    "THREADS": "2",
    "NEXT_THREADS": "1",
    "CORES": "2",
    "NOTIFY": "1",
    "NEXT_ADDRESS": "003030306131",
    "PREV_ADDRESS": "-",
    "REASON...": "not yours",
}
"""A value for each placeholder the page's datagrams use."""


def documented_datagrams() -> list[str]:
    return [re.findall(r"`([^`]+)`", cells[0])[0] for cells in table_rows(PROTOCOL_PAGE) if "catanc/2" in cells[0]]


def test_every_documented_datagram_is_one_the_protocol_reads() -> None:
    for datagram in documented_datagrams():
        words = [SAMPLE_WORDS.get(word, word) for word in datagram.split(" ")]
        message = protocol.decode(" ".join(words).encode())  # raises ProtocolError if the page is wrong
        assert words[1] == message.TYPE
        assert message.encode() == " ".join(words).encode(), f"{datagram}: the code writes it otherwise"


def test_every_message_type_is_documented_with_its_fields_in_order() -> None:
    documented = documented_datagrams()
    for kind, cls in protocol.MESSAGE_TYPES.items():
        template = " ".join([protocol.PROTOCOL.decode(), kind.decode(), *(field.upper() for field in cls.FIELDS)])
        assert any(d.rstrip(".") == template for d in documented), f"{template} is not on the protocol page"


LIMITS = {
    "MAX_DATAGRAM": protocol.MAX_DATAGRAM,
    "MAX_NAME": protocol.MAX_NAME,
    "MAX_THREADS_PER_NODE": protocol.MAX_THREADS_PER_NODE,
    "STOP_GRACE_S": protocol.STOP_GRACE_S,
    "MAX_ENDPOINTS": endpoints.MAX_ENDPOINTS,
    "REGISTRATIONS_PER_S": endpoints.REGISTRATIONS_PER_S,
    "PEER_REGISTRATIONS_PER_S": endpoints.PEER_REGISTRATIONS_PER_S,
    "SLOTS": ring.SLOTS,
    "HEADER_SIZE": ring.HEADER_SIZE,
    "ENTRY_SIZE": ring.ENTRY_SIZE,
}


def test_the_limits_table_holds_the_codes_values() -> None:
    named = {f"`{name}`" for name in LIMITS}
    stated = {cells[0].strip("`"): float(cells[1]) for cells in table_rows(PROTOCOL_PAGE) if cells[0] in named}
    assert stated == {name: float(value) for name, value in LIMITS.items()}


def layout(fmt: str) -> list[tuple[int, str]]:
    """(offset, u32/u64) of each field of a struct format of I and Q fields."""
    out, offset = [], 0
    for code in fmt.lstrip("="):
        size = struct.calcsize("=" + code)
        out.append((offset, f"u{8 * size}"))
        offset += size
    return out


def ring_table(after: str) -> list[tuple[int, str]]:
    """(offset, type) rows of the first table after the line starting ``after`` on the protocol page."""
    lines = PROTOCOL_PAGE.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(after))
    rows: list[tuple[int, str]] = []
    for line in lines[start + 1 :]:
        if rows and not line.startswith("|"):
            break
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        if line.startswith("|") and cells[0].isdigit():
            rows.append((int(cells[0]), cells[1]))
    return rows


def test_the_ring_layout_is_the_codes() -> None:
    assert ring_table("The header, at offset 0") == layout(ring.HEADER.format)
    assert ring_table("Bytes 24 to 63 are zero") == layout(ring.ENTRY.format)
    assert struct.calcsize(ring.ENTRY.format) == ring.ENTRY_SIZE
    text = PROTOCOL_PAGE.read_text()
    assert f"`{ring.MAGIC:#x}`" in text
    assert f"`{ring.HEADER_SIZE} + SLOTS * {ring.ENTRY_SIZE}`" in text
