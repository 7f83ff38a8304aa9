"""The generated blocks of verification/README.md: the text between
``<!-- BEGIN generated: NAME -->`` and ``<!-- END generated: NAME -->``, rewritten by the
script that measured it; a block the README does not have yet is appended under a heading."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parent / "README.md"


def with_block(text: str, name: str, body: str, heading: str) -> str:
    """``text`` with block ``name`` set to ``body`` (appended under ``heading`` if absent)."""
    begin, end = f"<!-- BEGIN generated: {name} -->", f"<!-- END generated: {name} -->"
    block = f"{begin}\n{body}\n{end}"
    pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.DOTALL)
    if pattern.search(text):
        return pattern.sub(lambda _: block, text)
    return text.rstrip("\n") + f"\n\n## {heading}\n\n{block}\n"


def write_block(name: str, body: str, heading: str) -> None:
    """Rewrite block ``name`` of verification/README.md."""
    README.write_text(with_block(README.read_text() if README.is_file() else "# Verification\n", name, body, heading))
