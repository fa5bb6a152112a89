"""The wheel carries the sample data (sample_data/ -> scanqa/sample_data), so that
``scanqa demo`` and the README's Python examples run from an installed wheel
(``scanqa.sample_data_path()``). Everything else is in pyproject.toml."""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py


class BuildPyWithSampleData(build_py):
    """build_py, then sample_data/ copied into the built package (not regenerate.sh)."""

    def run(self):
        super().run()
        source = Path(__file__).resolve().parent / "sample_data"
        if not self.editable_mode and source.is_dir():
            target = Path(self.build_lib) / "scanqa" / "sample_data"
            shutil.rmtree(target, ignore_errors=True)
            shutil.copytree(source, target, ignore=shutil.ignore_patterns("*.sh"))


setup(cmdclass={"build_py": BuildPyWithSampleData})
