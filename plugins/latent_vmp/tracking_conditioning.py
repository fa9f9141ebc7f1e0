"""VMP stage II conditioning and action helpers shared by the env and the imitator: ``c_t``
(:class:`VmpConditioning`), non-looping reference frames, the action map and the hold-pose action.

Moved out of :mod:`mocap_vmp.tracking` (re-exported there); the design is described in that
module's docstring."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from mocap.rotations import heading_quat_inv
from mocap.skeleton import Skeleton
from mocap.state import HumanoidState, MotionFrames
from mocap_vmp.features import FeatureLayout, clip_starts, standardize
from mocap_vmp.tracking_params import VmpTrackerParams, conditioning_dim, conditioning_spec
from mocap_vmp.tracking_reward import state_features


# ------------------------------------------------------------------------- the conditioning
class VmpConditioning:
    """Builds ``c_t`` for (clip, time) pairs of a motion library from a trained :class:`VmpLatent`.

    The per-frame latents of ``library`` are the latent's saved ones when they were made on the
    same clips, else encoded here once (posterior means)."""

    def __init__(self, params: VmpTrackerParams, latent: Any, library: Any, dt: float):
        self.params = params
        self.spec = conditioning_spec(params.conditioning)
        self.latent = latent
        self.library = library
        self.layout: FeatureLayout = latent.layout
        self.dt = float(dt)
        dev = library.device
        self.ee_index = latent.ee_index.to(dev)
        self.mean = latent.feat_mean.detach().to(dev, library.dtype)
        self.std = latent.feat_std.detach().to(dev, library.dtype)
        rstd = self.std.clamp_min(params.reward_std_min)
        rstd[self.layout.theta] = 1.0
        self.reward_std = rstd
        self.starts = clip_starts(library).to(dev)
        self.frame_latents: Tensor | None = None
        if self.spec.use_z:
            saved = getattr(latent, "frame_latents", None)
            same = saved is not None and list(getattr(latent, "clip_names", [])) == list(library.clip_names)
            if same and saved is not None and saved.shape[0] == library.total_frames:
                self.frame_latents = saved.detach().to(dev, library.dtype)
            else:
                self.frame_latents = latent.encode_library(library).detach().to(dev, library.dtype)
        self.dim = conditioning_dim(params.conditioning, self.layout.dim, int(latent.latent_dim))

    def standardize(self, x: Tensor) -> Tensor:
        """With the VAE's statistics (the observation's ``m_t``)."""
        return standardize(x, self.mean.to(x), self.std.to(x))

    def reward_standardize(self, x: Tensor) -> Tensor:
        """With the VAE's statistics, std floored at ``reward_std_min`` (the reward's quantities)."""
        return standardize(x, self.mean.to(x), self.reward_std.to(x))

    def frame_rows(self, clip_ids: Tensor, times: Tensor) -> Tensor:
        """(N,) packed row of the clip frame nearest each time (clamped into the clip)."""
        lib = self.library
        c = clip_ids.to(self.starts.device).long()
        k = torch.round(times.to(torch.float64) * lib._fps64[c]).long()
        k = torch.minimum(k.clamp_min(0), lib.num_frames.to(k.device)[c] - 1)
        return self.starts[c] + k

    def __call__(self, ref: HumanoidState, clip_ids: Tensor, times: Tensor) -> tuple[Tensor, Tensor]:
        """(N, C) conditioning and (N, F) the unstandardized own-heading features of ``ref`` (the
        reference at ``times`` of ``clip_ids``)."""
        lib = self.library
        feat = state_features(ref, self.ee_index)
        parts: list[Tensor] = []
        if self.spec.use_m:
            parts.append(self.standardize(feat))
        K = self.spec.future
        if K:
            N = feat.shape[0]
            c = clip_ids.to(lib.device).long()
            dur = lib._dur64.to(lib.device)[c]
            ks = torch.arange(1, K + 1, device=lib.device, dtype=torch.float64)
            t = (times.to(lib.device, torch.float64)[:, None] + ks[None, :] * self.dt).minimum(dur[:, None])  # (N, K)
            fut = clip_frames(lib, c[:, None].expand(N, K).reshape(-1), t.reshape(-1))
            hinv = None
            if self.params.future_heading == "current":
                hinv = heading_quat_inv(ref.root_rot)[:, None, :].expand(N, K, 4).reshape(-1, 4)
            ff = state_features(fut, self.ee_index, hinv).to(feat)
            parts.append(self.standardize(ff).reshape(N, K * feat.shape[-1]))
        if self.spec.use_z:
            assert self.frame_latents is not None
            parts.append(self.frame_latents[self.frame_rows(clip_ids, times)].to(feat))
        return torch.cat(parts, -1), feat


def clip_frames(library: Any, clip_ids: Tensor, times: Tensor) -> MotionFrames:
    """``library.frames`` with the times clamped into ``[0, duration]`` of a *non-looping* reading of
    every clip (a looping clip's time ``duration`` is its last frame, not the next cycle's first)."""
    c = clip_ids.to(library.device).long()
    dur = library._dur64.to(library.device)[c]
    t = times.to(library.device, torch.float64).clamp_min(0.0).minimum((dur - 1e-7).clamp_min(0.0))
    return library.frames(c, t)


def _action_map(skeleton: Skeleton, params: VmpTrackerParams) -> Any:
    from mocap.pd_actions import ActionMap

    return ActionMap.for_skeleton(skeleton, params.action, params.action_clip, {})


def hold_action(action_map: Any, dof_pos: Tensor) -> Tensor:
    """The raw action whose PD target is the pose ``dof_pos`` (absolute map; zeros for residual)."""
    if action_map.mode == "absolute":
        return (dof_pos - action_map.offset.to(dof_pos)) / action_map.scale.to(dof_pos)
    return torch.zeros_like(dof_pos)


def _clean(x: Tensor) -> Tensor:
    return torch.nan_to_num(x.float(), nan=0.0, posinf=0.0, neginf=0.0)
