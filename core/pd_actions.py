"""Policy actions to PD targets: PHC's absolute mapping ``q = offset + scale * a`` of a skeleton
(PHC code ``_build_pd_action_offset_scale``) and the residual mapping ``q = q^ + a``, shared by the
PHC imitator, VMP's tracker and the fallen-state generator (:mod:`mocap.fail_states`)."""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

from mocap.interfaces import Box
from mocap.skeleton import Skeleton


def pd_offset_scale(skeleton: Skeleton, overrides: dict[str, float] | None = None) -> tuple[Tensor, Tensor]:
    """(D,) offset and scale of PHC's absolute action mapping ``q = offset + scale * a``.

    * a joint of 2 or more hinges (PHC's 3-DoF joints): ``scale = min(1.2 max(|lo|, |hi|), pi)``
      over the joint's hinges, shared by them, ``offset = 0`` (PHC ``_build_pd_action_offset_scale``);
    * a single hinge (AMP/ASE lineage; PHC's SMPL has none): the range widened to
      ``mid -+ 0.7 (hi - lo)``, i.e. ``offset = mid``, ``scale = 0.7 (hi - lo)``;
    * ``overrides``: DoF-name glob -> scale (PHC: the knee's y hinge gets 5 rad, ``*Knee_y``).
    """
    offset, scale = [], []
    for body in skeleton.bodies[1:]:
        hs = body.joint.hinges
        if len(hs) == 1:
            lo, hi = hs[0].range
            offset.append((lo + hi) / 2.0)
            scale.append(0.7 * (hi - lo))
        elif hs:
            s = min(1.2 * max(max(abs(h.range[0]), abs(h.range[1])) for h in hs), math.pi)
            offset.extend([0.0] * len(hs))
            scale.extend([s] * len(hs))
    for pattern, value in (overrides or {}).items():
        for i, name in enumerate(skeleton.dof_names):
            if fnmatch.fnmatchcase(name, pattern):
                scale[i] = float(value)
    return torch.tensor(offset, dtype=torch.float64), torch.tensor(scale, dtype=torch.float64)


@dataclass(frozen=True)
class ActionMap:
    """Policy action (N, D) -> PD targets (N, D), rad.

    * ``"absolute"`` (PHC): ``q = offset + scale * a`` (:func:`pd_offset_scale`);
    * ``"residual"`` (UHC/RFC-style; it learned faster in early CPU runs here): ``q = q^_{t+1} + a``,
      the next reference pose plus the action.

    ``clip`` (optional) clamps ``a`` to ``[-clip, clip]`` first.
    """

    mode: Literal["absolute", "residual"]
    offset: Tensor
    scale: Tensor
    clip: float | None = None

    @classmethod
    def for_skeleton(
        cls, skeleton: Skeleton, mode: Literal["absolute", "residual"], clip: float | None = None, overrides: dict[str, float] | None = None
    ) -> "ActionMap":
        if mode not in ("absolute", "residual"):
            raise ValueError(f"unknown action mode {mode!r}; choose 'absolute' or 'residual'")
        offset, scale = pd_offset_scale(skeleton, overrides)
        return cls(mode, offset, scale, clip)

    @property
    def space(self) -> Box:
        c = math.inf if self.clip is None else float(self.clip)
        return Box((int(self.offset.numel()),), -c, c)

    def __call__(self, actions: Tensor, ref_dof_pos: Tensor | None) -> Tensor:
        a = actions if self.clip is None else actions.clamp(-self.clip, self.clip)
        if self.mode == "absolute":
            return self.offset.to(a) + self.scale.to(a) * a
        if ref_dof_pos is None:
            raise ValueError("residual actions need the next reference's DoF angles")
        return ref_dof_pos.to(a) + a

    def inverse(self, targets: Tensor, ref_dof_pos: Tensor | None) -> Tensor:
        """The action whose PD targets are ``targets`` (``a = (q - offset) / scale`` or ``q - q^``),
        clamped to ``[-clip, clip]``: ``self(self.inverse(q, r), r) == q`` wherever that action lies
        within the clip (a distillation label in this map's action space)."""
        q = targets.float() if not targets.is_floating_point() else targets
        if self.mode == "absolute":
            a = (q - self.offset.to(q)) / self.scale.to(q)
        elif ref_dof_pos is None:
            raise ValueError("residual actions need the next reference's DoF angles")
        else:
            a = q - ref_dof_pos.to(q)
        return a if self.clip is None else a.clamp(-self.clip, self.clip)


__all__ = ["ActionMap", "pd_offset_scale"]
