"""The README's Python examples run as printed, in order, in one namespace, as a reader would
paste them (a renamed function or a changed signature fails here); so do the environments'
page's (docs/envs.md)."""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"


def test_the_readme_python_examples_run_in_order():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert len(blocks) >= 3
    namespace: dict = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"README.md python block {i}", "exec"), namespace)


def test_the_environments_page_examples_run_in_order():
    pytest.importorskip("gymnasium")
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "envs.md").read_text(), flags=re.S)
    assert len(blocks) >= 3
    namespace: dict = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"docs/envs.md python block {i}", "exec"), namespace)
