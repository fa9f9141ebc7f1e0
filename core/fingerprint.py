"""Fingerprints of the files a run reads, for content-addressed artifact keys.

A stage's artifact key (:func:`mocap.pipeline.stage_keys`) hashes the spec; the motion source's
input files (:meth:`mocap.interfaces.MotionSource.inputs`) enter it through
:func:`files_fingerprint`, so editing a clip in place gives new keys and the stages train again.

A file up to :data:`CONTENT_LIMIT` bytes is hashed by content (a copy on another machine or a fresh
clone gets the same key). A larger file is identified by its size and modification time instead,
so that a motion collection of many gigabytes is not read at every ``mocap run``: replacing such a
file in place changes its modification time and with it the key.

**Code.** :func:`package_digest` hashes the source files of an importable top-level package (the
folder that ``import name`` finds, or a single-module file): what the code fingerprint of a
component's plugin (:meth:`mocap.plugins.PluginSet.code_of`) puts into the stage keys, so that
editing a plugin's code retrains the stages that use it.
"""

from __future__ import annotations

import hashlib
import importlib.util
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


_SKIPPED_SUFFIXES = (".pyc", ".pyo")
_package_digests: dict[str, str] = {}


def _source_files(root: Path) -> list[Path]:
    """The files under ``root`` in a stable order, without byte-code caches and hidden entries."""
    out = []
    for path in root.rglob("*"):
        rel = path.relative_to(root).parts
        if any(part == "__pycache__" or part.startswith(".") for part in rel) or path.suffix in _SKIPPED_SUFFIXES:
            continue
        if path.is_file():
            out.append(path)
    return sorted(out, key=lambda p: p.relative_to(root).as_posix())


def package_digest(name: str) -> str:
    """sha256 (hex) of the source files of the top-level package or module ``name`` as installed:
    every file's path relative to the package folder and its content (:func:`_one`), byte-code
    caches left out. ``"unlocated"`` when ``import name`` would find nothing on disk (a module
    defined at run time). Computed once per process and name (:func:`forget_package_digests`)."""
    top = name.split(".", 1)[0]
    if top in _package_digests:
        return _package_digests[top]
    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):  # e.g. __main__ without a spec
        spec = None
    h = hashlib.sha256()
    if spec is not None and spec.submodule_search_locations:
        for folder in sorted(str(p) for p in spec.submodule_search_locations):
            root = Path(folder)
            for path in _source_files(root):
                h.update(f"{path.relative_to(root).as_posix()}\0{_one(path)}\n".encode("utf-8", "surrogateescape"))
        digest = h.hexdigest()
    elif spec is not None and spec.origin and Path(spec.origin).is_file():
        h.update(f"{Path(spec.origin).name}\0{_one(Path(spec.origin))}\n".encode("utf-8", "surrogateescape"))
        digest = h.hexdigest()
    else:
        digest = "unlocated"
    _package_digests[top] = digest
    return digest


def forget_package_digests() -> None:
    """Drop the per-process cache of :func:`package_digest` (a process that edits code and keys again)."""
    _package_digests.clear()


__all__ = ["CONTENT_LIMIT", "file_digest", "files_fingerprint", "forget_package_digests", "package_digest"]
