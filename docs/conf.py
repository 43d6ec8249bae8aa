"""Sphinx configuration of the sb3-ua2c documentation.

Build (from the repository root; CI and ``make docs`` run exactly this):

    sphinx-build -W --keep-going -n -b html docs docs/_build/html

The user pages are the Markdown files of this folder (read by MyST, the same files GitHub shows);
the API pages are generated from the docstrings by autodoc; the README, the changelog and the
reports of ``results/`` are included through ``_ext/repo_pages.py``. Importing ``sb3_ua2c`` and
``envs`` needs neither SUMO nor the optional extras, so nothing is mocked.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path[:0] = [str(DOCS.parent), str(DOCS / "_ext")]

from sb3_ua2c import __version__  # noqa: E402

project = "sb3-ua2c"
author = "sb3-ua2c contributors"
copyright = "the sb3-ua2c contributors"
version = release = __version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.viewcode",
    "repo_pages",
    "python_names",
]

root_doc = "index"
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
# docs/README.md is the folder's index on GitHub; the site shows it as its root page, index.md
exclude_patterns = ["_build", "README.md", "Thumbs.db", ".DS_Store"]

# every cross-reference must resolve (as with -n), whoever runs the build
nitpicky = True

# MyST: the pages are GitHub Markdown; headings get GitHub's anchors so page.md#section links resolve
myst_heading_anchors = 6

# autodoc: signatures with their type hints, the class docstring for the constructor's parameters
autoclass_content = "class"
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
# a long signature (UA2C has 38 arguments) shows one argument per line
python_maximum_signature_line_length = 100
# only the docstrings written here: an override without one does not show its base class's text
autodoc_inherit_docstrings = False
# each object on the page of the module that defines it: a name a module re-exports in ``__all__``
# (``envs.mixed_traffic.RewardConfig``) is not documented twice
autodoc_default_options = {"members": True, "show-inheritance": True, "ignore-module-all": True}

html_theme = "furo"
html_title = f"sb3-ua2c {release}"
html_static_path: list[str] = []

# No intersphinx (the build works offline): references into other packages are not checked.
nitpick_ignore_regex = [
    ("py:.*", r"(torch|th|numpy|np|collections|os|pathlib|io|types|typing|gymnasium|gym"
              r"|stable_baselines3|optuna)(\..*)?"),
]


def dataclass_factories(app, what, name, obj, options, signature, return_annotation):
    """A dataclass field with a ``default_factory`` shows as ``= <factory>`` in the signature, which
    is no Python and makes Sphinx split the signature at every comma: show ``= dict()`` instead."""
    if signature and "<factory>" in signature and dataclasses.is_dataclass(obj):
        for field in dataclasses.fields(obj):
            if field.init and field.default_factory is not dataclasses.MISSING:
                factory = getattr(field.default_factory, "__name__", "factory")
                signature = signature.replace("<factory>", f"{factory}()", 1)
    return signature, return_annotation


def setup(app):
    app.connect("autodoc-process-signature", dataclass_factories)
