"""The documentation: every relative link in README.md, docs/*.md and results/README.md names a file
or directory of the repository, and an anchor (``page.md#section``) names a heading of that page, as
GitHub shows them. The README stays a short front page: at most 200 lines of at most 100 characters,
code blocks included. The API reference is generated from the docstrings (``make docs``, Sphinx
autodoc, built with warnings as errors in CI): here, every module of ``sb3_ua2c`` and ``envs`` is on an
API page, every constructor argument of ``UA2C``, ``UA2CPolicy`` and ``ChunkReplayBuffer`` is described
in the docstring the page shows, and the site's link rewriting (``docs/_ext``) is checked on hand-made
pages."""

from __future__ import annotations

import inspect
import re
import unicodedata
from pathlib import Path

import pytest
from extras import require

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
#: The pages GitHub shows; docs/index.md is only the site's wrapper around docs/README.md.
PAGES = sorted(
    [REPO / "README.md", REPO / "results" / "README.md", *(p for p in DOCS.glob("*.md") if p.name != "index.md")]
)
README_MAX_LINES = 200
README_MAX_WIDTH = 100

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
    index = set(links((DOCS / "README.md").read_text(encoding="utf-8")))
    for page in DOCS.glob("*.md"):
        if page.name not in ("README.md", "index.md"):
            assert page.name in index, f"docs/README.md does not link {page.name}"


# the API reference generated from the docstrings

API_PAGES = sorted((DOCS / "api").glob("*.rst"))
AUTOMODULE = re.compile(r"^\.\. automodule:: ([\w.]+)", re.MULTILINE)
#: Constructor parameters the docstrings need not describe: plumbing that SB3 or UA2C passes itself.
NOT_DOCUMENTED = {"self", "observation_space", "action_space", "lr_schedule", "device", "n_envs"}
PARAM = re.compile(r"^\s*:param (\w+):", re.MULTILINE)


def documented_modules() -> list[str]:
    """The modules the API pages pass to ``automodule``, in page order."""
    return [m for page in API_PAGES for m in AUTOMODULE.findall(page.read_text(encoding="utf-8"))]


def package_modules(package: str) -> set[str]:
    """Every module of ``package`` (itself included) but its command lines (``__main__``, ``cli``),
    which ``--help`` documents."""
    import importlib
    import pkgutil

    root = importlib.import_module(package)
    names = {package} | {m.name for m in pkgutil.walk_packages(root.__path__, f"{package}.")}
    return {n for n in names if n.rsplit(".", 1)[-1] not in ("__main__", "cli")}


