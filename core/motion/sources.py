"""What every motion source shares: the :class:`MotionSet` it returns, bad-file handling, resampling,
and the ``npz`` source for native clip files.

A motion source (a registered ``motion_source`` component, see :mod:`mocap.motion.plugin`) is
built from its validated params and converts some format to :class:`~mocap.motion.clip.Clip`
objects on a given skeleton with ``source.load(skeleton) -> MotionSet``. Every problem with a
file (missing, truncated, malformed, NaN, zero-length, made for another skeleton) raises
:class:`~mocap.motion.clip.MotionDataError` whose message names the file and the problem. Sources
with ``skip_bad`` skip such files instead and list them in :attr:`MotionSet.skipped`; when no file
loads at all, they raise.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Literal, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from mocap.motion.clip import MAX_FRAMES, Clip, MotionDataError, check_frame_count, check_npz  # noqa: F401  (re-exported)
from mocap.roles import MotionSource
from mocap.skeleton import Skeleton


VelocityMode = Literal["forward", "central_smoothed"]


class ReferenceVelocityParams(BaseModel):
    """How reference velocities are derived from a source's frames (every motion source's params)."""

    model_config = ConfigDict(extra="forbid")

    velocities: VelocityMode = Field(
        "forward",
        description="reference velocities: 'forward' differences (frame i: (x[i+1] - x[i]) fps) or 'central_smoothed', "
        "central differences and a Gaussian of velocity_sigma frames within each clip (PHC's code: np.gradient then "
        "gaussian_filter1d sigma 2, mode nearest; [P] §3.1 says only 'finite differences')",
    )
    velocity_sigma: float = Field(2.0, gt=0, le=100, description="frames; the Gaussian of 'central_smoothed' (PHC's code: 2)")


@dataclass
class MotionSet:
    """Clips a source loaded, plus the files it skipped.

    Attributes:
        clips: the loaded clips, all on one skeleton, in a stable order (sorted file order).
        skipped: ``(path, reason)`` for every file left out because it was unusable.
    """

    clips: list[Clip] = field(default_factory=list)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    #: how a motion library derives the clips' velocities (:class:`ReferenceVelocityParams`)
    velocities: VelocityMode = "forward"
    velocity_sigma: float = 2.0

    def with_velocities(self, params: "ReferenceVelocityParams") -> "MotionSet":
        """Record the source's velocity choice (returns ``self``)."""
        self.velocities, self.velocity_sigma = params.velocities, float(params.velocity_sigma)
        return self

    def __len__(self) -> int:
        return len(self.clips)

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.clips]

    def extend(self, other: "MotionSet") -> "MotionSet":
        """Append another set's clips and skipped files (returns ``self``)."""
        self.clips.extend(other.clips)
        self.skipped.extend(other.skipped)
        return self


def load_each(
    items: Iterable[tuple[Path, str]],
    load_one: Callable[[Path, str], Clip],
    *,
    skip_bad: bool,
    what: str,
    where: Sequence[Path | str] | None = None,
) -> MotionSet:
    """Load ``(path, clip_name)`` items with ``load_one``; skip or raise on :class:`MotionDataError`.

    With ``skip_bad`` a bad file lands in :attr:`MotionSet.skipped` with the error message as the
    reason; if nothing at all loads, a :class:`MotionDataError` lists every skipped file.
    """
    out = MotionSet()
    for path, name in items:
        try:
            out.clips.append(load_one(path, name))
        except MotionDataError as exc:
            if not skip_bad:
                raise
            out.skipped.append((str(path), str(exc)))
    if not out.clips:
        if out.skipped:
            listed = "; ".join(reason for _, reason in out.skipped)
            raise MotionDataError(f"no {what} clip could be loaded ({len(out.skipped)} file(s) skipped): {listed}")
        searched = f" in {', '.join(str(Path(w).expanduser()) for w in where)} (folders searched recursively)" if where else ""
        raise MotionDataError(f"no {what} files found{searched}")
    return out


def expand_paths(paths: Sequence[Path], suffix: str, ignore: Callable[[Path], bool] | None = None) -> list[tuple[Path, str]]:
    """Files and directories -> ``(file, clip name)`` pairs, in the given order, directories sorted.

    A file keeps its path (even if missing: the loader reports it) and is named by its stem. A
    directory contributes every ``*suffix`` file below it (recursively), named by its path relative
    to the directory without the suffix (``CMU/01/01_01_poses``), so that names are unique.
    """
    out: list[tuple[Path, str]] = []
    for p in paths:
        p = Path(p).expanduser()
        if p.is_dir():
            for f in sorted(p.rglob(f"*{suffix}")):
                if f.is_file() and not (ignore and ignore(f)):
                    out.append((f, f.relative_to(p).with_suffix("").as_posix()))
        else:
            out.append((p, p.stem))
    return out


