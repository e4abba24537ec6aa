"""The documentation site's promises that hold without building it (`make docs` builds it with
mkdocs --strict, running the tutorials): every public name has a docstring of its own and an
entry in the API reference (docs/api/*.md), every entry there resolves, and the examples the
pages quote (their python blocks, the docstrings' doctests, the README's commands) run or agree
as printed."""
import ast
import doctest
import importlib
import importlib.util
import inspect
import json
import pkgutil
import re
from pathlib import Path

import pytest

import multipendulum as mp

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
PACKAGE = ROOT / "python" / "multipendulum"
BLOCK = re.compile(r"```python\n(.*?)```", flags=re.S)

# Pages whose python blocks another suite already runs, in order, in one namespace (each with
# the set-up its page needs); every other page's run here.
COVERED = {
    "chaos.md": "test_fractal.py",
    "datasets.md": "test_dataset.py",
    "sensitivities.md": "test_sensitivities.py",
    "widget.md": "test_widget.py",
}
# Pages whose examples need an optional extra.
NEEDS = {"envs.md": "gymnasium"}
# Modules whose doctests need an optional extra, and those that are not the API's.
DOCTEST_NEEDS = {"multipendulum.envs": "gymnasium", "multipendulum.notebook": "anywidget",
                 "multipendulum._notebook": "anywidget"}


def _lazy_names():
    """The names the package loads on first use (its ``__getattr__``'s table)."""
    tree = ast.parse((PACKAGE / "__init__.py").read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "lazy" for t in node.targets):
            return [k.value for k in node.value.keys]
    raise AssertionError("multipendulum/__init__.py has no table of lazily loaded names")


def _public():
    """(qualified name, object) of every public name: mp.__all__, the lazy ones, envs'."""
    names = [(f"multipendulum.{n}", getattr(mp, n)) for n in mp.__all__]
    names += [(f"multipendulum.{n}", getattr(mp, n)) for n in _lazy_names() if n not in mp.__all__]
    try:
        import multipendulum.envs as envs
    except ImportError:
        pass
    else:
        names += [(f"multipendulum.envs.{n}", getattr(envs, n)) for n in envs.__all__]
    return names


def _entries():
    """Every `::: identifier` of the API reference pages: {identifier: page}."""
    found = {}
    for page in sorted((DOCS / "api").glob("*.md")):
        for ident in re.findall(r"^::: ([\w.]+)\s*$", page.read_text(encoding="utf-8"), flags=re.M):
            assert ident not in found, f"{ident} has two entries: {found[ident]} and {page.name}"
            found[ident] = page.name
    return found


def _resolve(ident):
    parts = ident.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for part in parts[i:]:
            obj = getattr(obj, part)
        return obj
    raise ImportError(ident)


def _is_data(obj):
    return not (inspect.isclass(obj) or inspect.isroutine(obj) or inspect.ismodule(obj))


def _comment_above(name, obj):
    """The ``#:`` comment above ``name``'s top-level assignment in the module that defines it."""
    names = ["multipendulum"] + [info.name for info in pkgutil.walk_packages([str(PACKAGE)], "multipendulum.")]
    for modname in names:
        if modname in ("multipendulum.viewer", "multipendulum.__main__") or ".web" in modname:
            continue
        try:
            module = importlib.import_module(modname)
        except ImportError:
            continue
        if getattr(module, name, None) is not obj or not str(getattr(module, "__file__", "")).endswith(".py"):
            continue
        lines = Path(module.__file__).read_text(encoding="utf-8").splitlines()
        for node in ast.parse("\n".join(lines)).body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
            if any(isinstance(t, ast.Name) and t.id == name for t in targets):
                above, i = [], node.lineno - 2
                while i >= 0 and lines[i].lstrip().startswith("#:"):
                    above.insert(0, lines[i].lstrip()[2:].strip())
                    i -= 1
                if above:
                    return " ".join(above)
    return ""


# ----------------------------------------------------------------------------------------------
# The API reference


def test_every_api_entry_resolves():
    for ident, page in _entries().items():
        if ident.startswith("multipendulum.envs"):
            pytest.importorskip("gymnasium")
        if ident.startswith(("multipendulum.notebook", "multipendulum._notebook")):
            pytest.importorskip("anywidget")
        try:
            _resolve(ident)
        except (ImportError, AttributeError) as e:
            raise AssertionError(f"docs/api/{page}: `::: {ident}` does not resolve ({e})") from e


def test_every_public_name_has_an_entry_in_the_api_reference():
    entries = {}
    for ident in _entries():
        try:
            entries[ident] = _resolve(ident)
        except ImportError:
            pass  # an optional extra is missing: test_every_api_entry_resolves says so
    missing = []
    for name, obj in _public():
        documented = name in entries or any(o is obj for o in entries.values() if not _is_data(obj))
        if not documented:
            missing.append(name)
    assert not missing, f"public names without an entry (`::: ...`) in docs/api/*.md: {missing}"


def test_every_public_name_has_a_docstring_of_its_own():
    missing = []
    for name, obj in _public():
        if _is_data(obj):
            doc = _comment_above(name.rsplit(".", 1)[1], obj)
        else:
            doc = obj.__dict__.get("__doc__") if inspect.isclass(obj) else obj.__doc__
        if not (isinstance(doc, str) and doc.strip()):
            missing.append(name)
    assert not missing, ("public names without a docstring (a constant: a `#:` comment above its "
                         f"assignment): {missing}")


