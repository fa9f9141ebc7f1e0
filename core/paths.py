"""Names from user data made safe as file names, and paths confined to the folder they belong in.

A clip's name comes from inside a motion file and a spec's ``name`` from a YAML file: neither may
steer a write outside the run or artifact directory (``../../x``), break a Markdown table (a
newline, ``|``) or exceed a file-name limit (255 bytes on most file systems).
"""

from __future__ import annotations

import re
from pathlib import Path

_UNSAFE = re.compile(r"[^A-Za-z0-9._+-]+")
#: longest file-name stem produced (leaves room for a prefix and a suffix within 255 bytes)
MAX_STEM = 120


def safe_filename(name: str, *, fallback: str = "unnamed") -> str:
    """``name`` as one file-name component: runs of characters outside ``[A-Za-z0-9._+-]`` become
    ``_``, leading dots and underscores are dropped (no ``..``, no hidden files), at most :data:`MAX_STEM` characters,
    never empty (``fallback``)."""
    return _UNSAFE.sub("_", str(name)).lstrip("._")[:MAX_STEM].rstrip("_") or fallback


def confined(base: Path, *parts: str) -> Path:
    """``base / parts...``, refusing (``ValueError``) a result that is not inside ``base`` once
    resolved (``..`` components, absolute parts, symlinks pointing out)."""
    base = Path(base)
    path = base.joinpath(*parts)
    root = base.resolve()
    if not path.resolve().is_relative_to(root):
        raise ValueError(f"{path}: outside {base}")
    return path


def check_output_dir(path: Path, option: str = "--out") -> None:
    """Raise :class:`UserError` unless ``path`` is (or can be created as) a writable directory —
    before anything is trained, so a bad ``--out`` costs nothing."""
    import tempfile

    from mocap.errors import UserError

    path = Path(path)
    try:
        for existing in (path, *path.parents):
            if existing.exists() or existing.is_symlink():
                if not existing.is_dir():
                    where = "it is" if existing == path else f"{existing} is"
                    raise UserError(f"{option} {path}: {where} a file, not a directory; choose another {option}")
                break
    except OSError as exc:  # e.g. a name longer than the file system allows (ENAMETOOLONG)
        raise UserError(f"{option} {path}: not a usable path ({exc.strerror or exc}); choose another {option}") from None
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise UserError(f"{option} {path}: not writable ({exc.strerror or exc}); choose another {option}") from None


__all__ = ["MAX_STEM", "check_output_dir", "confined", "safe_filename"]
