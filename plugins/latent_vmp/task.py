"""VMP as a task action space (hierarchical control, :mod:`mocap.hierarchy`).

**This composition goes beyond the paper**: VMP is a motion *tracker* (a kinematic reference is
encoded to ``z_t`` and tracked); the paper has no task policy and no generative mode (its section 8
lists "a mechanism to traverse the latent space" as future work). Here a task policy chooses ``z``
and the two frozen VMP stages turn it into PD targets::

    task action a --to_latent--> z (d_z) --VAE decoder--> window M' = d(z): 2W+1 kinematic frames
        m = M'[W] (the centre frame, in its own heading frame, as the tracker's m_t)
        c = (m, z) per the tracker's conditioning (LM: standardized m and z; L: z; M: m;
            M5 / M10: m and the next 5 / 10 window frames, heading of the centre frame)
        tracker obs = [proprioception | a_{t-1} | a_{t-2} | c] --tracking policy (mean)--> raw action
        PD targets = the tracker's action map (residual: q of m + action; absolute: offset + scale action)

**Task action** (``VmpParams.task_action``):

* ``latent`` (default): the action *is* ``z`` (a Box of d_z dims, unbounded, or clamped to
  ``[-task_action_clip, task_action_clip]``): the VAE's prior is N(0, I), so a task policy whose
  initial output is near 0 starts at the prior mean, and ``random_action`` samples z ~ N(0, I).
* ``residual``: ``z = z_cur + a``, where ``z_cur`` is the encoder's posterior mean of the *current
  window*: the simulated humanoid's current frame (features reconstructed from the proprioception,
  :func:`features_from_proprio`) held over all 2W+1 frames, i.e. the edge padding VMP uses at clip
  boundaries (the simulation has no future frames). A zero residual asks the tracker to keep the
  current pose and velocities; the action is Markov in the observation (``z_cur`` is a function of
  it).

The tracker keeps the previous two raw actions per env (its observation has them). A task env
should call :meth:`mocap_vmp.latent.VmpLatent.reset_envs` for reset envs (their history restarts at
the hold-the-current-pose action); without that call the history carries over the reset.
"""

from __future__ import annotations

from typing import Any

import torch
from mocap.kinematics import dofs_from_local_rotations
from mocap.observations import proprioception_dim
from mocap.rotations import (
    matrix_to_quat,
    quat_conjugate,
    quat_from_rotvec,
    quat_mul,
    sixd_to_matrix,
)
from mocap.skeleton import Skeleton
from mocap_vmp.features import standardize
from torch import Tensor

__all__ = ["TrackerDecoder", "features_from_proprio"]


def _split_proprio(proprio: Tensor, B: int) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """(root height (N, 1), body positions rel. to the root (N, B-1, 3), 6-D rotations (N, B, 6),
    linear (N, B, 3) and angular (N, B, 3) velocities), all in the heading frame."""
    n = proprio.shape[0]
    i = 0
    h = proprio[:, :1]
    i = 1
    rel = proprio[:, i : i + 3 * (B - 1)].reshape(n, B - 1, 3)
    i += 3 * (B - 1)
    rot = proprio[:, i : i + 6 * B].reshape(n, B, 6)
    i += 6 * B
    lin = proprio[:, i : i + 3 * B].reshape(n, B, 3)
    i += 3 * B
    ang = proprio[:, i : i + 3 * B].reshape(n, B, 3)
    return h, rel, rot, lin, ang


def features_from_proprio(proprio: Tensor, skeleton: Skeleton, ee_index: Tensor, eps: float = 1e-4) -> Tensor:
    """(N, F) VMP per-frame features (:mod:`mocap_vmp.features` layout, own heading frame) of the
    state whose proprioception (``mocap.observations.proprioception``, 6-D convention ``zhou``) is
    ``proprio`` (N, 15 B - 2).

    ``h``, ``theta``, ``v`` and ``p`` are read off directly; ``q`` from the local body rotations
    (:func:`mocap.kinematics.dofs_from_local_rotations`); ``qd`` by a central difference of ``q``
    over the local rotations advanced by ``+-eps`` seconds with the bodies' angular velocities.
    """
    B = skeleton.num_bodies
    x = proprio[:, : proprioception_dim(B)].double()
    h, rel, rot6, lin, ang = _split_proprio(x, B)
    R = sixd_to_matrix(rot6)  # (N, B, 3, 3) heading-frame body rotations
    quat = matrix_to_quat(R)
    parents = torch.tensor(skeleton.parents[1:], dtype=torch.long, device=x.device)

    def local(qw: Tensor) -> Tensor:
        return quat_mul(quat_conjugate(qw.index_select(1, parents)), qw[:, 1:])

    q = dofs_from_local_rotations(skeleton, local(quat))
    q_plus = dofs_from_local_rotations(skeleton, local(quat_mul(quat_from_rotvec(eps * ang), quat)))
    q_minus = dofs_from_local_rotations(skeleton, local(quat_mul(quat_from_rotvec(-eps * ang), quat)))
    d = torch.remainder(q_plus - q_minus + torch.pi, 2 * torch.pi) - torch.pi
    qd = d / (2.0 * eps)
    theta = rot6[:, 0]
    v = torch.cat((lin[:, 0], ang[:, 0]), -1)
    ee = ee_index.to(x.device).long()
    p = rel[:, ee - 1].reshape(x.shape[0], -1)
    return torch.cat((h, theta, v, q, qd, p), -1).to(proprio.dtype)