def check_finite(path: Path | str, what: str, arr: np.ndarray) -> None:
    """Raise :class:`MotionDataError` naming ``path`` and the first frame holding NaN/inf in ``arr`` (T, ...)."""
    if not np.all(np.isfinite(arr)):
        bad = int(np.argwhere(~np.isfinite(arr.reshape(arr.shape[0], -1)))[0, 0])
        raise MotionDataError(f"{path}: {what} contains NaN or infinite values (first at frame {bad})")


#: the largest root position, m (a clip 10 km from the origin is a unit mistake or a damaged file)
MAX_POSITION = 10_000.0


def check_magnitude(path: Path | str, what: str, arr: np.ndarray, bound: float, unit: str = "") -> None:
    """Raise :class:`MotionDataError` naming ``path`` and the first frame of ``arr`` (T, ...) with a
    value beyond ``bound`` in magnitude (``arr`` is finite: :func:`check_finite` first)."""
    big = np.abs(arr.reshape(arr.shape[0], -1)) > bound
    if np.any(big):
        frame, col = (int(i) for i in np.argwhere(big)[0])
        value = float(arr.reshape(arr.shape[0], -1)[frame, col])
        raise MotionDataError(f"{path}: {what} holds {value:.3g}{unit} at frame {frame}; at most {bound:g}{unit} in magnitude")


def resample(
    src_times: np.ndarray,
    root_pos: np.ndarray,
    root_rot: np.ndarray,
    joint_rot: np.ndarray,
    dst_times: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample a trajectory at ``dst_times``: positions by linear interpolation, rotations by slerp.

    ``src_times`` (T,) is increasing; ``dst_times`` (T',) lies within ``[src_times[0], src_times[-1]]``
    (values outside are clamped). Shapes: root_pos (T, 3), root_rot (T, 4), joint_rot (T, J, 4).
    """
    import torch  # here: a motion source module imports without torch (`mocap validate` builds sources)

    from mocap.rotations import quat_normalize, quat_slerp

    t = np.clip(np.asarray(dst_times, dtype=np.float64), src_times[0], src_times[-1])
    i0 = np.clip(np.searchsorted(src_times, t, side="right") - 1, 0, len(src_times) - 2)
    span = src_times[i0 + 1] - src_times[i0]
    alpha = np.clip((t - src_times[i0]) / span, 0.0, 1.0)
    pos = root_pos[i0] + alpha[:, None] * (root_pos[i0 + 1] - root_pos[i0])
    a = torch.from_numpy(alpha)
    rot = quat_slerp(torch.from_numpy(root_rot[i0]), torch.from_numpy(root_rot[i0 + 1]), a)
    jrot = quat_slerp(torch.from_numpy(joint_rot[i0]), torch.from_numpy(joint_rot[i0 + 1]), a[:, None])
    return pos, quat_normalize(rot).numpy(), quat_normalize(jrot).numpy()


def check_clip_skeleton(clip: Clip, skeleton: Skeleton, where: str) -> None:
    """Raise :class:`MotionDataError` if ``clip`` was made for another skeleton than ``skeleton``."""
    if clip.skeleton != skeleton.name:
        raise MotionDataError(f"{where}: clip {clip.name!r} is for skeleton {clip.skeleton!r}, not {skeleton.name!r}")
    clip.check(skeleton.num_bodies)


# ------------------------------------------------------------------------------- native clips
class NpzParams(ReferenceVelocityParams):
    """Native ``.npz`` clip files (the format documented in :mod:`mocap.motion.clip`)."""

    model_config = ConfigDict(extra="forbid")

    paths: list[Path] = Field(min_length=1, description="clip files, or directories searched recursively for *.npz")
    skip_bad: bool = Field(default=True, description="skip unusable files (listed in the motion set) instead of failing")


class NpzSource(MotionSource):
    """Loads native clips; each must name the skeleton it is loaded onto."""

    def __init__(self, params: NpzParams):
        self.params = params

    @property
    def default_humanoid(self) -> str | None:
        """The skeleton named by the first readable clip (what the CLI loads them onto by default)."""
        for path, _ in expand_paths(self.params.paths, ".npz"):
            try:
                with np.load(path, allow_pickle=False) as data:
                    return str(data["skeleton"])
            except Exception:  # noqa: BLE001 - any unreadable file: try the next one
                continue
        return None

    def inputs(self) -> list[Path]:
        return [path for path, _ in expand_paths(self.params.paths, ".npz")]

    def load(self, skeleton: Skeleton) -> MotionSet:
        def one(path: Path, name: str) -> Clip:
            clip = Clip.load(path)
            check_clip_skeleton(clip, skeleton, str(path))
            return clip

        return load_each(
            expand_paths(self.params.paths, ".npz"), one, skip_bad=self.params.skip_bad, what="native npz", where=self.params.paths
        ).with_velocities(self.params)
