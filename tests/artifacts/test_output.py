"""The output folder's I/O layer: atomic writes, never losing a user's file, and comparing."""

from __future__ import annotations

import os
import py_compile
import stat
from pathlib import Path

import pytest

from catanc.artifacts import output
from catanc.artifacts.output import Status, compare, ensure_comparable, replace_file, write
from catanc.errors import ExitCode, NotCompiledError, OutputBlockedError, OutputError

FILES = {
    "PLAN.md": "# plan\n",
    "launch.py": "print('hi')\n",
    "launch.sh": "#!/usr/bin/env bash\necho hi\n",
    "params.yaml": "/n:\n  ros__parameters: {}\n",
    "runtime.json": "{}\n",
}


def tree(folder: Path) -> dict[str, tuple[bytes, bool]]:
    return {
        path.name: (path.read_bytes(), bool(path.stat().st_mode & stat.S_IXUSR)) for path in sorted(folder.iterdir())
    }


def leftovers(parent: Path, folder: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p != folder)


def test_write_creates_exactly_the_files_with_launch_sh_executable(tmp_path: Path) -> None:
    folder = tmp_path / "out" / "demo" / "cores-2"
    before = write(folder, FILES)
    assert not before.exists
    written = tree(folder)
    assert {name: text for name, (text, _) in written.items()} == {k: v.encode() for k, v in FILES.items()}
    assert {name for name, (_, executable) in written.items() if executable} == {"launch.sh"}
    assert leftovers(folder.parent, folder) == []


def test_rewriting_the_same_files_touches_nothing(tmp_path: Path) -> None:
    folder = tmp_path / "cores-1"
    write(folder, FILES)
    inode = folder.stat().st_ino
    mtimes = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
    assert write(folder, FILES).current
    assert folder.stat().st_ino == inode
    assert {p.name: p.stat().st_mtime_ns for p in folder.iterdir()} == mtimes


def test_a_changed_file_replaces_the_whole_folder(tmp_path: Path) -> None:
    folder = tmp_path / "cores-1"
    write(folder, FILES)
    changed = {**FILES, "runtime.json": '{"new": true}\n'}
    before = write(folder, changed)
    assert before.statuses["runtime.json"] is Status.CHANGED
    assert before.statuses["PLAN.md"] is Status.UNCHANGED
    assert (folder / "runtime.json").read_text() == changed["runtime.json"]
    assert leftovers(tmp_path, folder) == []


def test_without_an_atomic_exchange_two_renames_do_the_same(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def unavailable(a: Path, b: Path) -> bool:
        return False

    monkeypatch.setattr(output, "_exchange", unavailable)
    folder = tmp_path / "cores-1"
    write(folder, FILES)
    write(folder, {**FILES, "PLAN.md": "# other\n"})
    assert (folder / "PLAN.md").read_text() == "# other\n"
    assert leftovers(tmp_path, folder) == []


@pytest.mark.parametrize("fail_after", [0, 2, 4])
def test_an_interrupted_write_leaves_the_old_folder_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fail_after: int
) -> None:
    folder = tmp_path / "cores-1"
    write(folder, FILES)
    old = tree(folder)
    real_write = Path.write_bytes
    calls: list[Path] = []

    def failing_write(self: Path, data: bytes) -> int:
        if len(calls) == fail_after:
            raise OSError(28, "No space left on device")
        calls.append(self)
        return real_write(self, data)

    monkeypatch.setattr(Path, "write_bytes", failing_write)
    with pytest.raises(OutputError, match="No space left on device"):
        write(folder, {name: text + "changed\n" for name, text in FILES.items()})
    assert tree(folder) == old
    assert leftovers(tmp_path, folder) == []


