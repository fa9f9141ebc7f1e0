"""Checkpoint files: written atomically, carrying the spec and the package versions that made them.

Loading never runs code from the file: :func:`load_checkpoint` reads with
``torch.load(weights_only=True)``, PyTorch's restricted unpickler, which builds only tensors,
containers (dict, list, tuple) and plain values and refuses every other Python object (a pickled
function call, a class, a NumPy array). A file that holds such objects is refused with one line;
if it is an older mocap checkpoint the user trusts, :func:`convert_checkpoint` (``mocap checkpoint
convert PATH --trust``) rewrites it once into the safe form. (Why not safetensors: a trainer
checkpoint also carries nested metadata, optimizer state and RNG states; the restricted unpickler
reads all of it without executing code, so one file format serves both, and the committed
checkpoints stay readable.)

Errors a user can act on are raised as :class:`CheckpointError` (a missing, corrupt or truncated
file, a format version this mocap does not read, a checkpoint trained for another humanoid or
architecture than the spec asks for) and :class:`StorageError` (a write that failed: disk full,
read-only folder); the CLI prints either as one ``error:`` line with exit code 2.
"""

from __future__ import annotations

import json
import math
import os
import platform
import re
import tempfile
import warnings
from importlib import metadata
from pathlib import Path
from typing import Any

import torch

from mocap.errors import DISK_FULL, CheckpointError, StorageError  # noqa: F401  (defined there, re-exported)


def package_versions() -> dict[str, str]:
    """Versions of Python and of the packages that decide a result."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for name in ("mocap", "torch", "mujoco", "numpy", "pydantic", "pluggy"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def component_provenance() -> dict[str, dict[str, str]]:
    """Which plugin package (and version) registered each component in this process
    (:meth:`mocap.plugins.PluginSet.provenance`); empty when the plugins cannot be listed."""
    from mocap.plugins import get_plugins

    try:
        return get_plugins().provenance()
    except Exception:  # noqa: BLE001 - a record for error messages must never fail a save
        return {}


def hardware() -> dict[str, Any]:
    info: dict[str, Any] = {"cpu_count": os.cpu_count(), "machine": platform.machine()}
    if torch.cuda.is_available():  # pragma: no cover - no GPU in CI
        info["cuda"] = torch.cuda.get_device_name(0)
    return info


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see the old file or the whole new one, never a part.

    The data goes to a temporary sibling ``.<name>.*.tmp`` that is renamed over ``path``. A process
    killed mid-write (SIGKILL, power loss) leaves only such a temporary behind; the next successful
    write of the same path removes it (temporaries carry their writer's pid, so another live
    process writing the same path concurrently keeps its own).

    A write that fails (disk full, read-only folder) raises :class:`StorageError` naming ``path``;
    the temporary is removed and an existing ``path`` is left as it was.
    """
    path = Path(path)
    existed = path.is_file()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise StorageError(path, exc, previous_kept=existed) from exc
    try:
        _write_fd(fd, data, path)
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and not isinstance(exc, StorageError):
            raise StorageError(path, exc, previous_kept=existed) from exc
        raise
    for stale in path.parent.glob(f".{path.name}.*.tmp"):  # left by an earlier writer that was killed
        if not _writer_alive(stale.name[len(path.name) + 2 :].split(".", 1)[0]):
            stale.unlink(missing_ok=True)


def _write_fd(fd: int, data: bytes, path: Path) -> None:
    """Write all of ``data`` to the open temporary ``fd`` (that will become ``path``) and flush it to
    the disk; closes ``fd``. (One function, so that tests can simulate a full disk here.)"""
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def _writer_alive(pid_text: str) -> bool:
    """Whether the process that named a temporary file (by its pid) still runs (unknown: assume so)."""
    try:
        pid = int(pid_text)
    except ValueError:
        return True
    if pid == os.getpid():
        return False  # our own earlier write of this path finished or failed: nothing is writing it now
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: Path, data: Any) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def save_checkpoint(path: Path, payload: dict[str, Any], *, spec_yaml: str | None = None) -> None:
    """``torch.save`` ``payload`` plus ``versions`` (and the resolved ``spec`` when given), atomically."""
    import io

    payload = dict(payload)
    payload.setdefault("versions", package_versions())
    payload.setdefault("components", component_provenance())
    if spec_yaml is not None:
        payload["spec"] = spec_yaml
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    atomic_write_bytes(Path(path), buffer.getvalue())


