"""Fallen starts that track a get-up clip (``getup_starts`` of the PHC imitator's params and of
``distill``): the training side of ``mocap recover --planner getup`` (:mod:`mocap_phc.recovery_planner`).

PHC's fallen starts (Sec. 3.2; ``fail_states.fall_init_prob``) put a fallen humanoid under the
reference of an ordinary RSI clip and let it recover within a grace window; PHC learns the get-up
itself with a separate primitive (and its code with an AMP-only phase). With ``getup_starts`` a
fallen start instead gets, as its reference, the get-up clip whose first frame lies the way the
humanoid does (:func:`mocap.motion.transform.match_first_frames`), turned about the vertical and
moved so that its first root lies under the humanoid's (:func:`mocap.motion.transform.yaw_frames`),
played from its first frame: getting up becomes a tracking problem with a dense reward. After the
clip's last frame the episode goes on for ``hold_s`` seconds with that frame held at rest (the
humanoid has to stand still, as it must after a get-up in ``mocap recover``); then it is truncated.

Such episodes do not count as failures or successes of their clip for hard-negative mining or the
adaptive start sampler (they start from a state the clip does not contain). Used by the PHC
imitation env (:mod:`mocap_phc.env`) and by the distillation episodes (:mod:`mocap.distill_episodes`),
so that a latent space distilled from a teacher trained this way sees the get-ups with the
reference its teacher learned them from.
"""

from __future__ import annotations

import fnmatch
from typing import Any

import torch
from torch import Tensor

from mocap.motion.transform import frames_at_rate, match_first_frames, yaw_frames
from mocap.errors import UserError
from mocap.fail_state_params import GetUpStartParams
from mocap.state import HumanoidState, MotionFrames


class NoGetUpClip(UserError, ValueError):
    """A get-up setting whose patterns match no clip of the motion set (the user's spec or options)."""


def getup_clip_names(names: list[str], patterns: list[str]) -> list[str]:
    """The clip ``names`` that match one of the fnmatch ``patterns`` (case-sensitive)."""
    return [name for name in names if any(fnmatch.fnmatchcase(name, pat) for pat in patterns)]


class GetUpClips:
    """The get-up clips of ``library`` (names matching the fnmatch ``patterns``; a clear error when
    none does) and how to lay one onto a fallen humanoid. ``who`` names the setting in the error."""

    def __init__(self, library: Any, patterns: list[str], who: str = "getup_starts"):
        names = list(library.clip_names)
        wanted = set(getup_clip_names(names, patterns))
        self.clips = torch.tensor([i for i, name in enumerate(names) if name in wanted], dtype=torch.long)
        if not len(self.clips):
            raise NoGetUpClip(f"{who}: no clip matches {patterns} (clips: {', '.join(names)})")
        zero = torch.zeros(len(self.clips), dtype=library.dtype, device=library.device)
        first = library.frames(self.clips.to(library.device), zero)
        self._first_rot = first.root_rot.double().cpu()
        self._first_xy = first.root_pos[:, :2].double().cpu()

    def lay_onto(self, root_pos: Tensor, root_rot: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """For humanoids at ``root_pos`` (K, 3) lying as ``root_rot`` (K, 4): (clip (K,), yaw (K,),
        pivot (K, 2), target (K, 2)) such that ``yaw_frames(frames, yaw, pivot, target)`` puts the
        matching clip's first root under the humanoid's, turned to lie like it
        (:func:`mocap.motion.transform.match_first_frames`)."""
        clip, yaw, _ = match_first_frames(self._first_rot, self.clips, root_rot.double().cpu())
        pivot = self._first_xy[torch.searchsorted(self.clips, clip)]
        return clip, yaw, pivot, root_pos[:, :2].double().cpu()


class GetUpStarts:
    """Per-env alignment of get-up references for ``n`` envs on ``library`` (module docstring)."""

    def __init__(self, library: Any, params: GetUpStartParams, n: int):
        self.getups = GetUpClips(library, params.clips)
        self.lib, self.hold_s = library, float(params.hold_s)
        self.active = torch.zeros(n, dtype=torch.bool)
        self.yaw = torch.zeros(n, dtype=torch.float64)
        self.pivot = torch.zeros(n, 2, dtype=torch.float64)
        self.target = torch.zeros(n, 2, dtype=torch.float64)

    def start(self, ids: Tensor, fallen: Tensor, state: HumanoidState) -> Tensor:
        """Envs ``ids`` (K,) start now; the ``fallen`` (K,) ones, in ``state`` (K rows), get a get-up
        reference. Returns the (F,) get-up clip of each fallen one (its start time is 0)."""
        ids = ids.cpu()
        self.active[ids] = False
        rows = fallen.cpu().nonzero().squeeze(-1)
        if not len(rows):
            return torch.zeros(0, dtype=torch.long)
        clip, yaw, pivot, target = self.getups.lay_onto(state.root_pos[rows], state.root_rot[rows])
        env = ids[rows]
        self.active[env] = True
        self.yaw[env] = yaw
        self.pivot[env] = pivot
        self.target[env] = target
        return clip

    def apply(self, frames: MotionFrames, ids: Tensor | None, times: Tensor) -> MotionFrames:
        """Reference ``frames`` of envs ``ids`` (all when None) at clip ``times``: the get-up envs'
        rows turned and moved onto where their humanoid lay, held at rest past the clip's end."""
        act = self.active if ids is None else self.active[ids.cpu()]
        if not bool(act.any()):
            return frames
        sel = slice(None) if ids is None else ids.cpu()
        dur = self.lib.durations.double().cpu()[frames.clip_ids.cpu()]
        rest = act & (times.double().cpu() >= dur - 1e-9)
        if bool(rest.any()):
            frames = frames_at_rate(frames, (~rest).double())
        yaw = torch.where(act, self.yaw[sel], torch.zeros_like(self.yaw[sel]))
        pivot, target = self.pivot[sel], torch.where(act[:, None], self.target[sel], self.pivot[sel])
        return yaw_frames(frames, yaw, pivot, target)

    def over(self, clip_ids: Tensor, t_next: Tensor, clip_over: Tensor) -> Tensor:
        """(N,) bool, the episode has no reference left at ``t_next``: ``clip_over`` (the library's
        test) for ordinary envs, past the get-up's end plus ``hold_s`` for get-up envs."""
        dur = self.lib.durations.double().to(t_next.device)[clip_ids]
        act = self.active.to(t_next.device)
        return torch.where(act, t_next.double() > dur + self.hold_s + 1e-6, clip_over)

    def state_dict(self) -> dict[str, Any]:
        return {"getup_starts": {k: getattr(self, k).clone() for k in ("active", "yaw", "pivot", "target")}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if "getup_starts" not in state:
            raise ValueError("the saved env state has no get-up start state, but params.getup_starts is on")
        for k, v in state["getup_starts"].items():
            setattr(self, k, v.clone())


__all__ = ["GetUpClips", "GetUpStartParams", "GetUpStarts"]
