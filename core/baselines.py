"""Baseline policies that need no training."""

from __future__ import annotations

from torch import Tensor

from mocap.interfaces import Imitator
from mocap.state import MotionFrames, Observations, SimState


class PDReplay(Imitator):
    """PD targets = the reference pose of the next frame (no feedback, no learning).

    What the simulator does with the raw reference: the humanoid follows the clip's joint angles
    but nothing keeps its root on track, so it falls within about a second on most clips
    (measured here: ~26 steps on walk). It is the floor any imitator must beat.
    """

    def observe(self, state: SimState, reference: MotionFrames) -> Observations:
        return Observations(proprio=state.dof_pos, goal=reference.dof_pos)

    def act(self, obs: Observations, deterministic: bool = True) -> Tensor:
        assert obs.goal is not None
        return obs.goal
