"""Early termination for imitation: PHC's Relaxed Early Termination (paper) and the code's rule.

Distances are global (world frame) between each simulated body and the reference body at the
same time, over the *checked* bodies: every body except the excluded ones (ankles and toes for
SMPL; by default the skeleton's ``feet``, which are the ankles and toes of ``smpl`` and the feet of
``amp``). PHC Sec. 3.1 "Relaxed Early Termination": the feet are still rewarded, only not checked.

* ``"paper"``: terminate when the **mean** distance over the checked bodies exceeds ``threshold``
  (0.5 m, following UHC);
* ``"code"`` (PHC ``compute_humanoid_im_reset``, ``terminationDistance``): terminate when **any**
  checked body is farther than ``threshold`` (0.25 m), and only once the episode is more than
  ``grace`` = 1 step old (``progress_buf > 1``: the first step after a reset is never checked).

Optional fall check (not PHC imitation; ASE/AMP style): terminate when a
non-foot body touches the ground (``SimState.body_contact``), optionally only when that body is
also below ``fall_height``. Per-clip contact rules (:func:`contact_table`, MimicKit-style) replace
the non-foot set by the bodies each clip may not touch the ground with.
"""

from __future__ import annotations

from dataclasses import dataclass
import fnmatch
from typing import Any, Literal, Mapping, Sequence

import torch
from torch import Tensor

from mocap.skeleton import Skeleton
from mocap.state import HumanoidState, SimState

TerminationRule = Literal["paper", "code"]
DEFAULT_THRESHOLD: dict[str, float] = {"paper": 0.5, "code": 0.25}
DEFAULT_GRACE: dict[str, int] = {"paper": 0, "code": 1}


def curriculum_threshold(curriculum: Any, final: float, steps_seen: int) -> float:
    """The termination threshold after ``steps_seen`` training env steps: linear from
    ``curriculum.start`` to ``final`` over ``curriculum.env_steps``, then ``final``
    (:class:`mocap_phc.phc_params.TerminationCurriculum`)."""
    frac = min(1.0, max(0.0, steps_seen / float(curriculum.env_steps)))
    return float(curriculum.start + (final - curriculum.start) * frac)


def body_distances(sim: HumanoidState, ref: HumanoidState) -> Tensor:
    """(N, B) world distance of every simulated body to its reference body, m."""
    return torch.linalg.vector_norm(sim.body_pos - ref.body_pos, dim=-1)


def checked_mask(skeleton: Skeleton, exclude: Sequence[str] | None = None) -> Tensor:
    """(B,) bool: bodies checked by the termination test (all but ``exclude``; default the feet)."""
    names = skeleton.feet if exclude is None else tuple(exclude)
    mask = torch.ones(skeleton.num_bodies, dtype=torch.bool)
    for name in names:
        mask[skeleton.body_index(name)] = False
    if not bool(mask.any()):
        raise ValueError("the termination test excludes every body")
    return mask


def imitation_failed(
    dist: Tensor,
    checked: Tensor,
    rule: TerminationRule = "paper",
    threshold: float | None = None,
    progress: Tensor | None = None,
    grace: int | None = None,
) -> Tensor:
    """(N,) bool: the tracking error ended the episode (module doc).

    Args:
        dist: (N, B) body distances (:func:`body_distances`).
        checked: (B,) bool mask of the checked bodies.
        rule: ``"paper"`` (mean > threshold) or ``"code"`` (any > threshold).
        threshold: m; None: 0.5 (paper) or 0.25 (code).
        progress: (N,) steps since reset counting the step just taken; needed for ``grace``.
        grace: envs with ``progress <= grace`` never terminate; None: 0 (paper) or 1 (code).
    """
    if rule not in DEFAULT_THRESHOLD:
        raise ValueError(f"unknown termination rule {rule!r}; choose 'paper' or 'code'")
    thr = DEFAULT_THRESHOLD[rule] if threshold is None else threshold
    d = dist[:, checked.to(dist.device)]
    failed = d.mean(-1) > thr if rule == "paper" else (d > thr).any(-1)
    g = DEFAULT_GRACE[rule] if grace is None else grace
    if progress is not None and g > 0:
        failed = failed & (progress.to(failed.device) > g)
    return failed


