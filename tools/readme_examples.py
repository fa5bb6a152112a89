"""Run the README's Python API examples as written, in order, in the current folder.

    python tools/readme_examples.py [README.md]

tests/test_readme.py runs them from the source tree; ``make wheel-check`` runs them with
the Python of a fresh venv that holds only the installed wheel, in a scratch folder, so
that they must find the sample data through ``scanqa.sample_data_path()`` (the wheel's
copy). Prints what they made; exits 1 when an example fails.

The ```py blocks (the board path: calibrate_board, characterize_board) are compiled here,
not run: they need the calib extra (OpenCV), which the wheel check installs without on
purpose, and board captures, which a wheel does not ship. tests/test_readme.py runs them
from the repository on simulated board poses (scanqa.simulator.boardfringes).
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


def board_blocks(text: str) -> list[str]:
    """The ```py blocks of a Markdown text (compiled only, module notes), in order."""
    return re.findall(r"```py\n(.*?)```", text, flags=re.S)


def run_blocks(blocks: list[str]) -> dict:
    """Execute the blocks in one namespace (their output swallowed); the namespace."""
    namespace: dict = {}
    with contextlib.redirect_stdout(io.StringIO()):
        for block in blocks:
            exec(compile(block, "README.md", "exec"), namespace)
    return namespace


def main(argv: list[str]) -> int:
    readme = Path(argv[0]) if argv else README
    text = readme.read_text(encoding="utf-8")
    blocks = python_blocks(text)
    try:
        for block in board_blocks(text):
            compile(block, "README.md", "exec")
        namespace = run_blocks(blocks)
    except Exception as err:  # a failing example, whatever it raised
        print(f"README example failed: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    import scanqa

    print(f"README: {len(blocks)} Python examples ran with scanqa {scanqa.__version__} from "
          f"{Path(scanqa.__file__).parent} on {namespace['data']}; "
          f"{len(namespace['cloud'])} points annotated; {len(board_blocks(text))} board "
          "example compiled, run by tests/test_readme.py")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
