"""The files committed to the repository (``git ls-files``), not whatever lies in its folders: a
user's ``mocap export runs/x checkpoints/my_pulse`` must not make the suite fail (issue 63)."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def committed_files(folder: str, pattern: str, root: Path = ROOT) -> list[Path]:
    """The files under ``root/folder`` that git tracks and that match ``pattern`` (``*/*.pt``), sorted.
    Outside a git checkout (an unpacked source archive) every matching file counts."""
    try:
        listed = subprocess.run(["git", "-C", str(root), "ls-files", "-z", "--", folder], capture_output=True, check=True, timeout=60).stdout.decode(
            "utf-8", "surrogateescape"
        )
    except (OSError, subprocess.SubprocessError):
        return sorted((root / folder).glob(pattern))
    tracked = {root / name for name in listed.split("\0") if name}
    return sorted(p for p in (root / folder).glob(pattern) if p in tracked)
