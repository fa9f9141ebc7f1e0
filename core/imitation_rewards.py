"""PHC's imitation reward (Eq. 2) and energy penalty, with the paper's and the official code's forms.

Imitation reward, PHC Eq. 2, over all B bodies, ``^`` the reference at the time the simulated
state reached (the step's target, ``q^_{t+1}`` of the observation)::

    r^g = w_p exp(-k_p e_p) + w_r exp(-k_r e_r) + w_v exp(-k_v e_v) + w_w exp(-k_w e_w)

with weights ``(w_p, w_r, w_v, w_w) = (0.5, 0.3, 0.1, 0.1)`` and scales ``(k_p, k_r, k_v, k_w) =
(100, 10, 0.1, 0.1)`` (PHC code / PULSE Table 4; the PHC main paper gives neither). The error
``e`` of each term depends on ``form``:

* ``"paper"``: a norm, ``||x^ - x||``. The paper applies it to the stacked (B, 3) quantities; we
  take the **mean over bodies of the per-body Euclidean norm** (rotation: of the angle of
  ``q^_j q_j^-1``), so that the scale does not grow with the number of bodies (the Frobenius
  reading would be ``sqrt(B)`` times larger for the same per-body error). [I]
* ``"code"`` (PHC ``compute_imitation_reward``): the mean of squared components,
  ``e_p = mean_{j, xyz} (p^ - p)^2`` (likewise for v and w), ``e_r = mean_j angle_j^2``.

Energy penalty (``dof_force`` tau and ``dof_vel`` q-dot, per hinge):

* ``"paper"`` (PHC Sec. 3.1 "Reward", after Fu et al.): ``-c sum_j (tau_j w_j)^2``;
* ``"code"`` (PHC ``power`` reward): ``-c sum_j |tau_j q-dot_j|`` (not squared), zero while the
  episode is at most ``warmup`` = 3 steps old (``progress_buf <= 3``).

``c = 0.0005`` in both (the code's composer/get-up configs use 5e-5).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from mocap.imitation_reward_params import CODE_ENERGY_WARMUP, DEFAULT_SCALES, DEFAULT_WEIGHTS, TERMS, EnergyForm, RewardForm
from mocap.rotations import quat_angle, quat_conjugate, quat_mul
from mocap.state import HumanoidState


def _vector_error(diff: Tensor, form: RewardForm) -> Tensor:
    """(N,) error of (N, B, 3) differences: mean per-body norm (paper) or mean squared component (code)."""
    if form == "paper":
        return torch.linalg.vector_norm(diff, dim=-1).mean(-1)
    if form == "code":
        return diff.square().mean(dim=(-1, -2))
    raise ValueError(f"unknown reward form {form!r}; choose 'paper' or 'code'")


def imitation_errors(sim: HumanoidState, ref: HumanoidState, form: RewardForm = "paper") -> dict[str, Tensor]:
    """Per-env (N,) errors ``e_pos, e_rot, e_vel, e_ang_vel`` of the chosen ``form`` (module doc)."""
    angle = quat_angle(quat_mul(ref.body_rot, quat_conjugate(sim.body_rot)))  # (N, B) in [0, pi]
    if form == "paper":
        e_rot = angle.mean(-1)
    elif form == "code":
        e_rot = angle.square().mean(-1)
    else:
        raise ValueError(f"unknown reward form {form!r}; choose 'paper' or 'code'")
    return {
        "pos": _vector_error(ref.body_pos - sim.body_pos, form),
        "rot": e_rot,
        "vel": _vector_error(ref.body_lin_vel - sim.body_lin_vel, form),
        "ang_vel": _vector_error(ref.body_ang_vel - sim.body_ang_vel, form),
    }


def exp_term(error: Tensor, scale: float) -> Tensor:
    """``exp(-scale * error)``: in (0, 1] for ``error >= 0``, 1 iff ``error == 0``, decreasing in error."""
    return torch.exp(-scale * error)


@dataclass(frozen=True)
class ImitationReward:
    """PHC Eq. 2 (module doc): weighted sum of four exponential terms.

    Attributes:
        form: ``"paper"`` (norms) or ``"code"`` (mean squares).
        weights: ``(w_pos, w_rot, w_vel, w_ang_vel)``.
        scales: ``(k_pos, k_rot, k_vel, k_ang_vel)``.
    """

    form: RewardForm = "paper"
    weights: tuple[float, float, float, float] = DEFAULT_WEIGHTS
    scales: tuple[float, float, float, float] = DEFAULT_SCALES

    def terms(self, sim: HumanoidState, ref: HumanoidState) -> dict[str, Tensor]:
        """The four unweighted terms (N,) each in (0, 1]."""
        errors = imitation_errors(sim, ref, self.form)
        return {name: exp_term(errors[name], k) for name, k in zip(TERMS, self.scales)}

    def __call__(self, sim: HumanoidState, ref: HumanoidState) -> tuple[Tensor, dict[str, Tensor]]:
        """``(r^g (N,), terms)``."""
        terms = self.terms(sim, ref)
        total = sum(w * terms[name] for name, w in zip(TERMS, self.weights))
        return total, terms  # type: ignore[return-value]


def energy_penalty(
    dof_force: Tensor,
    dof_vel: Tensor,
    form: EnergyForm = "paper",
    coef: float = 0.0005,
    progress: Tensor | None = None,
    warmup: int | None = None,
) -> Tensor:
    """Energy penalty (N,) <= 0 (module doc).

    Args:
        dof_force: (N, D) actuator torques tau, N m (an empty tensor means no torque data: 0).
        dof_vel: (N, D) hinge velocities q-dot, rad/s.
        form: ``"paper"`` ``-c sum (tau q-dot)^2`` or ``"code"`` ``-c sum |tau q-dot|``.
        coef: c >= 0.
        progress: (N,) steps since the episode's reset, counting the step just taken (1 after the
            first step); with ``warmup`` the penalty is 0 where ``progress <= warmup``.
        warmup: steps without penalty; None: 3 for the code form, 0 for the paper form.
    """
    if dof_force.numel() == 0:
        return torch.zeros(dof_vel.shape[0], dtype=dof_vel.dtype, device=dof_vel.device)
    power = dof_force * dof_vel
    if form == "paper":
        pen = -coef * power.square().sum(-1)
    elif form == "code":
        pen = -coef * power.abs().sum(-1)
    else:
        raise ValueError(f"unknown energy form {form!r}; choose 'paper' or 'code'")
    if warmup is None:
        warmup = CODE_ENERGY_WARMUP if form == "code" else 0
    if progress is not None and warmup > 0:
        pen = torch.where(progress.to(pen.device) <= warmup, torch.zeros_like(pen), pen)
    return pen


__all__ = [
    "CODE_ENERGY_WARMUP",
    "DEFAULT_SCALES",
    "DEFAULT_WEIGHTS",
    "TERMS",
    "ImitationReward",
    "energy_penalty",
    "exp_term",
    "imitation_errors",
]
