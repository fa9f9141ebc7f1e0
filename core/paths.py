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


#: the video files the renderers write
VIDEO_SUFFIXES = (".mp4", ".gif")
#: the longest file name most file systems take, bytes
MAX_NAME_BYTES = 255


def check_output_file(path: Path, option: str, *, video: bool = False) -> Path:
    """Raise :class:`UserError` unless ``path`` can be written as a file, before any work starts:
    (``video``) a ``.mp4`` or ``.gif`` name; not a directory or a device; a name the file system
    takes; its folder existing (it is not created) and writable. Every command that writes a file
    the user named checks it here; returns ``path``."""
    import os

    from mocap.errors import UserError

    path = Path(path)
    shown = repr(str(path)) if video else str(path)
    if video and path.suffix.lower() not in VIDEO_SUFFIXES:
        raise UserError(f"{option} {shown}: the video must be a {' or '.join(VIDEO_SUFFIXES)} file")
    if len(path.name.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES:
        raise UserError(f"{option} {shown[:80]}...: the file name is longer than {MAX_NAME_BYTES} bytes; choose a shorter one")
    try:
        if path.is_dir():
            raise UserError(f"{option} {shown}: a directory; give a file name (e.g. {path / ('out.mp4' if video else 'out.json')})")
        if path.exists() and not path.is_file():
            raise UserError(f"{option} {shown}: not a regular file; give a file name in a folder you can write")
        folder = path.parent
        for existing in (folder, *folder.parents):
            if existing.exists():
                if not existing.is_dir():
                    raise UserError(f"{option} {shown}: {existing} is a file, not a folder; choose another path")
                break
        if not folder.is_dir():
            raise UserError(f"{option} {shown}: the folder {folder} does not exist; create it or choose another path")
    except OSError as exc:  # e.g. a path longer than the file system allows (ENAMETOOLONG)
        raise UserError(f"{option} {shown[:200]}: not a usable path ({exc.strerror or exc}); choose another path") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UserError(f"{option} {shown}: not writable (permission denied); choose another path")
    return path


def write_output_text(path: Path, text: str, option: str) -> None:
    """Write ``text`` to a file the user named (:func:`check_output_file`, then an atomic write); a
    write that fails (a full disk, a read-only file system) is a :class:`UserError` naming it."""
    from mocap.checkpoint import StorageError, atomic_write_text
    from mocap.errors import UserError

    check_output_file(path, option)
    try:
        atomic_write_text(Path(path), text)
    except StorageError as exc:
        raise UserError(f"{option} {exc}") from None


__all__ = ["MAX_STEM", "VIDEO_SUFFIXES", "check_output_dir", "check_output_file", "confined", "safe_filename", "write_output_text"]
