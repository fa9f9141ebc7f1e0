"""The example plugin's motion source ``sway`` and metric ``root_drift`` (imported when a spec uses them)."""

from __future__ import annotations

import math

import numpy as np
import torch

from mocap.humanoids.common import rest_root_height
from mocap.interfaces import Metric, MotionSource
from mocap.kinematics import local_rotations_from_dofs
from mocap.motion.clip import Clip
from mocap.motion.sources import MotionSet
from mocap.skeleton import Skeleton
from mocap.state import Trajectories
from mocap_example import SwayParams


class SwaySource(MotionSource):
    """One looping clip on any skeleton: every hinge swings sinusoidally around zero, root still."""

    def __init__(self, params: SwayParams):
        self.params = params

    def load(self, skeleton: Skeleton) -> MotionSet:
        p = self.params
        frames = int(round(p.seconds * p.fps)) + 1
        t = torch.arange(frames, dtype=torch.float64) / p.fps
        phase = torch.linspace(0, math.pi, skeleton.num_dofs, dtype=torch.float64)
        low = torch.tensor([h.range[0] for h in skeleton.hinges], dtype=torch.float64)
        high = torch.tensor([h.range[1] for h in skeleton.hinges], dtype=torch.float64)
        dofs = p.amplitude * torch.sin(2 * math.pi * p.frequency * t[:, None] + phase)
        dofs = torch.minimum(torch.maximum(dofs, low), high)
        joint_rot = local_rotations_from_dofs(skeleton, dofs).numpy()
        root_pos = np.zeros((frames, 3))
        root_pos[:, 2] = rest_root_height(skeleton) + 0.02
        root_rot = np.tile([1.0, 0.0, 0.0, 0.0], (frames, 1))
        clip = Clip("sway", skeleton.name, p.fps, root_pos, root_rot, joint_rot, loop=False, source="mocap_example:sway")
        return MotionSet(clips=[clip.check(skeleton.num_bodies)])


class RootDrift(Metric):
    """Largest horizontal distance between simulated and reference root over an episode, mm."""

    name = "root_drift"
    unit = "mm"

    def __call__(self, tr: Trajectories) -> torch.Tensor:
        d = torch.linalg.vector_norm(tr.sim[..., 0, :2] - tr.ref[..., 0, :2], dim=-1)  # (T, N)
        d = torch.where(tr.valid(), d, torch.zeros_like(d))
        return 1000.0 * d.amax(0)
