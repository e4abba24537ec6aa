"""The README's Python examples run as printed, in order, in one namespace, as a reader would
paste them (a renamed function or a changed signature fails here). tests/test_docs.py runs the
docs pages' examples (or names the suite that does)."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"


def test_the_readme_python_examples_run_in_order():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert len(blocks) >= 3
    namespace: dict = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"README.md python block {i}", "exec"), namespace)

