"""The documentation's links resolve: every relative link in README.md, docs/*.md and
results/README.md names a file or directory of the repository, and an anchor (``page.md#section``)
names a heading of that page. The README stays a short front page: at most 200 lines of at most 100
characters, code blocks included. docs/api.md documents every constructor argument of ``UA2C`` and
``UA2CPolicy`` and names none they lack, so a changed signature fails here until the page follows."""

from __future__ import annotations

import inspect
import re
import unicodedata
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAGES = sorted([REPO / "README.md", REPO / "results" / "README.md", *(REPO / "docs").glob("*.md")])
README_MAX_LINES = 200
README_MAX_WIDTH = 100
#: The one README block allowed past the width: ``make main``'s measured output table, kept verbatim.

# [text](target) and ![alt](target); the target stops at whitespace or ")" (no titles are used)
LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?\s*\)")
# a reference definition, [label]: target, on a line of its own
REFERENCE = re.compile(r"^ {0,3}\[[^\]]+\]:\s*<?([^\s>]+)>?")
FENCE = re.compile(r"^(```|~~~)")
INLINE_CODE = re.compile(r"`[^`]*`")
HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*#*\s*$")


def prose_lines(text: str, keep_code: bool = False) -> list[str]:
    """The lines outside fenced code blocks, with inline code removed unless ``keep_code`` (a link
    inside code is text, not a link)."""
    out, fenced = [], False
    for line in text.splitlines():
        if FENCE.match(line.lstrip()):
            fenced = not fenced
            continue
        if not fenced:
            out.append(line if keep_code else INLINE_CODE.sub("", line))
    return out


def links(text: str) -> list[str]:
    """Inline links and the targets of reference definitions, outside code."""
    out = []
    for line in prose_lines(text):
        out += [m.group(1) for m in LINK.finditer(line)]
        ref = REFERENCE.match(line)
        if ref:
            out.append(ref.group(1))
    return out


def github_slug(heading: str) -> str:
    """GitHub's anchor for a heading: inline markup dropped, lower case, every character that is not
    a letter, digit, space, hyphen or underscore removed, spaces turned into hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link keeps its text
    text = text.replace("`", "").replace("*", "").lower()
    kept = "".join(c for c in text if c in " -_" or unicodedata.category(c)[0] in "LN")
    return kept.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """Every anchor of a markdown page, with GitHub's -1, -2, ... suffixes for repeated headings."""
    if page.suffix != ".md":
        return set()
    counts: dict[str, int] = {}
    out = set()
    for line in prose_lines(page.read_text(encoding="utf-8"), keep_code=True):
        match = HEADING.match(line)
        if match:
            slug = github_slug(match.group(1))
            n = counts.get(slug, 0)
            out.add(slug if n == 0 else f"{slug}-{n}")
            counts[slug] = n + 1
    return out


def is_external(target: str) -> bool:
    return bool(re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE))


def broken_links(page: Path) -> list[str]:
    problems = []
    for target in links(page.read_text(encoding="utf-8")):
        if is_external(target):
            continue
        path_part, _, anchor = target.partition("#")
        dest = page if not path_part else (page.parent / path_part).resolve()
        if not dest.exists():
            problems.append(f"{target}: no such file")
        elif REPO not in dest.parents and dest != REPO:
            problems.append(f"{target}: outside the repository")
        elif anchor and anchor not in anchors(dest):
            problems.append(f"{target}: no heading #{anchor} in {dest.relative_to(REPO)}")
    return problems


def test_the_pages_exist() -> None:
    names = {p.relative_to(REPO).as_posix() for p in PAGES}
    expected = {
        "algorithm", "api", "environment", "style", "offline-to-online", "zoo", "benchmarks", "figure2", "layout",
    }
    assert {f"docs/{n}.md" for n in expected | {"README", "research-log"}} <= names
    assert {"README.md", "results/README.md"} <= names


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_relative_links_resolve(page: Path) -> None:
    assert links(page.read_text(encoding="utf-8")), f"{page.name} links nowhere"
    assert broken_links(page) == []


def test_readme_is_short() -> None:
    n_lines = len((REPO / "README.md").read_text(encoding="utf-8").splitlines())
    assert n_lines <= README_MAX_LINES, f"README.md has {n_lines} lines (at most {README_MAX_LINES})"


def wide_lines(text: str, width: int) -> list[int]:
    """Numbers of the lines longer than ``width`` characters, code blocks included."""
    return [i for i, line in enumerate(text.splitlines(), 1) if len(line) > width]


def test_readme_lines_are_narrow() -> None:
    wide = wide_lines((REPO / "README.md").read_text(encoding="utf-8"), README_MAX_WIDTH)
    assert wide == [], f"README.md lines {wide} are longer than {README_MAX_WIDTH} characters"


def test_the_width_check() -> None:
    text = f"short\n```\n{'y' * 100}\n{'y' * 101}\n```\n```bash\n{'z' * 101}\n```\n{'w' * 101}\n"
    assert wide_lines(text, 100) == [4, 7, 9]  # code blocks count too


def test_every_docs_page_is_in_the_index() -> None:
    index = set(links((REPO / "docs" / "README.md").read_text(encoding="utf-8")))
    for page in (REPO / "docs").glob("*.md"):
        if page.name != "README.md":
            assert page.name in index, f"docs/README.md does not link {page.name}"


# docs/api.md against the signatures

