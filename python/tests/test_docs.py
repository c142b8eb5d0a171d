"""docs/python.md's example runs as written: every ```python block of the page, in order, in one
namespace (as a notebook would)."""

import re
from pathlib import Path

PAGE = Path(__file__).resolve().parents[2] / "docs" / "python.md"


def test_the_python_page_runs():
    blocks = re.findall(r"^```python\n(.*?)^```", PAGE.read_text(), flags=re.S | re.M)
    assert blocks, f"no python block in {PAGE}"
    namespace: dict = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"{PAGE}:block{i}", "exec"), namespace)
