"""MkDocs hooks of the documentation site (mkdocs.yml: ``hooks``). They add, at every build,
what is generated from the package itself rather than written by hand:

- ``img/conventions.svg``, the concepts page's figure (docs/_ext/conventions_figure.py);
- ``cli-help.md``, every command's ``--help`` text, from the command line's own parser;
- ``api/index.md``, the API reference's overview: every entry of the reference pages with the
  first paragraph of its docstring. Making it checks the reference: an entry without a
  docstring, or a name of ``__all__`` (the package's, ``multipendulum.envs``') without an
  entry, is a warning, which fails the strict build;
- the scenario files and scripts of ``examples/``, under ``examples/``, so the pages' links to
  them (written ``../examples/...`` so that they also work when browsing the repository) resolve.

The tutorials' links are checked and rewritten here too: mkdocs-jupyter hands over their HTML
as it is, so a link to ``../chaos.md`` would stay one (broken on the site) and a broken one
would pass unseen. Each relative link of a notebook page must name a file of the site (a
warning otherwise, which fails the strict build) and becomes that file's URL.
"""
from __future__ import annotations

import argparse
import logging
import os
import posixpath
import re
import sys
from pathlib import Path

from mkdocs.structure.files import File, Files

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]

_EXAMPLES = re.compile(r"\]\((?:\.\./)+examples/")
_HREF = re.compile(r'(<a\s[^>]*?href=")([^"]+)(")')
log = logging.getLogger("mkdocs.hooks.multipendulum")


def _help_page() -> str:
    from multipendulum.cli import build_parser

    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "88"  # argparse wraps to the terminal: the same page everywhere
    try:
        return _help_text(build_parser())
    finally:
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns


def _help_text(parser: argparse.ArgumentParser) -> str:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    parts = [
        "# Command reference",
        "",
        "Every command's `--help`, generated from the command line's own parser at each build of",
        "this site. What the commands do, the scenario format and the results files are on",
        "[the command line and scenario files](cli.md).",
        "",
        "```text",
        "$ multipendulum --help",
        parser.format_help().rstrip(),
        "```",
    ]
    for name, command in sub.choices.items():
        parts += ["", f"## `multipendulum {name}`", "", "```text", f"$ multipendulum {name} --help",
                  command.format_help().rstrip(), "```"]
    return "\n".join(parts) + "\n"


def _local(name: str):
    """A module of this folder (MkDocs loads the hooks from a file, not as a package)."""
    import importlib.util

    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, HERE / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


def load_api():
    """The package as the API reference sees it: griffe, with this site's extension."""
    import griffe

    MultipendulumDocstrings = _local("griffe_multipendulum").MultipendulumDocstrings

    return griffe.load("multipendulum", search_paths=[str(ROOT / "python")], allow_inspection=True,
                       extensions=griffe.load_extensions(MultipendulumDocstrings()), resolve_aliases=True)


def _all(module) -> list:
    """A module's ``__all__``, as griffe read it."""
    names = module.exports if getattr(module, "exports", None) is not None else []
    return [n if isinstance(n, str) else n.name for n in names]


def _api_pages(docs: Path, nav) -> list:
    """The reference's pages in the order of the site's navigation."""
    order: list = []

    def walk(item):
        if isinstance(item, str):
            if item.startswith("api/") and item != "api/index.md":
                order.append(docs / item)
        elif isinstance(item, dict):
            for value in item.values():
                walk(value)
        elif isinstance(item, list):
            for value in item:
                walk(value)

    walk(nav)
    rest = [p for p in sorted((docs / "api").glob("*.md")) if p not in order]
    return order + rest


def _api_index(docs: Path, config_nav) -> str:
    pkg = load_api()
    rows, documented = [], set()
    for page in _api_pages(docs, config_nav):
        text = page.read_text(encoding="utf-8")
        entries = re.findall(r"^::: ([\w.]+)\s*$", text, flags=re.M)
        if not entries:
            continue
        title = text.splitlines()[0].lstrip("# ").strip()
        rows += ["", f"## [{title}]({page.name})", ""]
        for ident in entries:
            obj = pkg if ident == pkg.path else pkg[ident.split(".", 1)[1]]
            doc = obj.docstring.value if obj.docstring is not None else ""
            if not doc.strip():
                log.warning("docs/api/%s: %s has no docstring (a constant: no '#:' comment above it)",
                            page.name, ident)
            documented.add(ident)
            documented.add(obj.final_target.path if obj.is_alias else obj.path)
            summary = " ".join(doc.strip().split("\n\n")[0].split())
            rows.append(f"- [`{ident.rsplit('.', 1)[-1]}`][{ident}]: {summary}")
    for module in ("multipendulum", "multipendulum.envs"):
        obj = pkg if module == pkg.path else pkg[module.split(".", 1)[1]]
        for name in _all(obj):
            if name in obj.all_members:
                member = obj[name]
                paths = {f"{module}.{name}", member.final_target.path if member.is_alias else member.path}
                found = bool(paths & documented)
            else:  # loaded on first use (the package's __getattr__): documented under its module
                found = any(ident.endswith("." + name) for ident in documented)
            if not found:
                log.warning("%s.%s is public (in __all__) but has no entry in docs/api/*.md", module, name)
    return "\n".join([
        "# API reference",
        "",
        "Everything `import multipendulum as mp` exports (`mp.__all__`), the presentation layers it",
        "loads on first use, and `multipendulum.envs`. Generated from the docstrings at each build;",
        "a constant is described by the `#:` comment above it in the source.",
    ] + rows) + "\n"


def on_files(files: Files, config) -> Files:
    conventions_figure = _local("conventions_figure")
    files.append(File.generated(config, "img/conventions.svg", content=conventions_figure.draw()))
    files.append(File.generated(config, "cli-help.md", content=_help_page()))
    files.append(File.generated(config, "api/index.md", content=_api_index(Path(config["docs_dir"]), config["nav"])))
    for path in sorted((ROOT / "examples").rglob("*")):
        if path.is_file() and path.suffix in (".py", ".toml", ".csv"):
            uri = "examples/" + path.relative_to(ROOT / "examples").as_posix()
            files.append(File.generated(config, uri, abs_src_path=str(path)))
    return files


def on_page_markdown(markdown: str, page, config, files) -> str:
    depth = page.file.src_uri.count("/")
    return _EXAMPLES.sub("](" + "../" * depth + "examples/", markdown)


def on_page_content(html: str, page, config, files) -> str:
    if not page.file.src_uri.endswith(".ipynb"):
        return html
    here = posixpath.dirname(page.file.src_uri)

    def fix(m: re.Match) -> str:
        href = m.group(2)
        if re.match(r"^([a-z][a-z0-9+.-]*:|#|/)", href):
            return m.group(0)  # absolute, an anchor on this page, or another site
        path, _, anchor = href.partition("#")
        target = files.get_file_from_path(posixpath.normpath(posixpath.join(here, path)))
        if target is None:
            log.warning("%s contains a link to '%s', which is not a file of the site", page.file.src_uri, href)
            return m.group(0)
        url = target.url_relative_to(page.file)
        return m.group(1) + url + ("#" + anchor if anchor else "") + m.group(3)

    return _HREF.sub(fix, html)
