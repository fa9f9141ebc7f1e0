"""Fingerprints of the files a run reads, for content-addressed artifact keys.

A stage's artifact key (:func:`mocap.pipeline.stage_keys`) hashes the spec; the motion source's
input files (:meth:`mocap.interfaces.MotionSource.inputs`) enter it through
:func:`files_fingerprint`, so editing a clip in place gives new keys and the stages train again.

A file up to :data:`CONTENT_LIMIT` bytes is hashed by content (a copy on another machine or a fresh
clone gets the same key). A larger file is identified by its size and modification time instead,
so that a motion collection of many gigabytes is not read at every ``mocap run``: replacing such a
file in place changes its modification time and with it the key.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Iterable

CONTENT_LIMIT = 16 * 2**20


def file_digest(path: Path) -> str:
    """sha256 of a file's bytes."""
    h = hashlib.sha256()
    with Path(path).open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _one(path: Path) -> str:
    try:
        st = path.stat()
    except OSError as exc:  # missing, a name the OS cannot look up: the loader reports it later
        return f"unreadable:{type(exc).__name__}"
    if not path.is_file():
        return "not-a-file"
    if st.st_size > CONTENT_LIMIT:
        return f"stat:{st.st_size}:{st.st_mtime_ns}"
    try:
        return file_digest(path)
    except OSError as exc:
        return f"unreadable:{type(exc).__name__}"


def files_fingerprint(paths: Iterable[Path]) -> str:
    """One hex digest of the files' names (without their folders, in order) and contents (module
    docstring). The folders are left out so that a clone elsewhere, or another site-packages, gives
    the same digest for the same files."""
    h = hashlib.sha256()
    for p in paths:
        h.update(f"{Path(p).name}\0{_one(Path(p))}\n".encode("utf-8", "surrogateescape"))
    return h.hexdigest()


__all__ = ["CONTENT_LIMIT", "file_digest", "files_fingerprint"]
