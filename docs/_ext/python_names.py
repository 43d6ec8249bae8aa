"""Cross-references in docstrings resolved the way Python resolves the name.

A docstring of ``sb3_ua2c.ua2c`` writes :class:`UA2CPolicy` because ``ua2c.py`` imports it; Sphinx
looks for ``sb3_ua2c.ua2c.UA2CPolicy`` and finds nothing, as the class is documented where it is
defined. For a Python reference Sphinx cannot resolve, :func:`resolve` looks the name up as Python
would from the docstring's module (and class): a name that leads to an object documented on this
site becomes a link to it; a name that leads to anything else (a name of another package, as there
are no inventories of other packages offline; a type variable; a method without a docstring) stays
plain text. A name that Python does not find either is left unresolved, so the nitpicky build fails
on it: a docstring that names a function since renamed or removed.
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any

from sphinx.util.nodes import make_refnode

#: The packages this site documents.
OWN = ("sb3_ua2c", "envs")
_MISSING = object()


def lookup(path: str) -> Any:
    """The object at the dotted ``path`` (a module, then attributes), or ``_MISSING``."""
    parts = path.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            obj = getattr(obj, name, _MISSING)
            if obj is _MISSING:
                return _MISSING
        return obj
    return _MISSING


def inherited_annotation(cls: Any, name: str) -> bool:
    """Whether a base class of ``cls`` from another package declares the attribute ``name``
    (``gymnasium.Env.observation_space``, set on the instance, is not an attribute of the class)."""
    bases = inspect.getmro(cls)[1:] if inspect.isclass(cls) else ()
    return any(
        name in getattr(base, "__annotations__", {}) and not base.__module__.startswith(OWN) for base in bases
    )


def canonical_names(obj: Any, name: str, documented: dict) -> list[str]:
    """The documented full names under which ``obj`` (found as ``name``) may stand."""
    if isinstance(obj, property):
        obj = obj.fget
    module, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    if inspect.ismodule(obj):
        return [obj.__name__]
    if isinstance(module, str) and isinstance(qualname, str):
        return [f"{module}.{qualname}"]
    # data (a constant): the documented names whose module holds this very object
    short = name.rsplit(".", 1)[-1]
    return [full for full in documented if full.rsplit(".", 1)[-1] == short and lookup(full) is obj]


def resolve(app, env, node, contnode):
    """``missing-reference`` handler for the Python domain (see the module docstring)."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip("~.")
    module, cls = node.get("py:module"), node.get("py:class")
    # the innermost scope first: the class of the docstring, its module, then the name as written
    scopes = [s for s in (f"{module}.{cls}" if module and cls else "", module or "") if s] + [""]
    domain = env.get_domain("py")
    for scope in scopes:
        path = f"{scope}.{target}" if scope else target
        obj = lookup(path)
        if obj is _MISSING and scope and inherited_annotation(lookup(scope), target):
            return contnode  # an attribute a base class of another package declares: plain text
        if obj is _MISSING:
            continue
        for full in canonical_names(obj, path, domain.objects):
            entry = domain.objects.get(full)
            if entry is not None:
                return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id, contnode, full)
        return contnode  # another package's name, a type variable, an undocumented method: plain text
    return None


def setup(app):
    app.connect("missing-reference", resolve)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