def parameters(function) -> set[str]:
    """Named parameters of ``function`` (no ``*args`` / ``**kwargs``)."""
    kinds = (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
    return {n for n, p in inspect.signature(function).parameters.items() if p.kind not in kinds}


def test_every_module_is_on_an_api_page() -> None:
    modules = documented_modules()
    assert len(modules) == len(set(modules)), f"a module is on two API pages: {sorted(modules)}"
    expected = (package_modules("sb3_ua2c") | package_modules("envs")) - {"sb3_ua2c.version"}
    assert sorted(expected - set(modules)) == [], "modules on no page of docs/api/"
    assert sorted(set(modules) - expected) == [], "docs/api/ documents modules that do not exist"


def test_every_api_page_is_in_the_api_toctree() -> None:
    text = (DOCS / "api.md").read_text(encoding="utf-8")
    for page in API_PAGES:
        assert f"\napi/{page.stem}\n" in text, f"docs/api.md has no toctree entry for {page.name}"
        assert f"(api/{page.name})" in text, f"docs/api.md does not link {page.name}"


@pytest.mark.parametrize("name", ["sb3_ua2c.ua2c.UA2C", "sb3_ua2c.policies.UA2CPolicy", "sb3_ua2c.buffers.ChunkReplayBuffer"])
def test_the_docstring_describes_every_argument(name: str) -> None:
    """The class docstring (the text autodoc shows, ``autoclass_content = "class"``) has one
    ``:param x:`` per constructor argument, and none for an argument the signature lacks."""
    import importlib

    module, cls_name = name.rsplit(".", 1)
    assert module in documented_modules()
    cls = getattr(importlib.import_module(module), cls_name)
    described = PARAM.findall(cls.__doc__ or "")
    signature = parameters(cls.__init__)
    assert len(described) == len(set(described)), f"{cls_name} describes an argument twice"
    assert sorted(signature - NOT_DOCUMENTED - set(described)) == [], f"{cls_name} arguments without :param:"
    assert sorted(set(described) - signature) == [], f"{cls_name} describes arguments the signature lacks"


def test_the_module_and_parameter_readers() -> None:
    page = ".. automodule:: a.b\n   :no-members:\n\ntext .. automodule:: not.this\n.. automodule:: c\n"
    assert AUTOMODULE.findall(page) == ["a.b", "c"]
    doc = "Text.\n\n    :param alpha: one\n    :param beta_2: two\n        :param gamma: nested\n x :param no: mid-line"
    assert PARAM.findall(doc) == ["alpha", "beta_2", "gamma"]
    assert parameters(lambda self, a, *args, b=1, **kwargs: None) == {"self", "a", "b"}
    assert "envs.style.model" in package_modules("envs") and "envs.style.cli" not in package_modules("envs")


# the site's link rewriting (docs/_ext/repo_pages.py) and name resolution (docs/_ext/python_names.py)


@pytest.fixture
def ext(monkeypatch):
    require("sphinx")  # the extensions import it: the docs extra
    monkeypatch.syspath_prepend(str(DOCS / "_ext"))
    import python_names
    import repo_pages

    return repo_pages, python_names


def test_links_are_aimed_at_site_pages(tmp_path: Path, ext) -> None:
    repo_pages, _ = ext
    src = tmp_path / "docs"
    for path in ("README.md", "CHANGELOG.md", "results/README.md", "results/run/report.md", "results/a.json",
                 "docs/README.md", "docs/page.md", "docs/index.md"):
        (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / path).write_text("# x\n")
    stubs = repo_pages.write_stubs(src, tmp_path)
    assert [s.relative_to(src).as_posix() for s in stubs] == [
        "_repo/CHANGELOG.md", "_repo/README.md", "_repo/results/README.md", "_repo/results/run/report.md",
    ]
    assert (src / "_repo/results/README.md").read_text() == (
        "```{include} ../../../results/README.md\n```\n\n```{toctree}\n:hidden:\n\nrun/report\n```\n"
    )
    # a page of docs/, read as it is
    page = "[a](page.md#s) [b](../results/run/report.md#t) [c](README.md) `[d](../CHANGELOG.md)` [e](https://x.org)\n"
    assert repo_pages.rewrite_links(page, src, src, src, tmp_path) == (
        "[a](page.md#s) [b](_repo/results/run/report.md#t) [c](index.md) `[d](../CHANGELOG.md)` [e](https://x.org)\n"
    )
    # results/README.md, shown by its stub in docs/_repo/results
    report = "[a](run/report.md) ![p](a.json) [b](../docs/page.md#s) [c](../README.md) [gone](nothing.md)\n"
    report += "```\n[fenced](../README.md)\n```\n[ref]: ../CHANGELOG.md\n"
    shown_in = src / "_repo" / "results"
    assert repo_pages.rewrite_links(report, tmp_path / "results", shown_in, src, tmp_path) == (
        "[a](run/report.md) ![p](../../../results/a.json) [b](../../page.md#s) [c](../README.md) [gone](nothing.md)\n"
        "```\n[fenced](../README.md)\n```\n[ref]: ../CHANGELOG.md\n"
    )
    (tmp_path / "results/run/report.md").unlink()
    repo_pages.write_stubs(src, tmp_path)
    assert not (src / "_repo/results/run/report.md").exists()


def test_names_are_looked_up_as_python_does(ext) -> None:
    _, python_names = ext
    from sb3_ua2c.buffers import ChunkReplayBuffer
    from sb3_ua2c.chunking import chunk_target

    assert python_names.lookup("sb3_ua2c.ua2c.ChunkReplayBuffer") is ChunkReplayBuffer  # imported there
    assert python_names.lookup("sb3_ua2c.chunking.chunk_target") is chunk_target
    assert python_names.lookup("sb3_ua2c.chunking.no_such_function") is python_names._MISSING
    assert python_names.lookup("no_such_package.x") is python_names._MISSING
    assert python_names.canonical_names(ChunkReplayBuffer, "x", {}) == ["sb3_ua2c.buffers.ChunkReplayBuffer"]
    import gymnasium as gym

    class Wrapper(gym.Wrapper):
        pass

    assert python_names.inherited_annotation(Wrapper, "env")  # gymnasium.Wrapper declares it
    assert python_names.inherited_annotation(Wrapper, "observation_space")  # gymnasium.Env does
    assert not python_names.inherited_annotation(Wrapper, "no_such_attribute")
    assert not python_names.inherited_annotation(gym.Wrapper, "env")  # its own, not a base's


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