class TrackerDecoder:
    """The frozen VMP tracking policy driven by a chosen ``z`` (module docstring)."""

    def __init__(self, latent: Any, tracker: dict[str, Any]):
        from mocap.rl.networks import ActorCritic
        from mocap_vmp.tracking import VmpTrackerParams, _action_map, conditioning_spec

        self.latent = latent
        self.params = VmpTrackerParams(**tracker["params"])
        if self.params.sixd != "zhou":
            raise ValueError("vmp task decoding: the tracker must observe 6-D rotations in the 'zhou' convention (the task env's)")
        self.spec = conditioning_spec(self.params.conditioning)
        if self.spec.future and self.params.future_heading != "current":
            raise ValueError("vmp task decoding supports M5/M10 trackers only with future_heading: current (the window's convention)")
        if self.spec.future > latent.params.window_half:
            raise ValueError(f"the tracker looks {self.spec.future} frames ahead, the VAE window only {latent.params.window_half}")
        policy = ActorCritic.from_config(tracker["policy_config"])
        policy.load_state_dict(tracker["policy_state"])
        self.policy = policy.eval()
        for prm in self.policy.parameters():
            prm.requires_grad_(False)
        self.action_map = _action_map(latent.skeleton, self.params)
        self.num_actions = int(self.action_map.offset.numel())
        self.proprio_dim = proprioception_dim(latent.skeleton.num_bodies)
        self.hist: Tensor | None = None  # (N, 2, A) raw actions a_{t-1}, a_{t-2}
        self._fresh: Tensor | None = None  # (N,) bool: restart the history at the next decode

    # ------------------------------------------------------------------------------ history
    def reset_envs(self, ids: Tensor) -> None:
        if self._fresh is not None:
            self._fresh[torch.as_tensor(ids, dtype=torch.long).cpu()] = True

    def _history(self, proprio: Tensor, feat: Tensor | None) -> Tensor:
        from mocap_vmp.tracking import hold_action

        n = proprio.shape[0]
        if self.hist is None or self.hist.shape[0] != n:
            self.hist = torch.zeros(n, 2, self.num_actions)
            self._fresh = torch.ones(n, dtype=torch.bool)
        assert self._fresh is not None
        if bool(self._fresh.any()):
            if self.action_map.mode == "absolute":
                if feat is None:
                    feat = features_from_proprio(proprio, self.latent.skeleton, self.latent.ee_index)
                q = feat[:, self.latent.layout.slices["q"]].float().cpu()
                hold = hold_action(self.action_map, q[self._fresh])
            else:
                hold = torch.zeros(int(self._fresh.sum()), self.num_actions)
            self.hist[self._fresh] = hold[:, None, :].expand(-1, 2, -1)
            self._fresh[:] = False
        return self.hist

    # ------------------------------------------------------------------------------ decoding
    def conditioning(self, window: Tensor, z: Tensor) -> tuple[Tensor, Tensor]:
        """(N, C) the tracker's conditioning from a decoded (unstandardized) window and z; and the centre frame."""
        lat = self.latent
        W = lat.params.window_half
        m = window[:, W]
        parts = []
        if self.spec.use_m:
            K = self.spec.future
            frames = window[:, W : W + 1 + K]
            parts.append(standardize(frames, lat.feat_mean, lat.feat_std).reshape(window.shape[0], -1))
        if self.spec.use_z:
            parts.append(z)
        return torch.cat(parts, -1), m

    @torch.no_grad()
    def __call__(self, proprio: Tensor, z: Tensor) -> Tensor:
        """(N, D) PD targets for latent ``z`` (N, d_z) at the state of ``proprio`` (N, >= 15 B - 2)."""
        from mocap_vmp.tracking import _clean

        lat = self.latent
        z = z.float().to(lat.feat_mean.device)
        prop = proprio[:, : self.proprio_dim].float().cpu()
        window = lat.decode_window(z)
        cond, m = self.conditioning(window, z)
        hist = self._history(prop, None)
        parts = [_clean(prop)]
        if self.params.prev_actions:
            parts.append(hist[:, : self.params.prev_actions].reshape(prop.shape[0], -1))
        parts.append(_clean(cond).cpu())
        a = self.policy.mean_action(torch.cat(parts, -1))
        if self.params.action_clip is not None:
            a = a.clamp(-self.params.action_clip, self.params.action_clip)
        targets = self.action_map(a, m[:, lat.layout.slices["q"]].cpu())
        self.hist = torch.stack((a, hist[:, 0]), 1)
        return targets
