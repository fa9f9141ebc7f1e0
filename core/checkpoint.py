"""Checkpoint files: written atomically, carrying the spec and the package versions that made them."""

from __future__ import annotations

import json
import os
import platform
import tempfile
from importlib import metadata
from pathlib import Path
from typing import Any

import torch


def package_versions() -> dict[str, str]:
    """Versions of Python and of the packages that decide a result."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for name in ("mocap", "torch", "mujoco", "numpy", "pydantic", "pluggy"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


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
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    for stale in path.parent.glob(f".{path.name}.*.tmp"):  # left by an earlier writer that was killed
        if not _writer_alive(stale.name[len(path.name) + 2 :].split(".", 1)[0]):
            stale.unlink(missing_ok=True)


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
    if spec_yaml is not None:
        payload["spec"] = spec_yaml
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    atomic_write_bytes(Path(path), buffer.getvalue())


def load_checkpoint(path: Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint")
    try:
        return torch.load(path, map_location=map_location, weights_only=False)
    except Exception as exc:  # noqa: BLE001
        raise ValueError(f"{path}: unreadable checkpoint ({type(exc).__name__}: {exc})") from None


__all__ = [
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "hardware",
    "load_checkpoint",
    "package_versions",
    "save_checkpoint",
]
