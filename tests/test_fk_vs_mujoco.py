"""The motion library's forward kinematics agrees with MuJoCo on every frame of every bundled clip."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from mocap.humanoids.amp import amp_skeleton
from mocap.motion.library import MotionLibrary
from mocap.plugins import get_plugins
from mocap_sim_mujoco.mjcf import build_model, model_index


@pytest.fixture(scope="module")
def amp_lib():
    skeleton = amp_skeleton()
    motion_set = get_plugins().get("motion_source", "deepmimic").build({}).load(skeleton)
    return skeleton, MotionLibrary(motion_set, skeleton, dtype=torch.float64)


def test_every_frame_of_every_clip_matches_mj_kinematics(amp_lib):
    skeleton, lib = amp_lib
    model = build_model(skeleton)
    index = model_index(model, skeleton)
    data = mujoco.MjData(model)
    root_pos, root_rot, dofs = lib.root_pos.numpy(), lib.root_rot.numpy(), lib.dof_pos.numpy()
    body_pos, body_rot = lib.body_pos.numpy(), lib.body_rot.numpy()
    assert lib.total_frames == len(root_pos) > 1500  # all 15 clips, every frame
    worst_pos, worst_rot = 0.0, 0.0
    for f in range(lib.total_frames):
        data.qpos[index.root_qpos : index.root_qpos + 3] = root_pos[f]
        data.qpos[index.root_qpos + 3 : index.root_qpos + 7] = root_rot[f]
        data.qpos[index.dof_qpos] = dofs[f]
        mujoco.mj_kinematics(model, data)
        pos = data.xpos[index.body_ids]
        quat = data.xquat[index.body_ids]
        worst_pos = max(worst_pos, float(np.linalg.norm(pos - body_pos[f], axis=-1).max()))
        dot = np.abs(np.sum(quat * body_rot[f], axis=-1)).clip(max=1.0)
        worst_rot = max(worst_rot, float((2 * np.arccos(dot)).max()))
    assert worst_pos < 1e-3, f"body position error {worst_pos * 1000:.3f} mm"
    assert worst_rot < 1e-4, f"body rotation error {worst_rot:.2e} rad"
