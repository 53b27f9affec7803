"""The README's code runs as written."""

from __future__ import annotations

import re

from tests.conftest import PROJECT_ROOT


def test_readme_python_blocks_run():
    text = (PROJECT_ROOT / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 2
    namespace: dict[str, object] = {}
    for block in blocks:
        exec(compile(block, "README.md", "exec"), namespace)
