"""Griffe extension: Sphinx cross-reference roles in bayesmap's docstrings as mkdocstrings cross-references.

The docstrings are Google style with Sphinx-like roles (``:func:`run_chain```, ``:class:`~bayesmap.grid.Grid```).
mkdocstrings' Google parser leaves those roles as literal text, so this extension rewrites each role, once the whole
package is loaded, into a Markdown cross-reference ``[`shown`][full.path]`` when its target is an object the API
pages render (public, with a docstring), and into plain code ``` `shown` ``` otherwise (objects of other packages,
private helpers, undocumented attributes): never a reference that could not be resolved, so ``mkdocs build
--strict`` stays quiet.

Targets resolve like Sphinx's Python domain: a full path (``bayesmap.inference.chains.run_chain``) as it is,
otherwise relative to the object's own scope, then each enclosing class and module outwards (names imported into a
module resolve to the object they import), and last, as Sphinx does, the one rendered object whose path ends with
the target, if exactly one does. ``~`` shows only the last component; ``title <target>`` shows the title.
"""

from __future__ import annotations

import re

import griffe

ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|data|attr|exc|obj|const):`([^`]+)`")
EXPLICIT_TITLE = re.compile(r"^(.+?)\s*<([^<>]+)>$")


def _lookup(collection, path: str):
    try:
        obj = collection.get_member(path)
    except (KeyError, ValueError, AttributeError, griffe.AliasResolutionError, griffe.CyclicAliasError):
        return None
    if obj is not None and obj.is_alias:
        try:
            obj = obj.final_target
        except (griffe.AliasResolutionError, griffe.CyclicAliasError):
            return None
    return obj


def _rendered(obj, root: str) -> bool:
    """Whether the API pages render ``obj``: a public object with a docstring below the root package."""
    parts = obj.path.split(".")
    public = all(not p.startswith("_") or (p.startswith("__") and p.endswith("__")) for p in parts)
    return parts[0] == root and len(parts) > 1 and public and bool(obj.docstring and obj.docstring.value.strip())


def _resolve(obj, target: str, collection, root: str, index: dict):
    scopes = []
    scope = obj if (obj.is_module or obj.is_class) else obj.parent
    while scope is not None:
        scopes.append(scope.path)
        scope = scope.parent
    candidates = [target] if target.split(".")[0] == root else [f"{s}.{target}" for s in scopes] + [target]
    for path in candidates:
        found = _lookup(collection, path)
        if found is not None:
            return found
    matches = index.get(target.split(".")[-1], [])
    matches = [m for m in matches if m.path == target or m.path.endswith("." + target)]
    return matches[0] if len(matches) == 1 else None


def _rewrite(obj, collection, root: str, index: dict) -> None:
    if not obj.docstring:
        return

    def replace(match: re.Match) -> str:
        text = match.group(1).strip()
        explicit = EXPLICIT_TITLE.match(text)
        if explicit:
            shown, target = explicit.group(1), explicit.group(2)
        else:
            target = text.lstrip("~").rstrip("()")
            shown = text.lstrip("~").split(".")[-1] if text.startswith("~") else text.lstrip("~")
        found = _resolve(obj, target.lstrip("~").rstrip("()"), collection, root, index)
        if found is not None and _rendered(found, root):
            return f"[`{shown}`][{found.path}]"
        return f"`{shown}`"

    obj.docstring.value = ROLE.sub(replace, obj.docstring.value)


class SphinxRoles(griffe.Extension):
    """Rewrite the roles of every docstring of a package once it is loaded (see the module docstring)."""

    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs) -> None:
        objects, stack = [], [pkg]
        while stack:
            obj = stack.pop()
            objects.append(obj)
            stack.extend(member for member in obj.members.values() if not member.is_alias)
        index: dict[str, list] = {}
        for obj in objects:
            if _rendered(obj, pkg.name):
                index.setdefault(obj.name, []).append(obj)
        for obj in objects:
            _rewrite(obj, loader.modules_collection, pkg.name, index)
