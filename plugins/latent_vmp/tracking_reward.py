"""VMP stage II reward and termination: the per-frame state features both sides are compared
on, the Eq. 5-8 tracking / smoothness errors, the reward's named terms and their weights (summed by
:class:`mocap.episodes.RewardTerms`), and the end-effector persistence rule.

Moved out of :mod:`mocap_vmp.tracking` (re-exported there); the design is described in that
module's docstring."""

from __future__ import annotations

import torch
from torch import Tensor

from mocap.rotations import (
    heading_quat_inv,
    matrix_to_sixd,
    quat_apply,
    quat_mul,
    quat_to_matrix,
    sixd_to_matrix,
)
from mocap.state import HumanoidState
from mocap_vmp.features import FeatureLayout
from mocap_vmp.tracking_params import VmpRewardWeights

TRACK_TERMS = ("h", "theta", "v", "q", "qd", "p")
SMOOTH_TERMS = ("da", "dda", "tau")


# ---------------------------------------------------------------------------------- features
def state_features(state: HumanoidState, ee_index: Tensor, heading_inv: Tensor | None = None) -> Tensor:
    """(N, F) stage-1 per-frame features of a simulated or reference state (same layout and
    conventions as :func:`mocap_vmp.features.window_features`), unstandardized, in the heading
    frame ``heading_inv`` (N, 4) (default: the state's own)."""
    root_pos, root_rot = state.root_pos, state.root_rot
    hinv = heading_quat_inv(root_rot) if heading_inv is None else heading_inv.to(root_rot)
    h = root_pos[:, 2:3]
    theta = matrix_to_sixd(quat_to_matrix(quat_mul(hinv, root_rot)))
    v = torch.cat((quat_apply(hinv, state.root_lin_vel), quat_apply(hinv, state.root_ang_vel)), -1)
    ee = state.body_pos[:, ee_index.to(root_pos.device)] - root_pos[:, None, :]
    p = quat_apply(hinv[:, None, :].expand(*ee.shape[:-1], 4), ee).flatten(1)
    return torch.cat((h, theta, v, state.dof_pos, state.dof_vel, p), -1)


# ------------------------------------------------------------------------------------ reward
def tracking_errors(ref: Tensor, sim: Tensor, layout: FeatureLayout) -> dict[str, Tensor]:
    """Squared errors (N,) per Eq. 6 group between **standardized** feature vectors (N, F); the
    orientation as ``||R(theta) - R(theta^)||_F^2`` (in [0, 8])."""
    s = layout.slices
    out = {}
    for g in TRACK_TERMS:
        if g == "theta":
            d = sixd_to_matrix(ref[..., s[g]]) - sixd_to_matrix(sim[..., s[g]])
            out[g] = d.square().sum((-1, -2))
        else:
            out[g] = (ref[..., s[g]] - sim[..., s[g]]).square().sum(-1)
    return out


def smoothness_errors(a: Tensor, a1: Tensor, a2: Tensor, tau: Tensor) -> dict[str, Tensor]:
    """Eq. 8's squared norms (N,): action rate, action acceleration (second difference), torque."""
    return {
        "da": (a - a1).square().sum(-1),
        "dda": (a - 2.0 * a1 + a2).square().sum(-1),
        "tau": tau.square().sum(-1) if tau.numel() else torch.zeros(a.shape[0], dtype=a.dtype, device=a.device),
    }


#: the reward's terms (:class:`mocap.episodes.RewardTerms`), in the order they are summed
REWARD_TERMS: tuple[str, ...] = ("alive", *(f"track/{g}" for g in TRACK_TERMS), *(f"smooth/{s}" for s in SMOOTH_TERMS))


def vmp_reward_weights(w: VmpRewardWeights, form: str = "paper") -> dict[str, float]:
    """The weight of every term of :data:`REWARD_TERMS`: ``c_alive``, ``-c_g`` (``form`` 'paper', Eq. 6)
    or ``+c_g`` ('exp') for the tracking terms, ``-c_s`` for the smoothness terms (Eq. 8)."""
    if form not in ("paper", "exp"):
        raise ValueError(f"unknown reward_form {form!r}")
    sign = 1.0 if form == "exp" else -1.0
    out = {"alive": float(w.alive)}
    out.update({f"track/{g}": sign * float(getattr(w, g)) for g in TRACK_TERMS})
    out.update({f"smooth/{s}": -float(getattr(w, s)) for s in SMOOTH_TERMS})
    return out


def vmp_reward_terms(
    track: dict[str, Tensor],
    smooth: dict[str, Tensor],
    form: str = "paper",
    dims: dict[str, int] | None = None,
    scale: float = 2.0,
) -> dict[str, Tensor]:
    """The unweighted terms (N,) of :data:`REWARD_TERMS`: ``alive`` = 1, ``track/<g>`` = the squared
    error ``e_g`` ('paper') or the kernel ``exp(-scale e_g / n_g)`` with ``n_g = dims[g]`` ('exp', in
    (0, 1]), ``smooth/<s>`` = ``e_s``. With :func:`vmp_reward_weights` the weighted sum is Eq. 5:
    ``r = c_alive - sum_g c_g e_g - sum_s c_s e_s`` ('paper') or with ``+ sum_g c_g exp(..)`` ('exp')."""
    if form not in ("paper", "exp"):
        raise ValueError(f"unknown reward_form {form!r}")
    if form == "exp" and dims is None:
        raise ValueError("reward_form 'exp' needs the feature dimensions of the tracking groups (dims)")
    any_t = track[TRACK_TERMS[0]]
    terms: dict[str, Tensor] = {"alive": torch.ones_like(any_t)}
    for g in TRACK_TERMS:
        e = track[g]
        terms[f"track/{g}"] = e if form == "paper" else torch.exp(-scale * e / max(int(dims[g]), 1))  # type: ignore[index]
    terms.update({f"smooth/{s}": smooth[s] for s in SMOOTH_TERMS})
    return terms


# ------------------------------------------------------------------------------- termination
def end_effector_error(ref_p: Tensor, sim_p: Tensor, norm: str = "max_euclidean") -> Tensor:
    """(N,) deviation of root-relative end-effector positions (N, 3E), metres."""
    d = (ref_p - sim_p).reshape(ref_p.shape[0], -1, 3)
    if norm == "max_euclidean":
        return torch.linalg.vector_norm(d, dim=-1).amax(-1)
    if norm == "inf":
        return d.abs().flatten(1).amax(-1)
    raise ValueError(f"unknown termination_norm {norm!r}")


def persist_steps(persist_s: float, dt: float) -> int:
    """Consecutive control steps that make ``persist_s`` seconds (at least 1)."""
    return max(1, round(persist_s / dt))


def update_counter(counter: Tensor, error: Tensor, threshold: float, steps: int) -> tuple[Tensor, Tensor]:
    """One step of the persistence rule: ``counter + 1`` where ``error > threshold`` (else 0) and
    ``fired = counter >= steps`` (the step where the deviation has lasted ``steps`` steps)."""
    over = error > threshold
    counter = torch.where(over, counter + 1, torch.zeros_like(counter))
    return counter, counter >= steps