def test_a_failed_swap_leaves_the_old_folder_whole(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = tmp_path / "cores-1"
    write(folder, FILES)
    old = tree(folder)

    def refuse(a: Path, b: Path) -> bool:
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(output, "_exchange", refuse)
    with pytest.raises(OutputError):
        write(folder, {**FILES, "PLAN.md": "# other\n"})
    assert tree(folder) == old
    assert leftovers(tmp_path, folder) == []


def test_a_users_file_in_the_folder_blocks_the_write(tmp_path: Path) -> None:
    folder = tmp_path / "cores-1"
    write(folder, FILES)
    (folder / "notes.txt").write_text("mine\n")
    with pytest.raises(OutputBlockedError, match=r"notes\.txt") as caught:
        write(folder, {**FILES, "PLAN.md": "# other\n"})
    assert caught.value.exit_code == ExitCode.OUTPUT_BLOCKED
    assert (folder / "notes.txt").read_text() == "mine\n"
    assert (folder / "PLAN.md").read_text() == FILES["PLAN.md"]


def test_a_home_folder_is_never_replaced(tmp_path: Path) -> None:
    home = tmp_path / "home"
    home.mkdir()
    (home / ".bashrc").write_text("x\n")
    with pytest.raises(OutputBlockedError):
        write(home, FILES)
    assert [p.name for p in home.iterdir()] == [".bashrc"]


@pytest.mark.parametrize("where", ["folder", "parent"])
def test_a_file_in_the_way_blocks_the_write(tmp_path: Path, where: str) -> None:
    blocker = tmp_path / "out"
    blocker.write_text("not a folder\n")
    folder = blocker if where == "folder" else blocker / "demo" / "cores-1"
    with pytest.raises(OutputBlockedError, match="a file is in the way"):
        write(folder, FILES)
    assert blocker.read_text() == "not a folder\n"


def test_a_symbolic_link_is_not_replaced(tmp_path: Path) -> None:
    target = tmp_path / "elsewhere"
    target.mkdir()
    link = tmp_path / "cores-1"
    link.symlink_to(target)
    with pytest.raises(OutputBlockedError, match="symbolic link"):
        write(link, FILES)
    assert link.is_symlink()
    assert list(target.iterdir()) == []


def test_an_unwritable_place_is_an_output_error() -> None:
    folder = Path("/sys/catanc-test/out/demo/cores-1")  # sysfs refuses new folders, even to root
    with pytest.raises(OutputError) as caught:
        write(folder, FILES)
    assert caught.value.exit_code == ExitCode.OUTPUT
    assert not folder.exists()


def test_compare_names_every_kind_of_difference(tmp_path: Path) -> None:
    folder = tmp_path / "cores-1"
    write(folder, FILES)
    (folder / "params.yaml").write_text("/n:\n  ros__parameters: {x: 1}\n")
    (folder / "PLAN.md").unlink()
    (folder / "stray.txt").write_text("?\n")
    (folder / "launch.sh").chmod(0o644)
    result = compare(folder, FILES, with_diffs=True)
    assert result.of(Status.CHANGED) == ["launch.sh", "params.yaml"]
    assert result.of(Status.MISSING) == ["PLAN.md"]
    assert result.of(Status.EXTRA) == ["stray.txt"]
    assert result.of(Status.UNCHANGED) == ["launch.py", "runtime.json"]
    assert not result.current
    diff = result.diffs["params.yaml"].splitlines()
    assert diff[0] == f"--- {folder / 'params.yaml'} (on disk)"
    assert diff[1] == f"+++ {folder / 'params.yaml'} (generated)"
    assert "-  ros__parameters: {x: 1}" in diff
    assert "+  ros__parameters: {}" in diff
    assert "should be executable" in result.diffs["launch.sh"]
    new_file = ["--- /dev/null", f"+++ {folder / 'PLAN.md'} (generated)", "@@ -0,0 +1 @@"]
    assert result.diffs["PLAN.md"].splitlines()[:3] == new_file


def test_compare_never_writes(tmp_path: Path) -> None:
    folder = tmp_path / "cores-1"
    result = compare(folder, FILES, with_diffs=True)
    assert not result.exists
    assert set(result.of(Status.NEW)) == set(FILES)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(NotCompiledError) as caught:
        ensure_comparable(result)
    assert caught.value.exit_code == ExitCode.NOT_COMPILED


def test_a_pycache_folder_is_neither_compared_nor_kept(tmp_path: Path) -> None:
    folder = tmp_path / "cores-1"
    write(folder, FILES)
    written = py_compile.compile(str(folder / "launch.py"), doraise=True)
    assert written is not None
    cached = Path(written)  # Python's own bytecode cache
    assert cached.parent.name == "__pycache__"
    comparison = compare(folder, FILES)
    assert comparison.current
    assert "__pycache__" not in comparison.statuses
    write(folder, {**FILES, "PLAN.md": "# other\n"})
    assert sorted(tree(folder)) == sorted(FILES)
    assert leftovers(tmp_path, folder) == []


@pytest.mark.parametrize(("name", "make"), [("__pycache__", "file"), ("__pycache__x", "folder"), ("cache", "folder")])
def test_only_a_folder_named_pycache_is_ignored(tmp_path: Path, name: str, make: str) -> None:
    folder = tmp_path / "cores-1"
    write(folder, FILES)
    if make == "file":
        (folder / name).write_text("mine\n")
    else:
        (folder / name).mkdir()
    assert compare(folder, FILES).statuses[name] is Status.EXTRA
    with pytest.raises(OutputBlockedError, match=name):
        write(folder, {**FILES, "PLAN.md": "# other\n"})
    assert (folder / name).exists()


# --------------------------------------------------------------------------- one file replaced


def test_replace_file_keeps_the_mode_and_writes_through_a_link(tmp_path: Path) -> None:
    target = tmp_path / "spec.yaml"
    target.write_text("old\n")
    target.chmod(0o640)
    link = tmp_path / "link.yaml"
    link.symlink_to(target)
    replace_file(link, "new: é\n")
    assert link.is_symlink()  # the link stays, its target is replaced
    assert target.read_bytes() == "new: é\n".encode()
    assert stat.S_IMODE(target.stat().st_mode) == 0o640
    replace_file(tmp_path / "fresh.yaml", "x\n")  # a new file: created
    assert (tmp_path / "fresh.yaml").read_text() == "x\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fresh.yaml", "link.yaml", "spec.yaml"]  # no temporary


def test_a_failed_replace_leaves_the_old_file_and_no_temporary(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "machine.yaml"
    target.write_text("old\n")

    def full(_fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OutputError) as caught:
        replace_file(target, "new\n")
    assert str(caught.value) == f"{target}: cannot write: No space left on device"
    assert caught.value.exit_code == ExitCode.OUTPUT
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["machine.yaml"]


def test_replace_file_in_an_unwritable_place_is_an_output_error() -> None:
    with pytest.raises(OutputError, match="cannot write"):
        replace_file(Path("/sys/catanc-test.yaml"), "x\n")  # sysfs refuses new files, even to root
