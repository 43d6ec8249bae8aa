"""The repository's own Markdown pages inside the site, with their links kept working.

The pages under ``docs/`` are the site's sources. The README, the changelog and the committed
reports under ``results/`` live outside ``docs/``; :func:`write_stubs` gives each one a stub page
under ``docs/_repo/`` (same relative path) that includes it, so it is built with the site.

Every page is written for GitHub, with links relative to the file's own folder (``../results/fig2.md``,
``docs/api.md``). :func:`rewrite_links` runs on every page and every included file as Sphinx reads
it and points each relative link at the site page of its target: the document itself for a page
under ``docs/``, the stub for a README, changelog or report, the file otherwise (the site then ships
a copy, e.g. a JSON result or a test module). A target that does not exist is left as written, so
the build (run with ``-W``) fails on it.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

#: Where the stubs go, under the site's source folder (not committed: written at every build).
STUB_DIR = "_repo"
#: The repository's Markdown pages outside ``docs/`` that become site pages (globs from the root).
EXTERNAL_PAGES = ("README.md", "CHANGELOG.md", "results/**/*.md")

# [text](target) and ![alt](target) (as tests/test_docs.py reads them), and [label]: target
LINK = re.compile(r"(!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?)([^)\s>]+)(>?\s*\))")
REFERENCE = re.compile(r"^( {0,3}\[[^\]]+\]:\s*<?)([^\s>]+)")
FENCE = re.compile(r"^\s*(```|~~~)")
INLINE_CODE = re.compile(r"`[^`]*`")
SCHEME = re.compile(r"^[a-z][a-z0-9+.-]*:", re.IGNORECASE)


def external_pages(repo: Path) -> list[Path]:
    """The repository's pages outside ``docs/`` that the site includes, in a fixed order."""
    return sorted({p for pattern in EXTERNAL_PAGES for p in repo.glob(pattern)})


def stub_path(srcdir: Path, repo: Path, page: Path) -> Path:
    """The stub of the external ``page``: ``docs/_repo/<its path from the repository root>``."""
    return srcdir / STUB_DIR / page.relative_to(repo)


def write_stubs(srcdir: Path, repo: Path) -> list[Path]:
    """Writes one stub per external page (only when its text changes, so Sphinx does not reread
    it) and removes stubs whose page is gone; returns the stubs."""
    stubs = []
    for page in external_pages(repo):
        stub = stub_path(srcdir, repo, page)
        text = f"```{{include}} {os.path.relpath(page, stub.parent)}\n```\n"
        if page.name == "README.md" and page.parent != repo:  # results/README.md: the reports below it
            below = [p for p in external_pages(repo) if page.parent in p.parents and p != page]
            entries = "".join(f"{os.path.relpath(p, page.parent)[:-3]}\n" for p in below)
            text += f"\n```{{toctree}}\n:hidden:\n\n{entries}```\n"
        stub.parent.mkdir(parents=True, exist_ok=True)
        if not stub.exists() or stub.read_text(encoding="utf-8") != text:
            stub.write_text(text, encoding="utf-8")
        stubs.append(stub)
    for old in (srcdir / STUB_DIR).rglob("*.md"):
        if old not in stubs:
            old.unlink()
    return stubs


def site_target(target: Path, srcdir: Path, repo: Path, root_page: Path) -> Path:
    """The file a link to ``target`` (an absolute path) should reach inside the site."""
    if target == root_page:  # docs/README.md is included by the root page, index.md
        return srcdir / "index.md"
    if target.suffix == ".md" and srcdir not in target.parents and target in external_pages(repo):
        return stub_path(srcdir, repo, target)
    return target


def rewrite_links(text: str, written_in: Path, shown_in: Path, srcdir: Path, repo: Path) -> str:
    """``text`` (Markdown written for GitHub in the folder ``written_in``) with every relative
    link made relative to ``shown_in``, the folder of the site page that shows it, and aimed at the
    site page of its target (:func:`site_target`). Code blocks and inline code are left alone."""
    root_page = srcdir / "README.md"

    def aim(target: str) -> str:
        if SCHEME.match(target) or target.startswith("#"):
            return target
        path, hash_, anchor = target.partition("#")
        real = (written_in / path).resolve()
        if not real.exists():
            return target  # the build reports it
        new = os.path.relpath(site_target(real, srcdir, repo, root_page), shown_in)
        return f"{Path(new).as_posix()}{hash_}{anchor}"

    out, fenced = [], False
    for line in text.splitlines(keepends=True):
        if FENCE.match(line):
            fenced = not fenced
        if fenced or FENCE.match(line):
            out.append(line)
            continue
        for pattern in (LINK, REFERENCE):
            code = [m.span() for m in INLINE_CODE.finditer(line)]  # a link inside code is text

            def replace(m: re.Match, code=code) -> str:
                if any(a <= m.start() < b for a, b in code):
                    return m.group(0)
                return m.group(1) + aim(m.group(2)) + (m.group(3) if m.re is LINK else "")

            line = pattern.sub(replace, line)
        out.append(line)
    return "".join(out)


def setup(app):
    srcdir = Path(app.srcdir).resolve()
    repo = srcdir.parent
    write_stubs(srcdir, repo)

    def on_source_read(app, docname: str, source: list[str]) -> None:
        path = Path(app.env.doc2path(docname)).resolve()
        if path.suffix == ".md":
            source[0] = rewrite_links(source[0], path.parent, path.parent, srcdir, repo)

    def on_include_read(app, relative_path, parent_docname: str, content: list[str]) -> None:
        # MyST passes the file name of the including page as ``parent_docname``; the page being read
        # is the environment's current document
        included = (srcdir / relative_path).resolve()
        if included.suffix == ".md":
            shown_in = Path(app.env.doc2path(app.env.docname)).resolve().parent
            content[0] = rewrite_links(content[0], included.parent, shown_in, srcdir, repo)

    app.connect("source-read", on_source_read)
    app.connect("include-read", on_include_read)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
