"""Fall detection: batched tensor functions of a :class:`~mocap.state.SimState` (any simulator).

A humanoid has *fallen* when a body that is not allowed to touch the ground does (by default every
body except the skeleton's ``feet``), or when its root is lower than ``height_threshold`` above
the ground. Tasks and imitators combine these with their own conditions (tracking error, time).

With props (e.g. the strike task's target) ``SimState.body_contact`` also counts touching the prop;
pass the simulator's ground-only contacts (``MujocoSimulator.ground_contact``) as ``contact`` so
that hitting the target with a hand is not a fall. On uneven terrain pass ``ground_height`` (N,)
(the terrain height under the root) so that the height test is relative to the ground.
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor

from mocap.skeleton import Skeleton
from mocap.state import SimState

__all__ = ["allowed_contact_mask", "fallen", "forbidden_contact", "root_too_low"]


def allowed_contact_mask(skeleton: Skeleton, bodies: Sequence[str] | None = None, device: torch.device | str = "cpu") -> Tensor:
    """(B,) bool, True for the bodies allowed to touch the ground (default: ``skeleton.feet``)."""
    names = skeleton.feet if bodies is None else tuple(bodies)
    mask = torch.zeros(skeleton.num_bodies, dtype=torch.bool, device=device)
    for name in names:
        mask[skeleton.body_index(name)] = True
    return mask


def forbidden_contact(body_contact: Tensor, allowed: Tensor) -> Tensor:
    """(N,) bool: some body outside ``allowed`` (B,) touches, given ``body_contact`` (N, B)."""
    return (body_contact & ~allowed.to(body_contact.device)).any(dim=-1)


def root_too_low(state: SimState, height_threshold: float, ground_height: Tensor | None = None) -> Tensor:
    """(N,) bool: root origin less than ``height_threshold`` above the ground (z = 0 or ``ground_height``)."""
    z = state.root_pos[:, 2]
    if ground_height is not None:
        z = z - ground_height
    return z < height_threshold


def fallen(
    state: SimState,
    allowed: Tensor,
    height_threshold: float,
    *,
    contact: Tensor | None = None,
    ground_height: Tensor | None = None,
) -> Tensor:
    """(N,) bool: :func:`forbidden_contact` or :func:`root_too_low` (module docstring).

    Args:
        state: the simulator state.
        allowed: (B,) bool bodies allowed to touch (:func:`allowed_contact_mask`).
        height_threshold: minimum root height above the ground, m.
        contact: (N, B) bool contacts to judge (default ``state.body_contact``).
        ground_height: (N,) ground height under the root (default 0).
    """
    c = state.body_contact if contact is None else contact
    return forbidden_contact(c, allowed) | root_too_low(state, height_threshold, ground_height)
