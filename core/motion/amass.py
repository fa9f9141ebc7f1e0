"""AMASS ``.npz`` motion files on the ``smpl`` humanoid.

An AMASS file holds ``poses`` (T, 72 for SMPL, 156 for SMPL+H, 165 for SMPL-X): axis-angle
rotations, 3 numbers per SMPL joint in SMPL's joint order, joint 0 being the global root
orientation; ``trans`` (T, 3), the root translation, m; ``mocap_framerate`` (or
``mocap_frame_rate``), Hz; and ``betas`` (body shape, unused: our skeleton has fixed proportions).

What this loader assumes (stated once here):

* **World axes**: AMASS worlds are z up (``up_axis="z"``, the default) and are kept as they are;
  ``up_axis="y"`` is for y-up data (e.g. SMPL fits in a camera-style frame), which is turned z up
  with the +90 degree rotation about x (as for DeepMimic).
* **Body axes**: SMPL's rest pose is y up and facing +z (x to the body's left); ours is z up and
  facing +x (y to the left). With ``c`` the rotation taking SMPL body axes to ours
  (x -> y, y -> z, z -> x: 120 degrees about (1, 1, 1), ``c = (0.5, 0.5, 0.5, 0.5)``), a local joint
  rotation ``q`` becomes ``c q c*`` and the global root rotation ``q0`` becomes ``q0 c*``.
* **Hands**: with 72 numbers per frame all 24 SMPL joints are used; with more (SMPL+H, SMPL-X) only
  the 22 body joints are, because joints 22-23 of those layouts are finger joints, and the two
  SMPL hand bodies get the identity.
* **Root position**: ``trans`` is used as the pelvis position. SMPL adds a shape-dependent rest
  offset of the pelvis joint (a few cm) that needs the SMPL model file, which is not used here.
* Frames are resampled to ``fps`` (linear interpolation of positions, slerp of rotations) over the
  same time span; ``fps=None`` keeps the file's rate. AMASS clips do not loop.

Joints are mapped onto the skeleton by body name (:data:`SMPL_JOINT_NAMES`, compared ignoring case
and underscores). In a directory, files named ``shape.npz`` (AMASS per-subject shape files, no
motion) are ignored.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field

from mocap.motion.clip import Clip, MotionDataError
from mocap.motion.deepmimic import y_up_to_z_up_pos
from mocap.motion.sources import (
    MAX_POSITION,
    MotionSet,
    ReferenceVelocityParams,
    check_finite,
    check_frame_count,
    check_magnitude,
    check_npz,
    expand_paths,
    load_each,
    resample,
)
from mocap.roles import MotionSource
from mocap.skeleton import Skeleton

#: SMPL joints in the order of AMASS ``poses`` (names as the ``smpl`` humanoid's bodies).
SMPL_JOINT_NAMES: tuple[str, ...] = (
    "Pelvis",
    "L_Hip",
    "R_Hip",
    "Torso",
    "L_Knee",
    "R_Knee",
    "Spine",
    "L_Ankle",
    "R_Ankle",
    "Chest",
    "L_Toe",
    "R_Toe",
    "Neck",
    "L_Thorax",
    "R_Thorax",
    "Head",
    "L_Shoulder",
    "R_Shoulder",
    "L_Elbow",
    "R_Elbow",
    "L_Wrist",
    "R_Wrist",
    "L_Hand",
    "R_Hand",
)
NUM_BODY_JOINTS = 22
#: SMPL body axes -> ours (x->y, y->z, z->x), wxyz.
SMPL_TO_OURS = np.array([0.5, 0.5, 0.5, 0.5])
#: y-up world -> z-up world, +90 degrees about x, wxyz.
Y_UP_TO_Z_UP = np.array([np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0])


def _key(name: str) -> str:
    return name.replace("_", "").lower()


def body_map(skeleton: Skeleton, where: str = "amass") -> list[int]:
    """Skeleton body index of each SMPL joint (raises :class:`MotionDataError` for a non-SMPL skeleton)."""
    index = {_key(n): i for i, n in enumerate(skeleton.body_names)}
    missing = [n for n in SMPL_JOINT_NAMES if _key(n) not in index]
    if missing or index.get(_key(SMPL_JOINT_NAMES[0])) != 0:
        raise MotionDataError(
            f"{where}: AMASS clips drive the 24 SMPL joints; skeleton {skeleton.name!r} lacks {', '.join(missing) or 'Pelvis as its root'}: use humanoid 'smpl'"
        )
    return [index[_key(n)] for n in SMPL_JOINT_NAMES]


#: the arrays of an AMASS file that hold real numbers (checked before loading), and those with one row per frame
_REAL = ("poses", "trans", "betas", "mocap_framerate", "mocap_frame_rate")
_TIMED = ("poses", "trans")


def _read(path: Path) -> tuple[np.ndarray, np.ndarray, float, np.ndarray | None]:
    if not path.is_file():
        raise MotionDataError(f"{path}: no such file")
    check_npz(path, _REAL, _TIMED)
    try:
        with np.load(path, allow_pickle=False) as data:
            keys = set(data.files)
            rate_key = next((k for k in ("mocap_framerate", "mocap_frame_rate") if k in keys), None)
            missing = [k for k in ("poses", "trans") if k not in keys] + ([] if rate_key else ["mocap_framerate"])
            if missing:
                raise MotionDataError(f"{path}: not an AMASS motion file (missing {', '.join(missing)})")
            poses = np.array(data["poses"], dtype=np.float64)
            trans = np.array(data["trans"], dtype=np.float64)
            rate = float(data[rate_key])
            betas = np.array(data["betas"], dtype=np.float64).reshape(1, -1) if "betas" in keys else None
    except MotionDataError:
        raise
    except Exception as exc:  # zipfile.BadZipFile, EOFError, zlib.error, ValueError, ...
        raise MotionDataError(f"{path}: unreadable or truncated npz file ({type(exc).__name__}: {exc})") from None
    return poses, trans, rate, betas


#: plausible capture rates, Hz (AMASS: 60-250; a rate of 1e-9 would ask for terabytes when resampled)
MIN_RATE, MAX_RATE = 1.0, 10_000.0
#: the longest rotation vector, rad, and the largest shape coefficient (SMPL's betas lie within a few units)
MAX_ROTVEC, MAX_BETA = 1_000.0, 100.0


def load_amass_file(
    path: str | Path,
    skeleton: Skeleton,
    name: str | None = None,
    fps: float | None = 30.0,
    up_axis: Literal["z", "y"] = "z",
) -> Clip:
    """Read one AMASS ``.npz`` file and convert it to a :class:`Clip` on ``skeleton`` (see the module doc)."""
    path = Path(path)
    index = body_map(skeleton, str(path))
    poses, trans, rate, betas = _read(path)
    if poses.ndim != 2 or poses.shape[1] < 3 * NUM_BODY_JOINTS or poses.shape[1] % 3:
        raise MotionDataError(f"{path}: poses has shape {poses.shape}, expected (T, 72), (T, 156) or (T, 165)")
    T = poses.shape[0]
    if T == 0:
        raise MotionDataError(f"{path}: clip has no frames")
    if trans.shape != (T, 3):
        raise MotionDataError(f"{path}: trans has shape {trans.shape}, expected ({T}, 3) to match poses")
    if not np.isfinite(rate) or not MIN_RATE <= rate <= MAX_RATE:
        raise MotionDataError(f"{path}: mocap_framerate must be between {MIN_RATE:g} and {MAX_RATE:g} Hz, got {rate}")
    check_finite(path, "poses", poses)
    check_finite(path, "trans", trans)
    check_magnitude(path, "poses", poses, MAX_ROTVEC, " rad")
    check_magnitude(path, "trans", trans, MAX_POSITION, " m")
    if betas is not None and betas.size:
        check_finite(path, "betas", betas)
        check_magnitude(path, "betas", betas, MAX_BETA)
    if T < 2:
        raise MotionDataError(f"{path}: clip has {T} frame; at least 2 are needed")

    import torch  # here: a motion source module imports without torch (`mocap validate` builds sources)

    from mocap.rotations import quat_conjugate, quat_from_rotvec, quat_mul, quat_normalize

    n_joints = 24 if poses.shape[1] == 72 else NUM_BODY_JOINTS
    q = quat_from_rotvec(torch.from_numpy(poses[:, : 3 * n_joints].reshape(T, n_joints, 3)))
    c = torch.from_numpy(SMPL_TO_OURS).expand_as(q)
    local = quat_mul(quat_mul(c[:, 1:], q[:, 1:]), quat_conjugate(c[:, 1:]))
    root = quat_mul(q[:, 0], quat_conjugate(c[:, 0]))
    root_pos = trans
    if up_axis == "y":
        root = quat_mul(torch.from_numpy(Y_UP_TO_Z_UP).expand_as(root), root)
        root_pos = y_up_to_z_up_pos(trans)
    joint_rot = np.zeros((T, skeleton.num_bodies - 1, 4))
    joint_rot[..., 0] = 1.0
    for j in range(1, n_joints):
        joint_rot[:, index[j] - 1] = local[:, j - 1].numpy()
    root_rot = quat_normalize(root).numpy()

    out_fps = float(rate)
    if fps is not None and abs(fps - rate) > 1e-9 * rate:
        src_t = np.arange(T) / rate
        n = int(np.floor(src_t[-1] * fps + 1e-6)) + 1
        check_frame_count(path, n, f"clip resampled to {fps:g} fps")
        if n < 2:
            raise MotionDataError(f"{path}: clip lasts {src_t[-1]:.3g} s, too short for one frame interval at {fps} fps")
        root_pos, root_rot, joint_rot = resample(src_t, root_pos, root_rot, joint_rot, np.arange(n) / fps)
        out_fps = float(fps)

    clip = Clip(
        name=name or path.stem,
        skeleton=skeleton.name,
        fps=out_fps,
        root_pos=np.ascontiguousarray(root_pos),
        root_rot=root_rot,
        joint_rot=joint_rot,
        loop=False,
        source=str(path),
    )
    return clip.check(skeleton.num_bodies)


class AmassParams(ReferenceVelocityParams):
    """AMASS ``.npz`` files (the user's own copy) on the ``smpl`` humanoid."""

    model_config = ConfigDict(extra="forbid")

    paths: list[Path] = Field(min_length=1, description="AMASS .npz files, or directories searched recursively")
    fps: float | None = Field(default=30.0, gt=0, description="resample to this frame rate (None keeps each file's rate)")
    skip_bad: bool = Field(default=True, description="skip unusable files (listed in the motion set) instead of failing")
    up_axis: Literal["z", "y"] = Field(default="z", description="the files' world up axis (AMASS is z up)")


class AmassSource(MotionSource):
    """Loads AMASS clips onto the ``smpl`` humanoid (mapping SMPL joints by body name)."""

    default_humanoid = "smpl"

    def __init__(self, params: AmassParams):
        self.params = params

    def inputs(self) -> list[Path]:
        return [path for path, _ in expand_paths(self.params.paths, ".npz", ignore=lambda f: f.name == "shape.npz")]

    def load(self, skeleton: Skeleton) -> MotionSet:
        body_map(skeleton, "amass")
        p = self.params
        return load_each(
            expand_paths(p.paths, ".npz", ignore=lambda f: f.name == "shape.npz"),
            lambda path, name: load_amass_file(path, skeleton, name, fps=p.fps, up_axis=p.up_axis),
            skip_bad=p.skip_bad,
            where=p.paths,
            what="AMASS",
        ).with_velocities(p)