def test_the_site_sees_every_docstring():
    """The reference as the site renders it (griffe, with the site's extension) has a docstring
    for every entry; needs the docs extra."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("griffe")
    spec = importlib.util.spec_from_file_location("docs_hooks", DOCS / "_ext" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    pkg = hooks.load_api()
    empty = []
    for ident in _entries():
        obj = pkg if ident == "multipendulum" else pkg[ident.split(".", 1)[1]]
        if obj.docstring is None or not obj.docstring.value.strip():
            empty.append(ident)
    assert not empty, f"entries the site would show without a docstring: {empty}"


def test_the_docstring_examples_run(tmp_path, monkeypatch):
    """The doctests the API reference quotes, module by module."""
    monkeypatch.chdir(tmp_path)
    tried = 0
    for info in pkgutil.walk_packages([str(PACKAGE)], "multipendulum."):
        if info.name in ("multipendulum.viewer", "multipendulum.__main__") or ".web" in info.name:
            continue
        need = DOCTEST_NEEDS.get(info.name)
        if need and importlib.util.find_spec(need) is None:
            continue
        module = importlib.import_module(info.name)
        result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, report=False)
        assert result.failed == 0, f"{info.name}: {result.failed} of its doctests fail (python -m doctest -v)"
        tried += result.attempted
    assert tried >= 50


# ----------------------------------------------------------------------------------------------
# The pages


def _pages_with_examples():
    return [p.name for p in sorted(DOCS.glob("*.md")) if BLOCK.search(p.read_text(encoding="utf-8"))]


def test_pages_run_elsewhere_are_run_there():
    for page, suite in COVERED.items():
        if not (DOCS / page).exists():
            continue
        text = (ROOT / "tests" / suite).read_text(encoding="utf-8")
        assert f'"{page}"' in text and "```python" in text, f"tests/{suite} no longer runs docs/{page}'s examples"


def _setup_cli_page(tmp_path):
    """docs/cli.md's examples read out/demo/results.npz (what `multipendulum demo` writes) and
    examples/triple.toml: a short demo run and a shortened copy of the scenario, so the example
    animations take a second, not a minute."""
    from multipendulum.results import save_results
    from multipendulum.scenario import default_scenario_path, load_scenario

    demo = load_scenario(default_scenario_path()).replace(t_end=1.0)
    (tmp_path / "out" / "demo").mkdir(parents=True)
    save_results(demo.run(), tmp_path / "out" / "demo" / "results.npz", scenario=demo)
    (tmp_path / "examples").mkdir()
    text = (ROOT / "examples" / "triple.toml").read_text(encoding="utf-8")
    short = re.sub(r"(?m)^t_end\s*=.*$", "t_end = 1.0", text)
    assert short != text
    (tmp_path / "examples" / "triple.toml").write_text(short, encoding="utf-8")


@pytest.mark.parametrize("page", [p for p in _pages_with_examples() if p not in COVERED])
def test_the_pages_python_examples_run_in_order(page, tmp_path, monkeypatch):
    if page in NEEDS:
        pytest.importorskip(NEEDS[page])
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    if page == "cli.md":
        _setup_cli_page(tmp_path)
    namespace: dict = {"__name__": f"docs_{page[:-3]}"}
    for i, block in enumerate(BLOCK.findall((DOCS / page).read_text(encoding="utf-8"))):
        exec(compile(block, f"docs/{page} python block {i}", "exec"), namespace)


def test_the_installation_page_quotes_the_readme_commands():
    def commands(text):
        return re.search(r"```sh\n(make demo.*?)```", text, flags=re.S).group(1)

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    page = (DOCS / "installation.md").read_text(encoding="utf-8")
    assert commands(page) == commands(readme)
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    assert re.search(r"(?m)^demo:", makefile) and re.search(r"(?m)^test:", makefile)
    assert re.search(r"(?m)^docs:", makefile)


def test_every_page_and_tutorial_is_in_the_navigation():
    """MkDocs warns (and, strict, fails) on a page left out of the nav only when it builds."""
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    listed = set(re.findall(r":\s*([\w/.-]+\.(?:md|ipynb))\s*$", nav, flags=re.M))
    generated = {"cli-help.md", "api/index.md"}  # written by docs/_ext/hooks.py at each build
    on_disk = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*") if p.suffix in (".md", ".ipynb")
               and "_ext" not in p.parts}
    assert on_disk | generated == listed


@pytest.mark.parametrize("notebook", sorted(p.name for p in (DOCS / "tutorials").glob("*.ipynb")))
def test_the_tutorials_are_committed_without_outputs(notebook):
    """The site runs them at each build: stored outputs would only go stale."""
    nb = json.loads((DOCS / "tutorials" / notebook).read_text(encoding="utf-8"))
    assert nb["nbformat"] == 4 and nb["metadata"]["kernelspec"]["name"] == "python3"
    for cell in nb["cells"]:
        if cell["cell_type"] == "code":
            assert cell["outputs"] == [] and cell["execution_count"] is None, notebook