def load_checkpoint(
    path: Path, map_location: str | torch.device = "cpu", *, expect: str | tuple[str, ...] | None = None, what: str = "checkpoint"
) -> dict[str, Any]:
    """The dict saved by :func:`save_checkpoint`. Raises :class:`CheckpointError` for a missing,
    corrupt or truncated file, and (with ``expect``: the accepted ``format`` ids) for another
    format or another version of the same format (see :func:`check_format`)."""
    path = Path(path)
    if path.is_dir():
        raise CheckpointError(f"{path}: a directory, not a checkpoint file")
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint")
    _check_archive(path)
    try:
        with warnings.catch_warnings():  # torch's "Detected pickle protocol 4" is no news to the user
            warnings.simplefilter("ignore", UserWarning)
            data = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises EOFError, RuntimeError, UnpicklingError, ...
        from mocap.pickle_scan import convertible, refused_global

        named = refused_global(path)  # read from the pickle's opcodes: torch does not always name it
        if named is not None and not convertible(named):
            raise CheckpointError(
                f"{path}: refused: the checkpoint names the global {named}, which mocap does not load (a mocap checkpoint "
                "holds only tensors and plain data; loading this one would run code from it)"
            ) from None
        unsafe = named or _refused_global(exc)
        if unsafe is not None:
            raise CheckpointError(
                f"{path}: refused: the file holds pickled Python objects ({unsafe}) that loading would have to run; mocap "
                f"loads only tensors and plain data. If this is an older mocap checkpoint from a source you trust, convert it "
                f"once: mocap checkpoint convert {path} --trust"
            ) from None
        size = path.stat().st_size
        reason = str(exc).split(". ")[0].strip() or type(exc).__name__
        raise CheckpointError(
            f"{path}: unreadable checkpoint, the file is corrupt or truncated ({size} bytes; {type(exc).__name__}: {reason}); "
            "an interrupted copy or download? copy it again, or retrain"
        ) from None
    if not isinstance(data, dict):
        raise CheckpointError(f"{path}: not a mocap checkpoint (it holds a {type(data).__name__}, not a dict)")
    if expect is not None:
        check_format(path, data, expect, what=what)
    return data


#: a checkpoint's records unpack to at most this many times the file's size plus :data:`UNPACK_SLACK`
#: bytes (torch stores them uncompressed: a mocap checkpoint unpacks to its own size)
UNPACK_FACTOR = 4
UNPACK_SLACK = 256 * 2**20


def _check_archive(path: Path) -> None:
    """Refuse, before torch reads it, a zip checkpoint whose records unpack to far more than the file
    holds (torch would inflate them in memory), whose pickle is larger than
    :data:`mocap.pickle_scan.MAX_PICKLE_BYTES`, or whose pickle names a global that allocates what
    its arguments ask (:data:`mocap.pickle_scan.ALLOCATING_GLOBALS`, e.g. ``builtins.bytearray``)."""
    import zipfile

    from mocap.pickle_scan import MAX_PICKLE_BYTES, allocating_global

    size = path.stat().st_size
    try:
        with zipfile.ZipFile(path) as archive:
            infos = archive.infolist()
    except Exception:  # noqa: BLE001 - no zip (torch's legacy format) or a damaged one: torch.load says which
        return
    cap = UNPACK_FACTOR * size + UNPACK_SLACK
    total = sum(info.file_size for info in infos)
    if total > cap:
        biggest = max(infos, key=lambda info: info.file_size)
        raise CheckpointError(
            f"{path}: refused: its records unpack to {total:,} bytes from a file of {size:,} ({biggest.filename[:100]} alone to "
            f"{biggest.file_size:,}); a checkpoint unpacks to at most {UNPACK_FACTOR} times its size plus {UNPACK_SLACK // 2**20} MiB"
        )
    pickles = [info for info in infos if info.filename.endswith("data.pkl") and info.file_size > MAX_PICKLE_BYTES]
    if pickles:
        raise CheckpointError(
            f"{path}: refused: its pickle {pickles[0].filename[:100]} is {pickles[0].file_size:,} bytes; a checkpoint's "
            f"metadata is at most {MAX_PICKLE_BYTES:,} (the weights are records of their own)"
        )
    named = allocating_global(path)
    if named is not None:
        raise CheckpointError(
            f"{path}: refused: the checkpoint names the global {named}, which allocates whatever size the file asks for; "
            "a mocap checkpoint holds only plain tensors and data"
        )


