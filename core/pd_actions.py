"""PHC's absolute PD-action mapping ``q = offset + scale * a`` of a skeleton (PHC code
``_build_pd_action_offset_scale``), shared by the imitator's action map and the fallen-state
generator (:mod:`mocap.fail_states`)."""

from __future__ import annotations

import fnmatch
import math

import torch
from torch import Tensor

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


__all__ = ["pd_offset_scale"]