API = REPO / "docs" / "api.md"
#: Constructor parameters the reference need not document: plumbing that SB3 or UA2C passes itself.
NOT_DOCUMENTED = {"self", "policy", "env", "observation_space", "action_space", "lr_schedule", "_init_setup_model"}
TABLE_NAME = re.compile(r"^\|\s*`([A-Za-z_]\w*)`")
TABLE_CELL_NAMES = re.compile(r"`([A-Za-z_]\w*)`")
CALL_NAME = re.compile(r"^\|\s*`(?:\w+\.)?([A-Za-z_]\w*)\(")


def section(text: str, heading: str) -> str:
    """The lines after the heading line ``heading`` up to the next heading of the same or a higher
    level (fenced code included)."""
    lines = text.splitlines()
    level = len(heading) - len(heading.lstrip("#"))
    start = lines.index(heading) + 1
    for end in range(start, len(lines)):
        match = re.match(r"^(#{1,6})\s", lines[end])
        if match and len(match.group(1)) <= level:
            return "\n".join(lines[start:end])
    return "\n".join(lines[start:])


def table_names(text: str, pattern: re.Pattern = TABLE_NAME) -> list[str]:
    """The name in the first cell of every table row (a backticked identifier, or a call)."""
    return [m.group(1) for line in text.splitlines() if (m := pattern.match(line))]


def first_cell_names(text: str) -> list[str]:
    """Every backticked identifier in the first cell of a table row (``| `a`, `b` | ...``)."""
    rows = [line.split("|")[1] for line in text.splitlines() if line.startswith("|") and line.count("|") > 2]
    return [name for cell in rows for name in TABLE_CELL_NAMES.findall(cell)]


def parameters(function) -> set[str]:
    """Named parameters of ``function`` (no ``*args`` / ``**kwargs``)."""
    kinds = (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
    return {n for n, p in inspect.signature(function).parameters.items() if p.kind not in kinds}


def test_api_documents_every_ua2c_argument() -> None:
    from sb3_ua2c import UA2C

    table = table_names(section(API.read_text(encoding="utf-8"), "### UA2C arguments"))
    signature = parameters(UA2C.__init__)
    assert len(table) == len(set(table)), f"docs/api.md lists an argument twice: {sorted(table)}"
    assert sorted(signature - NOT_DOCUMENTED - set(table)) == [], "UA2C arguments missing from docs/api.md"
    assert sorted(set(table) - signature) == [], "docs/api.md documents UA2C arguments the signature lacks"


def test_api_documents_every_policy_argument() -> None:
    from sb3_ua2c import MlpPolicy, UA2CPolicy

    assert MlpPolicy is UA2CPolicy
    text = section(API.read_text(encoding="utf-8"), "## `sb3_ua2c.UA2CPolicy`, `MlpPolicy`")
    signature = parameters(UA2CPolicy.__init__)
    table = first_cell_names(text)
    assert len(table) == len(set(table)), f"docs/api.md lists a policy argument twice: {sorted(table)}"
    assert sorted(signature - NOT_DOCUMENTED - set(table)) == [], "UA2CPolicy arguments missing from docs/api.md"
    assert sorted(set(table) - signature) == [], "docs/api.md documents policy arguments the signature lacks"


def test_api_names_only_existing_ua2c_methods() -> None:
    from sb3_ua2c import UA2C

    methods = table_names(section(API.read_text(encoding="utf-8"), "### UA2C methods"), CALL_NAME)
    assert methods, "no UA2C methods table in docs/api.md"
    assert [m for m in methods if not callable(getattr(UA2C, m, None))] == []


def test_the_api_table_reader() -> None:
    page = (
        "# API\n\n## `A`\n\n### A arguments\n\n| argument | default |\n|---|---|\n"
        "| `alpha` | 1 |\n| `beta_2` | `None` |\n| not code | x |\n\n### A methods\n\n"
        "| method | meaning |\n|---|---|\n| `learn(n)` | x |\n| `A.load(path)` | x |\n\n## `B`\n\n| `gamma` | 2 |\n"
    )
    assert table_names(section(page, "### A arguments")) == ["alpha", "beta_2"]
    assert table_names(section(page, "### A methods"), CALL_NAME) == ["learn", "load"]
    assert first_cell_names("| `a`, `b_1` | `c` |\n|---|---|\n| `d` | x |\nnot | a `row`\n") == ["a", "b_1", "d"]
    assert "gamma" not in section(page, "## `A`")
    assert parameters(lambda self, a, *args, b=1, **kwargs: None) == {"self", "a", "b"}


# the checker itself, on hand-made pages: a broken file, a broken anchor and a link in code


def test_the_checker_finds_broken_links(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setitem(globals(), "REPO", tmp_path)
    (tmp_path / "other.md").write_text(
        "# Reproducibility per machine\n\n## `make main`\n\n## Offline → online\n"
    )
    page = tmp_path / "page.md"
    page.write_text(
        "[ok](other.md#reproducibility-per-machine) [ok](other.md#make-main) "
        "[ok](other.md#offline--online) [web](https://example.org/x) ![img](other.md)\n"
        "[missing](nothing.md) [bad anchor](other.md#nowhere) `[code](nothing.md)`\n"
        "```\n[fenced](nothing.md)\n```\n"
        "[ref]: other.md#make-main\n[bad ref]: gone.md\n"
    )
    assert broken_links(page) == [
        "nothing.md: no such file",
        "other.md#nowhere: no heading #nowhere in other.md",
        "gone.md: no such file",
    ]


def test_github_slugs() -> None:
    assert (
        github_slug("Learning on Pendulum-v1: what limits UA2C") == "learning-on-pendulum-v1-what-limits-ua2c"
    )
    assert github_slug("Entropy, δ and their units") == "entropy-δ-and-their-units"
    assert github_slug("`make main`") == "make-main"
    assert github_slug("Cost model of the Figure-2 estimate") == "cost-model-of-the-figure-2-estimate"