def _refused_global(exc: BaseException) -> str | None:
    """The global a restricted (``weights_only``) load refused, e.g. ``numpy._core.multiarray._reconstruct``
    (None when ``exc`` is another failure: a corrupt or truncated file)."""
    m = re.search(r"Unsupported global: GLOBAL ([\w.]+)", str(exc))
    return m.group(1) if m else None


def _to_safe(obj: Any) -> Any:
    """``obj`` with NumPy arrays/scalars as tensors/numbers and deques/sets as lists (what a
    ``weights_only`` load accepts); NumPy's legacy RNG state tuple as :mod:`mocap.rng`'s dict."""
    import collections

    import numpy as np

    if isinstance(obj, dict):
        return {k: _to_safe(v) for k, v in obj.items()}
    if isinstance(obj, tuple) and len(obj) == 5 and obj[0] == "MT19937" and isinstance(obj[1], np.ndarray):
        return {"bit_generator": "MT19937", "keys": torch.from_numpy(obj[1].astype(np.int64)), "pos": int(obj[2]),
                "has_gauss": int(obj[3]), "cached_gaussian": float(obj[4])}  # fmt: skip
    if isinstance(obj, (list, tuple)):
        items = [_to_safe(v) for v in obj]
        return items if isinstance(obj, list) else tuple(items)
    if isinstance(obj, (collections.deque, set, frozenset)):
        return [_to_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return torch.from_numpy(np.array(obj, copy=True))
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def loads_safely(path: Path) -> bool:
    """Whether :func:`load_checkpoint` reads ``path`` (a restricted load, no code run): such a file
    needs no conversion."""
    try:
        load_checkpoint(path)
    except CheckpointError:
        return False
    return True


def convert_checkpoint(src: Path, dst: Path | None = None) -> Path:
    """Rewrite an older checkpoint that a safe load refuses into the safe form (``dst``, default in
    place). **This unpickles ``src`` without restriction, i.e. runs whatever code it holds: call it
    only on a file you trust.** A file that already loads safely is left as it is (copied unchanged
    to a ``dst`` elsewhere). Raises :class:`CheckpointError` when the result still is not safe
    (an object this converter does not know) or the file is not a checkpoint."""
    import io

    src = Path(src)
    dst = Path(dst) if dst is not None else src
    if not src.is_file():
        raise CheckpointError(f"{src}: no such checkpoint")
    if loads_safely(src):  # nothing to convert: the file stays byte for byte as it is
        if dst.resolve() != src.resolve():
            atomic_write_bytes(dst, src.read_bytes())
        return dst
    try:
        data = torch.load(src, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001
        raise CheckpointError(f"{src}: unreadable checkpoint ({type(exc).__name__}: {str(exc).split('. ')[0]})") from None
    if not isinstance(data, dict):
        raise CheckpointError(f"{src}: not a mocap checkpoint (it holds a {type(data).__name__}, not a dict)")
    safe = _to_safe(data)
    buffer = io.BytesIO()
    torch.save(safe, buffer)
    try:
        torch.load(io.BytesIO(buffer.getvalue()), map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001
        what = _refused_global(exc) or type(exc).__name__
        raise CheckpointError(f"{src}: cannot convert: it holds an object mocap does not know how to store safely ({what})") from None
    atomic_write_bytes(dst, buffer.getvalue())
    return dst


_FORMAT_RE = re.compile(r"^(?P<family>.+)/(?P<version>\d+)$")


def split_format(fmt: Any) -> tuple[str, int] | None:
    """``("mocap.rl.policy", 1)`` for ``"mocap.rl.policy/1"``; None for anything else."""
    m = _FORMAT_RE.match(fmt) if isinstance(fmt, str) else None
    return (m["family"], int(m["version"])) if m else None


def written_by(data: dict[str, Any]) -> str:
    """``"mocap 0.3.0"``: the package version recorded in a checkpoint (``"an unknown mocap"`` if none)."""
    versions = data.get("versions") if isinstance(data, dict) else None
    version = versions.get("mocap") if isinstance(versions, dict) else None
    return f"mocap {version}" if version else "an unknown mocap version"


def check_format(path: Path | str, data: dict[str, Any], expect: str | tuple[str, ...], *, what: str = "checkpoint") -> None:
    """Raise :class:`CheckpointError` unless ``data["format"]`` is one of ``expect``.

    A file of the same format family with another version (``mocap.rl.policy/2`` where this mocap
    reads ``mocap.rl.policy/1``) gets a message naming both versions and the mocap that wrote it."""
    accepted = (expect,) if isinstance(expect, str) else tuple(expect)
    got = data.get("format")
    if got in accepted:
        return
    mine = split_format(got)
    for fmt in accepted:
        want = split_format(fmt)
        if mine is not None and want is not None and mine[0] == want[0]:
            from mocap import __version__

            newer = mine[1] > want[1]
            advice = (
                f"a newer mocap wrote it: upgrade mocap, or use {written_by(data)}"
                if newer
                else f"this mocap cannot convert it; use {written_by(data)} or retrain"
            )
            raise CheckpointError(
                f"{path}: {what} format version {mine[1]} ({got!r}, written by {written_by(data)}), but mocap {__version__} "
                f"reads version {want[1]} ({fmt!r}); {advice}"
            )
    listed = " or ".join(repr(f) for f in accepted)
    raise CheckpointError(f"{path}: not a {what} file (format {got!r}, expected {listed})")


def training_status(data: dict[str, Any]) -> str | None:
    """``"in progress: 12,288 of 22,000,000 env steps (0.1%)"`` for a trainer checkpoint saved before
    the end of its budget (``finished`` False), None for a finished one or any other file."""
    if not isinstance(data, dict) or "finished" not in data or bool(data.get("finished")):
        return None
    params = data.get("params") if isinstance(data.get("params"), dict) else {}
    done = data.get("env_steps")
    total = params.get("total_env_steps") if isinstance(params, dict) else None
    if isinstance(done, (int, float)) and isinstance(total, (int, float)) and math.isfinite(done) and math.isfinite(total) and total > 0:
        return f"in progress: {int(done):,} of {int(total):,} env steps ({100.0 * done / total:.1f}%)"
    step = data.get("iteration", data.get("step"))
    return f"in progress (saved at step {int(step):,})" if isinstance(step, (int, float)) and math.isfinite(step) else "in progress"


def embedded_humanoid_section(data: dict[str, Any]) -> Any:
    """The ``humanoid:`` section of the spec embedded in a checkpoint (a mapping or a bare name;
    None without an embedded spec, or with one that does not parse)."""
    import yaml

    from mocap import safe_yaml

    text = data.get("spec") if isinstance(data, dict) else None
    if not isinstance(text, str):
        return None
    try:
        doc = safe_yaml.load(text)
    except (yaml.YAMLError, ValueError):
        return None
    return doc.get("humanoid") if isinstance(doc, dict) else None


def embedded_humanoid(data: dict[str, Any]) -> str | None:
    """The humanoid named by the spec embedded in a checkpoint (None without one)."""
    humanoid = embedded_humanoid_section(data)
    name = humanoid.get("name") if isinstance(humanoid, dict) else humanoid
    return str(name) if name else None


__all__ = [
    "CheckpointError",
    "StorageError",
    "atomic_write_bytes",
    "atomic_write_json",
    "component_provenance",
    "atomic_write_text",
    "check_format",
    "convert_checkpoint",
    "embedded_humanoid",
    "embedded_humanoid_section",
    "hardware",
    "load_checkpoint",
    "loads_safely",
    "package_versions",
    "save_checkpoint",
    "split_format",
    "training_status",
    "written_by",
]
