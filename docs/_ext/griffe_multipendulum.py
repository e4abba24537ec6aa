"""A griffe extension for the API reference (mkdocs.yml loads it): it makes the package's own
docstring conventions render as they read in the source.

- Constants documented by a Sphinx comment above them (``#: text``) get that text as their
  docstring (griffe reads only a string placed after an assignment).
- Objects of the compiled core (``multipendulum._core``, seen through its ``.pyi`` stub, which
  carries no docstrings) get the docstrings the Rust code gives them at run time.
- Sphinx roles (``:func:`simulate```, ``:class:`~multipendulum.Pivot```) become cross-references
  to the named object, resolved against the package; a name the site does not document stays
  code without a link (an optional reference: the build does not fail on it).
- Doctest examples (``>>>`` lines and their output) become highlighted ``pycon`` code blocks
  instead of Markdown quotes. ``tests/test_docs.py`` runs them.
"""
from __future__ import annotations

import importlib
import inspect
import re
from pathlib import Path
from typing import Any, Dict, List, Optional

import griffe

_ROLE = re.compile(r":(?:py:)?(func|class|meth|attr|data|exc|mod|obj|const):`(~?)([\w.]+)(?:\(\))?`")
_OTHER_ROLE = re.compile(r":(?:doc|ref|term):`([^`]+)`")
_PROMPT = re.compile(r"^(\s*)>>> ")


class MultipendulumDocstrings(griffe.Extension):
    """See the module docstring."""

    def __init__(self) -> None:
        self._files: Dict[str, List[str]] = {}

    # -- attribute comments -------------------------------------------------------------------

    def _lines(self, path: Any) -> List[str]:
        key = str(path)
        if key not in self._files:
            try:
                self._files[key] = Path(key).read_text(encoding="utf-8").splitlines()
            except OSError:
                self._files[key] = []
        return self._files[key]

    def on_attribute_instance(self, *, node: Any, attr: griffe.Attribute, agent: Any, **kwargs: Any) -> None:
        if attr.docstring is not None or not attr.lineno or attr.filepath is None:
            return
        if isinstance(attr.filepath, list):
            return
        lines = self._lines(attr.filepath)
        i, found = attr.lineno - 2, []
        while 0 <= i < len(lines) and lines[i].lstrip().startswith("#:"):
            found.insert(0, lines[i].lstrip()[2:].strip())
            i -= 1
        if found:
            attr.docstring = griffe.Docstring(" ".join(found), lineno=i + 2, endlineno=attr.lineno - 1,
                                              parent=attr)

    # -- the whole package: core docstrings, roles, doctests ----------------------------------

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        if pkg.name != "multipendulum":
            return
        self._pkg = pkg
        for obj in _walk(pkg):
            if obj.docstring is None and obj.path.startswith("multipendulum._core."):
                text = _runtime_doc(obj.path)
                if text:
                    obj.docstring = griffe.Docstring(text, parent=obj)
            if obj.docstring is not None:
                obj.docstring.value = _fence_doctests(self._roles(obj, obj.docstring.value))

    def _roles(self, obj: griffe.Object, text: str) -> str:
        def link(m: re.Match) -> str:
            kind, short, name = m.group(1), m.group(2), m.group(3)
            title = name.rsplit(".", 1)[-1] if short else name
            if kind in ("func", "meth"):
                title += "()"
            target = self._resolve(obj, name)
            if target is None:
                return f"`{title}`"
            return f'<autoref identifier="{target}" optional><code>{title}</code></autoref>'

        return _OTHER_ROLE.sub(r"`\1`", _ROLE.sub(link, text))

    def _resolve(self, obj: griffe.Object, name: str) -> Optional[str]:
        scopes = []
        o: Any = obj
        while o is not None:
            scopes.append(o.path)
            o = o.parent
        scopes.append("")
        for scope in scopes:
            path = f"{scope}.{name}" if scope else name
            if not path.startswith("multipendulum"):
                continue
            try:
                found = _get(self._pkg, path)
            except Exception:
                found = None
            if found is not None:
                try:
                    return found.final_target.path if found.is_alias else found.path
                except Exception:
                    return path
        return None


def _get(pkg: griffe.Module, path: str) -> Any:
    parts = path.split(".")
    if parts[0] != pkg.name:
        return None
    found: Any = pkg
    for part in parts[1:]:
        found = found.get_member(part) if hasattr(found, "get_member") else found.members[part]
    return found


def _walk(obj: Any, seen: Optional[set] = None):
    """Every object of the package once, and the targets of its aliases that are the package's
    (``from . import _core`` and the names re-exported from it may resolve to the compiled
    module's stub, an object outside the tree of members)."""
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return
    seen.add(id(obj))
    yield obj
    for member in list(obj.members.values()):
        if member.is_alias:
            try:
                member = member.final_target
            except Exception:
                continue
            if not member.path.startswith("multipendulum."):
                continue
        yield from _walk(member, seen)


def _runtime_doc(path: str) -> Optional[str]:
    module, _, rest = path.partition("._core.")
    try:
        value: Any = importlib.import_module("multipendulum._core")
        for part in rest.split("."):
            value = getattr(value, part)
    except Exception:
        return None
    if not (inspect.isclass(value) or inspect.isroutine(value) or inspect.ismodule(value)):
        return None  # an instance's __doc__ is its type's (a dict's, a tuple's): not about it
    doc = getattr(value, "__doc__", None)
    return doc.strip() if isinstance(doc, str) and doc.strip() else None


def _fence_doctests(text: str) -> str:
    lines, out, i = text.splitlines(), [], 0
    in_fence = False
    while i < len(lines):
        line = lines[i]
        if line.lstrip().startswith("```"):
            in_fence = not in_fence
        m = None if in_fence else _PROMPT.match(line)
        if m is None:
            out.append(line)
            i += 1
            continue
        indent = m.group(1)
        if out and out[-1].strip():
            out.append("")
        out.append(f"{indent}```pycon")
        while i < len(lines) and lines[i].strip():
            out.append(lines[i])
            i += 1
        out.append(f"{indent}```")
    return "\n".join(out)
