"""Batched tensors exchanged between simulators, the motion library, observations and policies.

Conventions (documented once, tested at the edges):

* world frame: z up, x forward, y left; SI units (m, s, kg, rad, N);
* quaternions are ``(w, x, y, z)`` and unit-norm; a body rotation maps body-frame vectors to the
  world frame;
* ``N`` is the number of environments (batch), ``B`` the number of bodies of the humanoid in the
  skeleton's body order (body 0 is the root/pelvis), ``D`` the number of actuated hinge DoFs in
  the skeleton's DoF order;
* velocities are world-frame: linear velocity of the body origin, angular velocity in world axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, Self

import torch
from torch import Tensor


@dataclass
class HumanoidState:
    """Full kinematic state of ``N`` humanoids (simulated or reference).

    Attributes:
        root_pos: (N, 3) world position of the root body origin, m.
        root_rot: (N, 4) world orientation of the root, wxyz.
        root_lin_vel: (N, 3) world linear velocity of the root origin, m/s.
        root_ang_vel: (N, 3) world angular velocity of the root, rad/s.
        dof_pos: (N, D) hinge angles, rad, skeleton DoF order.
        dof_vel: (N, D) hinge angular velocities, rad/s.
        body_pos: (N, B, 3) world positions of every body origin, m (body 0 = root).
        body_rot: (N, B, 4) world orientations of every body, wxyz.
        body_lin_vel: (N, B, 3) world linear velocities of body origins, m/s.
        body_ang_vel: (N, B, 3) world angular velocities, rad/s.
    """

    root_pos: Tensor
    root_rot: Tensor
    root_lin_vel: Tensor
    root_ang_vel: Tensor
    dof_pos: Tensor
    dof_vel: Tensor
    body_pos: Tensor
    body_rot: Tensor
    body_lin_vel: Tensor
    body_ang_vel: Tensor

    @property
    def num_envs(self) -> int:
        return int(self.root_pos.shape[0])

    def index(self, ids: Tensor | slice) -> Self:
        """Rows ``ids`` of every tensor field (same dataclass type)."""
        rows: dict[str, Any] = {f.name: _take(getattr(self, f.name), ids) for f in fields(self)}
        return replace(self, **rows)

    def to(self, device: torch.device | str) -> Self:
        moved: dict[str, Any] = {f.name: _to(getattr(self, f.name), device) for f in fields(self)}
        return replace(self, **moved)


#: the tensor fields of :class:`HumanoidState`, in declaration order
HUMANOID_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(HumanoidState))


@dataclass
class SimState(HumanoidState):
    """A simulator's batched state: a :class:`HumanoidState` plus contact information.

    Attributes:
        contact_forces: (N, B, 3) world-frame net contact force on each body, N.
        body_contact: (N, B) bool, body touches the ground (or a prop) this control step.
        unstable: (N,) bool, the env went numerically unstable during the last step (NaN or
            huge accelerations); the simulator resets such envs and counts them.
        dof_force: (N, D) actuator torque applied at each hinge during the last physics
            substep, N m (for energy penalties).
    """

    contact_forces: Tensor = field(default_factory=lambda: torch.zeros(0))
    body_contact: Tensor = field(default_factory=lambda: torch.zeros(0, dtype=torch.bool))
    unstable: Tensor = field(default_factory=lambda: torch.zeros(0, dtype=torch.bool))
    dof_force: Tensor = field(default_factory=lambda: torch.zeros(0))


@dataclass
class TargetState:
    """State of every env's target prop (the strike task's box; :class:`mocap.interfaces.MovableTarget`):
    pos (N, 3), rot (N, 4) wxyz, lin_vel and ang_vel (N, 3) world frame, ``fallen`` (N,) bool (tilted
    beyond the prop's fallen angle)."""

    pos: Tensor
    rot: Tensor
    lin_vel: Tensor
    ang_vel: Tensor
    fallen: Tensor


@dataclass
class MotionFrames(HumanoidState):
    """Reference frames sampled from the motion library at given (clip, time) pairs.

    Attributes:
        clip_ids: (N,) long, index of the clip in the motion library.
        times: (N,) float, time within the clip, s (already wrapped for looping clips).
        ahead: the same clips one, two, ... control steps later, for an imitator that observes
            more than one reference frame (:attr:`mocap.interfaces.Imitator.reference_steps`;
            :meth:`mocap.motion.library.MotionLibrary.frames_ahead`); empty otherwise.
    """

    clip_ids: Tensor = field(default_factory=lambda: torch.zeros(0, dtype=torch.long))
    times: Tensor = field(default_factory=lambda: torch.zeros(0))
    ahead: tuple["MotionFrames", ...] = ()


@dataclass
class Observations:
    """What a policy sees, split by meaning so that latent spaces can condition on parts of it.

    Attributes:
        proprio: (N, P) proprioception s^p: the humanoid's own state in its heading frame
            (root height, body positions/rotations/velocities relative to the root).
        goal: (N, G) goal observation: the imitation goal s^{g-mimic} for imitators and latent
            encoders (reference minus current, in the heading frame), or a task's goal
            observation for task policies. ``None`` when the policy has no goal.
        extra: named additional tensors (for example VMP's (N, 2W+1, F) motion window).
    """

    proprio: Tensor
    goal: Tensor | None = None
    extra: dict[str, Tensor] = field(default_factory=dict)


def _take(value: object, ids: Tensor | slice) -> object:
    if isinstance(value, tuple):  # MotionFrames.ahead
        return tuple(v.index(ids) for v in value)
    if isinstance(value, Tensor) and value.dim() > 0 and value.numel() > 0:
        return value[ids]
    return value


def _to(value: object, device: torch.device | str) -> object:
    if isinstance(value, tuple):  # MotionFrames.ahead
        return tuple(v.to(device) for v in value)
    return value.to(device) if isinstance(value, Tensor) else value


@dataclass
class Trajectories:
    """Simulated vs reference body positions of N episodes.

    Attributes:
        sim, ref: (T, N, B, 3) world body positions, m.
        fps: frames per second of the sampling.
        mask: (T, N) bool, frame t of episode n is valid (None: all valid).
        sim_rot, ref_rot: (T, N, B, 4) world body orientations, wxyz (None: not recorded; the
            rotation metric is then NaN).
    """

    sim: Tensor
    ref: Tensor
    fps: float
    mask: Tensor | None = None
    sim_rot: Tensor | None = None
    ref_rot: Tensor | None = None

    def valid(self) -> Tensor:
        T, N = self.sim.shape[:2]
        return torch.ones(T, N, dtype=torch.bool, device=self.sim.device) if self.mask is None else self.mask.bool()
