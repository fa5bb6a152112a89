"""Run the README's Python API examples as written, in order, in the current folder.

    python tools/readme_examples.py [README.md]

tests/test_readme.py runs them from the source tree; ``make wheel-check`` runs them with
the Python of a fresh venv that holds only the installed wheel, in a scratch folder, so
that they must find the sample data through ``scanqa.sample_data_path()`` (the wheel's
copy). Prints what they made; exits 1 when an example fails.
"""

from __future__ import annotations

import contextlib
import io
import re
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks(text: str) -> list[str]:
    """The ```python blocks of a Markdown text, in order."""
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def run_blocks(blocks: list[str]) -> dict:
    """Execute the blocks in one namespace (their output swallowed); the namespace."""
    namespace: dict = {}
    with contextlib.redirect_stdout(io.StringIO()):
        for block in blocks:
            exec(compile(block, "README.md", "exec"), namespace)
    return namespace


def main(argv: list[str]) -> int:
    readme = Path(argv[0]) if argv else README
    blocks = python_blocks(readme.read_text(encoding="utf-8"))
    try:
        namespace = run_blocks(blocks)
    except Exception as err:  # a failing example, whatever it raised
        print(f"README example failed: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    import scanqa

    print(f"README: {len(blocks)} Python examples ran with scanqa {scanqa.__version__} from "
          f"{Path(scanqa.__file__).parent} on {namespace['data']}; "
          f"{len(namespace['cloud'])} points annotated")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
