"""DeepMimic motion files (the 15 ``humanoid3d_*.txt`` clips bundled with ``pybullet``) on the ``amp`` humanoid.

File format: JSON with ``"Loop"`` (``"wrap"`` or ``"none"``) and ``"Frames"``, a list of frames of
44 numbers each, y up::

    duration (s to the next frame; the last frame's is ignored),
    root position (3, m), root rotation (w, x, y, z),
    chest (4), neck (4),
    right hip (4), right knee (1 angle), right ankle (4), right shoulder (4), right elbow (1),
    left hip (4), left knee (1), left ankle (4), left shoulder (4), left elbow (1)

Quaternions are the root's world rotation and each joint's local rotation relative to its parent;
knee and elbow angles are rotations about the joint's z axis (DeepMimic's revolute axis).

Conversion to our frame (z up, x forward, y left) is the +90 degree rotation about x:
``p' = (x, -z, y)``, and ``q' = (w, x, -z, y)`` for the root *and* every local joint quaternion,
because both skeletons' body frames are aligned with the world at rest. The hinge axis z becomes
``(0, -1, 0)``; the knee/elbow angle is applied about that axis, and the skeleton's own hinge axis
must be parallel to it (either sign: the DoF extraction then gives the signed angle).

Joints are mapped onto the skeleton **by body name** (:data:`JOINT_BODIES`); other non-root bodies
(the amp hands) get the identity. The frame rate is ``1 / duration`` rounded to an integer when it
is within 0.1 % of one (``0.033332`` s -> 30 fps). A file whose durations are not all equal
(``roll`` has one double-length frame) is resampled at that rate with slerp, stretching time by
less than 0.1 % so that the first and last frames are kept. A ``"wrap"`` clip's last frame is the
first frame of the next cycle (see :mod:`mocap.motion.clip`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from pydantic import ConfigDict, Field, model_validator

from mocap.motion.clip import Clip, MotionDataError
from mocap.motion.sources import (
    MAX_POSITION,
    MotionSet,
    ReferenceVelocityParams,
    check_finite,
    check_frame_count,
    check_magnitude,
    load_each,
    resample,
)
from mocap.roles import MotionSource
from mocap.skeleton import Skeleton

#: The bundled clip names (file ``humanoid3d_<name>.txt``).
CLIP_NAMES: tuple[str, ...] = (
    "walk",
    "run",
    "jump",
    "kick",
    "punch",
    "spinkick",
    "backflip",
    "cartwheel",
    "crawl",
    "roll",
    "dance_a",
    "dance_b",
    "spin",
    "getup_faceup",
    "getup_facedown",
)
FILE_PREFIX = "humanoid3d_"

#: The five DeepMimic walker clips pybullet also ships (``data/motions/walker/``, same format and
#: skeleton, zlib licence): a forward walk and turns to either side. Named in ``clips`` like the
#: bundled ones; not loaded by default (``clips: null`` is the 15 ``humanoid3d_*`` clips).
WALKER_CLIPS: dict[str, str] = {
    "walker_forward": "walker/0walk_forward.txt",
    "walker_turn_left0": "walker/turn_left0.txt",
    "walker_turn_left1": "walker/turn_left1.txt",
    "walker_turn_right0": "walker/turn_right0.txt",
    "walker_turn_right1": "walker/turn_right1.txt",
}
#: The locomotion clips: the bundled walk and run and the five walker clips.
LOCOMOTION_CLIPS: tuple[str, ...] = ("walk", "run", *WALKER_CLIPS)

#: DeepMimic joints in frame order after the root: (our body name, number of values).
JOINT_BODIES: tuple[tuple[str, int], ...] = (
    ("torso", 4),  # chest
    ("head", 4),  # neck
    ("right_thigh", 4),  # right hip
    ("right_shin", 1),  # right knee
    ("right_foot", 4),  # right ankle
    ("right_upper_arm", 4),  # right shoulder
    ("right_lower_arm", 1),  # right elbow
    ("left_thigh", 4),
    ("left_shin", 1),
    ("left_foot", 4),
    ("left_upper_arm", 4),
    ("left_lower_arm", 1),
)
FRAME_WIDTH = 1 + 3 + 4 + sum(n for _, n in JOINT_BODIES)  # 44
#: DeepMimic's revolute axis (z, y-up frame) expressed in our z-up frame.
HINGE_AXIS = np.array([0.0, -1.0, 0.0])
ROOT_BODY = "pelvis"


def default_data_dir() -> Path:
    """``pybullet_data.getDataPath()/data/motions`` (the bundled clips; not copied into this repo).

    Without ``pybullet_data`` (a broken or incomplete install) a :class:`MotionDataError` says what to install."""
    try:
        import pybullet_data
    except ImportError as exc:
        raise MotionDataError(
            f"the DeepMimic clips come from the pybullet_data package, which is missing or broken ({exc}); "
            "install it: pip install pybullet (or set the deepmimic source's data_dir to a folder of humanoid3d_*.txt files)"
        ) from None
    return Path(pybullet_data.getDataPath()) / "data" / "motions"


def y_up_to_z_up_pos(p: np.ndarray) -> np.ndarray:
    """``(x, y, z) -> (x, -z, y)``: the +90 degree rotation about x."""
    return np.stack((p[..., 0], -p[..., 2], p[..., 1]), axis=-1) + 0.0  # + 0.0: no negative zeros


def y_up_to_z_up_quat(q: np.ndarray) -> np.ndarray:
    """``(w, x, y, z) -> (w, x, -z, y)``: conjugation by the +90 degree rotation about x."""
    return np.stack((q[..., 0], q[..., 1], -q[..., 3], q[..., 2]), axis=-1)


def _normalize_quats(path: Path, what: str, q: np.ndarray) -> np.ndarray:
    """Normalize; the bundled files hold norms from 0.58 to 1.12 (DeepMimic normalizes on load), so
    only degenerate values (norm outside [0.25, 4], e.g. all zeros) are an error."""
    norm = np.linalg.norm(q, axis=-1)
    bad = (norm < 0.25) | (norm > 4.0)
    if np.any(bad):
        frame = int(np.argwhere(bad)[0, 0])
        raise MotionDataError(f"{path}: {what} quaternion at frame {frame} has norm {norm[frame]:.3g}, not a rotation")
    return q / norm[..., None]


def check_skeleton(skeleton: Skeleton, where: str = "deepmimic") -> None:
    """Raise :class:`MotionDataError` unless ``skeleton`` has the bodies DeepMimic clips drive."""
    names = set(skeleton.body_names)
    needed = (ROOT_BODY, *(b for b, _ in JOINT_BODIES))
    missing = [b for b in needed if b not in names]
    if missing or skeleton.body_names[0] != ROOT_BODY:
        raise MotionDataError(
            f"{where}: DeepMimic clips drive the 'amp' humanoid's bodies ({', '.join(needed)}); "
            f"skeleton {skeleton.name!r} lacks {', '.join(missing) or 'pelvis as its root'}: use humanoid 'amp'"
        )
    for body, n in JOINT_BODIES:
        if n != 1:
            continue
        hinges = skeleton.bodies[skeleton.body_index(body)].joint.hinges
        if len(hinges) != 1:
            raise MotionDataError(f"{where}: DeepMimic's {body} joint is a single hinge but skeleton {skeleton.name!r} gives it {len(hinges)} DoF")
        axis = np.asarray(hinges[0].axis, dtype=np.float64)
        if abs(abs(float(axis @ HINGE_AXIS)) - np.linalg.norm(axis)) > 1e-6:
            raise MotionDataError(f"{where}: skeleton {skeleton.name!r} hinges {body} about {tuple(axis)}; DeepMimic's axis is (0, -1, 0) (z up)")


#: the shortest and longest frame duration, s (frame rates of 1 to 10,000 Hz)
MIN_DURATION, MAX_DURATION = 1e-4, 1.0


def _frame_rate(path: Path, durations: np.ndarray) -> tuple[float, bool]:
    """(fps, uniform) from the per-frame durations (all but the last frame's)."""
    if np.any(durations <= 0):
        bad = int(np.argwhere(durations <= 0)[0, 0])
        raise MotionDataError(f"{path}: frame {bad} has non-positive duration {durations[bad]}")
    odd = (durations < MIN_DURATION) | (durations > MAX_DURATION)
    if np.any(odd):
        bad = int(np.argwhere(odd)[0, 0])
        raise MotionDataError(
            f"{path}: frame {bad} lasts {durations[bad]:.3g} s; a frame lasts {MIN_DURATION:g} to {MAX_DURATION:g} s (1 to 10,000 frames per second)"
        )
    dt = float(np.median(durations))
    fps = 1.0 / dt
    if abs(fps - round(fps)) < 1e-3 * fps:
        fps = float(round(fps))
    uniform = bool(np.all(np.abs(durations - 1.0 / fps) <= 1e-3 / fps))
    return fps, uniform


def _short_repr(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


#: largest DeepMimic file read (the bundled clips are 10-200 kB)
MAX_FILE_BYTES = 64 * 2**20


def load_deepmimic_file(path: str | Path, skeleton: Skeleton, name: str | None = None) -> Clip:
    """Read one DeepMimic JSON motion file and convert it to a z-up :class:`Clip` on ``skeleton``.

    Raises :class:`MotionDataError` naming the file for a missing/unreadable file, bad JSON,
    missing keys, frames of the wrong length, NaN values, fewer than 2 frames or a skeleton
    without the DeepMimic bodies.
    """
    path = Path(path)
    name = name or path.stem.removeprefix(FILE_PREFIX)
    check_skeleton(skeleton, str(path))
    if path.is_dir():
        raise MotionDataError(f"{path}: a directory, not a DeepMimic motion file")
    if not path.is_file():
        raise MotionDataError(f"{path}: no such file")
    if path.stat().st_size > MAX_FILE_BYTES:
        raise MotionDataError(f"{path}: {path.stat().st_size:,} bytes; a DeepMimic clip is at most {MAX_FILE_BYTES:,}")
    try:
        doc = json.loads(path.read_text(encoding="utf-8-sig"))  # -sig: a UTF-8 byte-order mark is accepted
    except json.JSONDecodeError as exc:
        raise MotionDataError(f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None
    except RecursionError:
        raise MotionDataError(f"{path}: not a DeepMimic motion file (JSON nested too deeply)") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:  # ValueError: e.g. an integer too long to parse
        raise MotionDataError(f"{path}: unreadable ({type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(doc, dict) or "Frames" not in doc:
        raise MotionDataError(f"{path}: not a DeepMimic motion file (missing the 'Frames' key)")
    loop_mode = doc.get("Loop", "none")
    if loop_mode not in ("wrap", "none", "clamp"):
        raise MotionDataError(f"{path}: 'Loop' is {loop_mode!r}, expected 'wrap' or 'none'")
    frames = doc["Frames"]
    if not isinstance(frames, list) or len(frames) == 0:
        raise MotionDataError(f"{path}: clip has no frames")
    for i, row in enumerate(frames):
        if not isinstance(row, list) or len(row) != FRAME_WIDTH:
            got = len(row) if isinstance(row, list) else type(row).__name__
            raise MotionDataError(f"{path}: frame {i} has {got} values, expected {FRAME_WIDTH}")
    for i, row in enumerate(frames):
        for j, value in enumerate(row):
            if type(value) not in (int, float):  # not bool (true would read as 1.0), nor a number written as text
                raise MotionDataError(f"{path}: frame {i} value {j} is {_short_repr(value)}; frames hold numbers")
    try:
        data = np.asarray(frames, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:  # OverflowError: an integer like 10**400
        raise MotionDataError(f"{path}: frames hold non-numeric values ({exc})") from None
    check_finite(path, "frame data", data)
    check_magnitude(path, "the root position", data[:, 1:4], MAX_POSITION, " m")
    T = data.shape[0]
    if T < 2:
        raise MotionDataError(f"{path}: clip has {T} frame; at least 2 are needed")

    fps, uniform = _frame_rate(path, data[:-1, 0])
    root_pos = y_up_to_z_up_pos(data[:, 1:4])
    root_rot = y_up_to_z_up_quat(_normalize_quats(path, "root", data[:, 4:8]))
    joint_rot = np.zeros((T, skeleton.num_bodies - 1, 4))
    joint_rot[..., 0] = 1.0
    col = 8
    for body, n in JOINT_BODIES:
        j = skeleton.body_index(body) - 1
        if n == 4:
            joint_rot[:, j] = y_up_to_z_up_quat(_normalize_quats(path, body, data[:, col : col + 4]))
        else:
            half = 0.5 * data[:, col]
            joint_rot[:, j, 0] = np.cos(half)
            joint_rot[:, j, 1:] = np.sin(half)[:, None] * HINGE_AXIS
        col += n

    if not uniform:
        src_t = np.concatenate(([0.0], np.cumsum(data[:-1, 0])))
        n = max(int(round(src_t[-1] * fps)), 1)
        check_frame_count(path, n + 1, f"clip resampled to {fps:g} fps")
        dst_t = np.linspace(0.0, src_t[-1], n + 1)
        root_pos, root_rot, joint_rot = resample(src_t, root_pos, root_rot, joint_rot, dst_t)

    clip = Clip(
        name=name,
        skeleton=skeleton.name,
        fps=fps,
        root_pos=root_pos,
        root_rot=root_rot,
        joint_rot=joint_rot,
        loop=loop_mode == "wrap",
        source=str(path),
    )
    return clip.check(skeleton.num_bodies)


class DeepMimicParams(ReferenceVelocityParams):
    """DeepMimic clips (by default the 15 bundled with ``pybullet``)."""

    model_config = ConfigDict(extra="forbid")

    clips: list[str] | None = Field(
        default=None,
        description=f"clip names (file stem without '{FILE_PREFIX}'; bundled: {', '.join(CLIP_NAMES)}; walker clips: "
        f"{', '.join(WALKER_CLIPS)}), or paths of .txt files; None loads every humanoid3d_*.txt file of data_dir",
    )
    data_dir: Path | None = Field(default=None, description="folder of the motion files (default: pybullet_data's data/motions)")
    skip_bad: bool = Field(default=False, description="skip unusable files (listed in the motion set) instead of failing")

    @model_validator(mode="after")
    def _known_names(self) -> "DeepMimicParams":
        if self.data_dir is None and self.clips is not None:
            unknown = [c for c in self.clips if c not in CLIP_NAMES and c not in WALKER_CLIPS and not c.endswith(".txt")]
            if unknown:
                names = ", ".join((*CLIP_NAMES, *WALKER_CLIPS))
                raise ValueError(f"unknown DeepMimic clip(s) {', '.join(map(repr, unknown))}; available: {names}")
        return self


class DeepMimicSource(MotionSource):
    """Loads DeepMimic JSON clips onto the ``amp`` humanoid."""

    default_humanoid = "amp"

    def __init__(self, params: DeepMimicParams | None = None):
        self.params = params or DeepMimicParams()

    @property
    def data_dir(self) -> Path:
        return Path(self.params.data_dir).expanduser() if self.params.data_dir is not None else default_data_dir()

    def available(self) -> list[str]:
        """Clip names found in :attr:`data_dir` (the bundled order first, then the rest sorted)."""
        found = {p.stem.removeprefix(FILE_PREFIX) for p in self.data_dir.glob(f"{FILE_PREFIX}*.txt")}
        return [n for n in CLIP_NAMES if n in found] + sorted(found - set(CLIP_NAMES))

    def files(self) -> list[tuple[Path, str]]:
        """``(file, clip name)`` for the requested clips; unknown names raise listing the available ones."""
        available = self.available()
        if self.params.clips is None:
            if not available:
                raise MotionDataError(f"{self.data_dir}: no {FILE_PREFIX}*.txt DeepMimic files found")
            return [(self.data_dir / f"{FILE_PREFIX}{n}.txt", n) for n in available]
        out = []
        for c in self.params.clips:
            if c.endswith(".txt"):
                p = Path(c).expanduser()
                p = p if p.is_absolute() else self.data_dir / p
                out.append((p, p.stem.removeprefix(FILE_PREFIX)))
            elif c in available:
                out.append((self.data_dir / f"{FILE_PREFIX}{c}.txt", c))
            elif c in WALKER_CLIPS and (self.data_dir / WALKER_CLIPS[c]).is_file():
                out.append((self.data_dir / WALKER_CLIPS[c], c))
            else:
                raise MotionDataError(f"unknown DeepMimic clip {c!r} in {self.data_dir}; available: {', '.join(available) or '(none)'}")
        return out

    def inputs(self) -> list[Path]:
        return [path for path, _ in self.files()]

    def load(self, skeleton: Skeleton) -> MotionSet:
        check_skeleton(skeleton, f"deepmimic ({self.data_dir})")
        return load_each(
            self.files(),
            lambda path, name: load_deepmimic_file(path, skeleton, name),
            skip_bad=self.params.skip_bad,
            what="DeepMimic",
        ).with_velocities(self.params)
