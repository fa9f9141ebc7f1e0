"""The type gate: mypy over every package of this repository, as installed (``.ci/run`` runs it).

The packages live in folders whose names differ from their import names (``core/`` is ``mocap``,
``plugins/imitator_phc/`` is ``mocap_phc``; ``[tool.setuptools] package-dir`` in pyproject.toml), and
the editable install maps them with an import hook that mypy does not follow. So this script links
each folder under its import name in a temporary directory and runs ``mypy -p <name>`` for all of
them there (settings: ``[tool.mypy]`` in pyproject.toml). Exit status: mypy's.

    python tools/typecheck.py
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    package_dir: dict[str, str] = config["tool"]["setuptools"]["package-dir"]
    with tempfile.TemporaryDirectory(prefix="mocap-mypy-") as tmp:
        for name, folder in package_dir.items():
            os.symlink(ROOT / folder, Path(tmp) / name)
        cmd = [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml")]
        for name in package_dir:
            cmd += ["-p", name]
        env = {**os.environ, "MYPYPATH": tmp}
        return subprocess.call(cmd, cwd=tmp, env=env)


if __name__ == "__main__":
    raise SystemExit(main())
