"""The native clip type every motion source converts to, and its ``.npz`` file format.

A :class:`Clip` stores what was captured, not what a simulator derives from it: the root
trajectory and the local rotation of every non-root body, for one named skeleton, at a fixed
frame rate. DoF angles, body positions and velocities are computed from it by the motion library
(:mod:`mocap.motion.library`) with the skeleton's forward kinematics.

``.npz`` layout (``numpy.savez``; all arrays float64 unless stated):

=============  ==============  ==========================================================
key            shape           meaning
=============  ==============  ==========================================================
format         ()              the string ``"mocap-clip"``
version        ()              int, format version (1)
name           ()              clip name
skeleton       ()              humanoid name the rotations refer to (``amp``, ``smpl``, ...)
fps            ()              frames per second
loop           ()              bool, the clip wraps around (see "Looping clips" below)
root_pos       (T, 3)          world position of the root, m, z up
root_rot       (T, 4)          world orientation of the root, wxyz
joint_rot      (T, B - 1, 4)   local rotation of bodies 1..B-1 relative to their parent, wxyz
=============  ==============  ==========================================================

Looping clips (DeepMimic's ``"Loop": "wrap"`` convention): the last frame is the first frame of
the next cycle, the same pose one period later with the root moved by the *cycle offset*
``root_pos[-1] - root_pos[0]`` (horizontal part). The period is therefore
``duration = (T - 1) / fps``, and a motion library playing the clip past its end adds the cycle
offset once per completed cycle (:mod:`mocap.motion.library`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

FORMAT_NAME = "mocap-clip"
FORMAT_VERSION = 1


class MotionDataError(ValueError):
    """A motion file or clip is unusable; the message names the file and the problem."""


#: the most frames of one clip, as read or after resampling (an hour at 60 fps; AMASS's longest
#: sequences have tens of thousands of frames at 120 Hz): a clip costs about 5 kB of memory per frame
MAX_FRAMES = 250_000
#: the most bytes one member of a motion ``.npz`` may unpack to (SMPL-X poses of MAX_FRAMES frames: 330 MB)
MAX_MEMBER_BYTES = 512 * 2**20


def check_frame_count(path: Path | str, frames: int, what: str = "clip") -> None:
    """Raise :class:`MotionDataError` when a clip would have more than :data:`MAX_FRAMES` frames."""
    if frames > MAX_FRAMES:
        raise MotionDataError(f"{path}: {what} has {frames:,} frames; a clip has at most {MAX_FRAMES:,} (split it into several files)")


def check_npz(path: Path, real: tuple[str, ...], timed: tuple[str, ...]) -> None:
    """Refuse, before numpy loads anything, an npz whose members unpack to more than
    :data:`MAX_MEMBER_BYTES`, whose ``timed`` arrays have more than :data:`MAX_FRAMES` rows, or
    whose ``real`` arrays hold anything but real numbers (bool, complex, text, objects): read from
    the zip's directory and each ``.npy`` header."""
    import zipfile

    try:
        archive = zipfile.ZipFile(path)
    except Exception:  # noqa: BLE001 - no zip or a damaged one: np.load says which
        return
    with archive:
        infos = {info.filename: info for info in archive.infolist()}
        for info in infos.values():
            if info.file_size > MAX_MEMBER_BYTES:
                raise MotionDataError(
                    f"{path}: {info.filename[:100]} unpacks to {info.file_size:,} bytes; a motion file's member is at most {MAX_MEMBER_BYTES:,}"
                )
        for key in dict.fromkeys((*real, *timed)):
            if f"{key}.npy" not in infos:
                continue
            try:
                with archive.open(f"{key}.npy") as fh:
                    version = np.lib.format.read_magic(fh)
                    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                    shape, _, dtype = read(fh)
            except Exception as exc:  # noqa: BLE001 - a damaged header: ValueError, zlib.error, EOFError, ...
                raise MotionDataError(f"{path}: {key} is not a readable array ({type(exc).__name__}: {str(exc)[:200]})") from None
            if key in real and dtype.kind not in "fiu":
                raise MotionDataError(f"{path}: {key} holds {dtype} values; expected real numbers")
            if key in timed and len(shape) >= 1:
                check_frame_count(path, int(shape[0]), key)


