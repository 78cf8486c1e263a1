"""References resolve in a clone: the docs' links, the docs paths the code names, and "the model, section N"."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = sorted(
    [ROOT / "README.md", *ROOT.glob("docs/**/*.md"), *ROOT.glob("examples/**/*.md"), *ROOT.glob("benchmarks/*.md")]
)
CODE_FOLDERS = ("catanc", "benchmarks", "tests", "examples", "templates", "specs", ".ci")
CODE_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".hpp", ".cpp", ".txt", ".j2", ".sh", ""}
MODEL = ROOT / "docs" / "explanation" / "model.md"

LINK = re.compile(r"\]\(([^)\s]+)\)")
DOCS_PATH = re.compile(r"(?<![\w/.-])docs/[\w./-]*\w")
SHARED = re.compile(r"shared/docs|\b(?:interfaces|catan-model|solver-notes)\.md\b")
MODEL_SECTIONS = re.compile(
    r"(?:model\.md|the model)\)?,?\s+(?:sections?\s+)?(\d+(?:(?:\s*,\s*|\s+and\s+)\d+)*)(?![\w.])", re.IGNORECASE
)


def code_files() -> Iterator[Path]:
    for folder in CODE_FOLDERS:
        for path in sorted((ROOT / folder).rglob("*")):
            if path.is_file() and path.suffix in CODE_SUFFIXES and "__pycache__" not in path.parts:
                yield path


def heading_anchor(heading: str) -> str:
    """GitHub's anchor for a markdown heading: lower case, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"[^\w\s-]", "", heading.strip().lower())
    return re.sub(r"\s", "-", text)


def anchors(page: Path) -> set[str]:
    return {heading_anchor(line.lstrip("#")) for line in page.read_text().splitlines() if line.startswith("#")}


def test_anchors_are_githubs() -> None:
    assert heading_anchor("## 4. Stage II: rates and time slices".lstrip("#")) == "4-stage-ii-rates-and-time-slices"
    assert heading_anchor(" Exit codes") == "exit-codes"


@pytest.mark.parametrize("page", PAGES, ids=lambda page: str(page.relative_to(ROOT)))
def test_every_relative_link_of_a_page_resolves(page: Path) -> None:
    broken = []
    for target in LINK.findall(page.read_text()):
        if re.match(r"[a-z]+:", target) or target.startswith("<"):
            continue  # a URL, or a placeholder such as <catanc's repository>
        path, _, anchor = target.partition("#")
        resolved = (page.parent / path).resolve() if path else page
        if not resolved.exists() or (anchor and resolved.suffix == ".md" and anchor not in anchors(resolved)):
            broken.append(target)
    assert not broken, f"{page.relative_to(ROOT)}: links that lead nowhere: {broken}"


def test_every_docs_path_the_code_names_exists() -> None:
    missing = [
        f"{path.relative_to(ROOT)}: {name}"
        for path in code_files()
        for name in DOCS_PATH.findall(path.read_text(errors="replace"))
        if not (ROOT / name).exists()
    ]
    assert not missing, f"docs paths that are not in the repository: {missing}"


def test_nothing_points_outside_the_repository_for_its_documentation() -> None:
    outside = [
        f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
        for path in [*code_files(), *PAGES]
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1)
        if SHARED.search(line) and path != Path(__file__)
    ]
    assert not outside, f"references to the team's shared folder, which a clone lacks: {outside}"


def test_every_model_section_cited_is_a_section_of_the_model() -> None:
    sections = {line.split(".")[0].lstrip("# ") for line in MODEL.read_text().splitlines() if line.startswith("## ")}
    wrong = []
    for path in [*code_files(), *PAGES]:
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            for cited in MODEL_SECTIONS.findall(line):
                for section in re.findall(r"\d+", cited):
                    if section not in sections:
                        wrong.append(f"{path.relative_to(ROOT)}:{number}: section {section}")
    assert not wrong, f"the model has sections {sorted(sections)}; cited: {wrong}"


def test_the_readme_links_every_guide_reference_and_explanation_page() -> None:
    linked = {(ROOT / target.partition("#")[0]).resolve() for target in LINK.findall((ROOT / "README.md").read_text())}
    pages = [*ROOT.glob("docs/guide/*.md"), *ROOT.glob("docs/reference/*.md"), *ROOT.glob("docs/explanation/*.md")]
    unlinked = sorted(str(page.relative_to(ROOT)) for page in pages if page.resolve() not in linked)
    assert not unlinked, f"README.md links none of: {unlinked}"
