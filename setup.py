"""Ship the repository's rules/ (rule files and budget targets) inside built wheels.

The rules live at the top of the repository, where users and reviewers find them; a wheel
carries them as frontdiag/data/rules, which is where the package looks when there is no
repository beside it. Editable installs read rules/ in place.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py


class BuildWithRules(build_py):
    def run(self) -> None:
        super().run()
        src = Path(__file__).resolve().parent / "rules"
        dst = Path(self.build_lib) / "frontdiag" / "data" / "rules"
        if src.is_dir():
            shutil.rmtree(dst, ignore_errors=True)
            shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


setup(cmdclass={"build_py": BuildWithRules})