@dataclass
class Clip:
    """One motion clip on a named skeleton (see the module docstring for the fields)."""

    name: str
    skeleton: str
    fps: float
    root_pos: np.ndarray
    root_rot: np.ndarray
    joint_rot: np.ndarray
    loop: bool = False
    source: str = ""

    @property
    def num_frames(self) -> int:
        return int(self.root_pos.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame; also a looping clip's period (its last frame is the next cycle's first)."""
        return max(self.num_frames - 1, 0) / self.fps

    def check(self, num_bodies: int | None = None) -> "Clip":
        """Raise :class:`MotionDataError` naming the source if shapes or values are invalid."""
        where = self.source or self.name
        T = self.num_frames
        if T < 2:
            raise MotionDataError(f"{where}: clip {self.name!r} has {T} frame(s); at least 2 are needed")
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise MotionDataError(f"{where}: frame rate must be positive, got {self.fps}")
        if self.root_pos.shape != (T, 3):
            raise MotionDataError(f"{where}: root_pos has shape {self.root_pos.shape}, expected ({T}, 3)")
        if self.root_rot.shape != (T, 4):
            raise MotionDataError(f"{where}: root_rot has shape {self.root_rot.shape}, expected ({T}, 4)")
        if self.joint_rot.ndim != 3 or self.joint_rot.shape[0] != T or self.joint_rot.shape[2] != 4:
            raise MotionDataError(f"{where}: joint_rot has shape {self.joint_rot.shape}, expected ({T}, bodies-1, 4)")
        if num_bodies is not None and self.joint_rot.shape[1] != num_bodies - 1:
            raise MotionDataError(
                f"{where}: clip has rotations for {self.joint_rot.shape[1] + 1} bodies but skeleton "
                f"{self.skeleton!r} has {num_bodies}; is it for another skeleton?"
            )
        for key in ("root_pos", "root_rot", "joint_rot"):
            arr = getattr(self, key)
            if not np.all(np.isfinite(arr)):
                bad = int(np.argwhere(~np.isfinite(arr.reshape(T, -1)))[0, 0])
                raise MotionDataError(f"{where}: {key} contains NaN or infinite values (first at frame {bad})")
        norms = np.concatenate([np.linalg.norm(self.root_rot, axis=-1).ravel(), np.linalg.norm(self.joint_rot, axis=-1).ravel()])
        if np.any(np.abs(norms - 1.0) > 1e-3):
            raise MotionDataError(f"{where}: quaternions are not unit-norm (max deviation {np.abs(norms - 1).max():.3g})")
        return self

    def save(self, path: str | Path) -> None:
        np.savez(
            path,
            format=np.array(FORMAT_NAME),
            version=np.array(FORMAT_VERSION),
            name=np.array(self.name),
            skeleton=np.array(self.skeleton),
            fps=np.array(float(self.fps)),
            loop=np.array(bool(self.loop)),
            root_pos=np.asarray(self.root_pos, dtype=np.float64),
            root_rot=np.asarray(self.root_rot, dtype=np.float64),
            joint_rot=np.asarray(self.joint_rot, dtype=np.float64),
        )

    @classmethod
    def load(cls, path: str | Path) -> "Clip":
        """Read a native ``.npz`` clip; any problem raises :class:`MotionDataError` naming the file."""
        path = Path(path)
        if not path.is_file():
            raise MotionDataError(f"{path}: no such file")
        arrays = ("root_pos", "root_rot", "joint_rot")
        check_npz(path, (*arrays, "fps"), arrays)
        try:
            with np.load(path, allow_pickle=False) as data:
                keys = set(data.files)
                missing = {"format", "name", "skeleton", "fps", "root_pos", "root_rot", "joint_rot"} - keys
                if missing:
                    raise MotionDataError(f"{path}: not a mocap clip file (missing {', '.join(sorted(missing))})")
                if str(data["format"]) != FORMAT_NAME:
                    raise MotionDataError(f"{path}: format is {str(data['format'])!r}, expected {FORMAT_NAME!r}")
                version = int(data["version"]) if "version" in keys else FORMAT_VERSION
                if version != FORMAT_VERSION:
                    raise MotionDataError(
                        f"{path}: clip format version {version}, but this mocap reads version {FORMAT_VERSION}"
                        + ("; a newer mocap wrote it: upgrade mocap" if version > FORMAT_VERSION else "")
                    )
                clip = cls(
                    name=str(data["name"]),
                    skeleton=str(data["skeleton"]),
                    fps=float(data["fps"]),
                    loop=bool(data["loop"]) if "loop" in keys else False,
                    root_pos=np.array(data["root_pos"], dtype=np.float64),
                    root_rot=np.array(data["root_rot"], dtype=np.float64),
                    joint_rot=np.array(data["joint_rot"], dtype=np.float64),
                    source=str(path),
                )
        except MotionDataError:
            raise
        except Exception as exc:  # zipfile.BadZipFile, EOFError, ValueError, ...
            raise MotionDataError(f"{path}: unreadable or truncated clip file ({type(exc).__name__}: {exc})") from None
        return clip.check()