def contact_table(skeleton: Skeleton, clip_names: Sequence[str], allowed: Mapping[str, Sequence[str]], default: Sequence[str] | None = None) -> Tensor:
    """(C, B) bool: per clip, the bodies whose ground contact ends an episode (all but the allowed).

    Clip ``c`` takes the body globs of the first key of ``allowed`` (an ``fnmatch`` glob) its name
    matches, else ``default`` (None: the skeleton's feet). A body glob that matches no body is a
    ValueError naming it (a typo would silently allow nothing)."""
    bodies = list(skeleton.body_names)

    def mask(globs: Sequence[str]) -> Tensor:
        ok = torch.zeros(len(bodies), dtype=torch.bool)
        for g in globs:
            hit = [i for i, b in enumerate(bodies) if fnmatch.fnmatchcase(b, g)]
            if not hit:
                raise ValueError(f"contact_rules: no body of the skeleton matches {g!r} (bodies: {', '.join(bodies)})")
            ok[hit] = True
        return ~ok

    fallback = mask(list(skeleton.feet) if default is None else list(default))
    rows = []
    for name in clip_names:
        key = next((k for k in allowed if fnmatch.fnmatchcase(name, k)), None)
        rows.append(fallback if key is None else mask(list(allowed[key])))
    return torch.stack(rows) if rows else torch.zeros(0, len(bodies), dtype=torch.bool)


def fallen(state: SimState, non_foot: Tensor, fall_height: float | None = None) -> Tensor:
    """(N,) bool: a non-foot body (``non_foot`` (B,) or per-env (N, B) mask) touches the ground [and is below ``fall_height``]."""
    if state.body_contact.numel() == 0:
        return torch.zeros(state.body_pos.shape[0], dtype=torch.bool, device=state.body_pos.device)
    touch = state.body_contact.bool() & non_foot.to(state.body_contact.device)
    if fall_height is not None:
        touch = touch & (state.body_pos[..., 2] < fall_height)
    return touch.any(-1)


@dataclass(frozen=True)
class Termination:
    """The configured termination test of an imitation env.

    Attributes:
        checked: (B,) bool, bodies the tracking test looks at (not the feet).
        non_foot: (B,) bool, bodies whose ground contact counts as a fall.
        rule, threshold, grace: see :func:`imitation_failed`.
        fall_check: also terminate on falls (:func:`fallen`).
        fall_height: see :func:`fallen`.
    """

    checked: Tensor
    non_foot: Tensor
    rule: TerminationRule = "paper"
    threshold: float | None = None
    grace: int | None = None
    fall_check: bool = False
    fall_height: float | None = None

    @classmethod
    def for_skeleton(
        cls,
        skeleton: Skeleton,
        rule: TerminationRule = "paper",
        threshold: float | None = None,
        grace: int | None = None,
        exclude: Sequence[str] | None = None,
        fall_check: bool = False,
        fall_height: float | None = None,
    ) -> "Termination":
        return cls(
            checked=checked_mask(skeleton, exclude),
            non_foot=checked_mask(skeleton, None),
            rule=rule,
            threshold=threshold,
            grace=grace,
            fall_check=fall_check,
            fall_height=fall_height,
        )

    def __call__(
        self, state: SimState, ref: HumanoidState, progress: Tensor | None = None, forbidden: Tensor | None = None, forbidden_height: float | None = None
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """``(terminated (N,), parts)``; parts: ``tracking``, ``fall``, ``unstable`` (N,) bool each.

        Unstable envs (``state.unstable``) always terminate. ``forbidden`` (N, B) bool: per-env bodies
        whose ground contact is a fall (per-clip contact rules, :func:`contact_table`), checked below
        ``forbidden_height`` when given; it replaces ``fall_check``'s non-foot rule.
        """
        dist = body_distances(state, ref)
        tracking = imitation_failed(dist, self.checked, self.rule, self.threshold, progress, self.grace)
        tracking = tracking | ~torch.isfinite(dist).all(-1)
        n = dist.shape[0]
        if forbidden is not None:
            fall = fallen(state, forbidden, forbidden_height)
        elif self.fall_check:
            fall = fallen(state, self.non_foot, self.fall_height)
        else:
            fall = torch.zeros(n, dtype=torch.bool, device=dist.device)
        unstable = state.unstable.bool() if state.unstable.numel() else torch.zeros(n, dtype=torch.bool, device=dist.device)
        return tracking | fall | unstable, {"tracking": tracking, "fall": fall, "unstable": unstable}


__all__ = ["DEFAULT_GRACE", "DEFAULT_THRESHOLD", "Termination", "body_distances", "checked_mask", "contact_table", "fallen", "imitation_failed"]
