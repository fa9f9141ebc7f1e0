"""VMP stage II parameter models: the tracker's pydantic params (reward weights, env and policy
interface, domain randomization) and the conditioning table of the ablations (M, M5, M10, L, LM).

Moved out of :mod:`mocap_vmp.tracking` (re-exported there); the design is described in that
module's docstring."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

Conditioning = Literal["M", "M5", "M10", "L", "LM"]


# ------------------------------------------------------------------------------------ params
# domain randomization (re-exported by mocap_vmp.randomization, whose docstring documents it)
Range = tuple[float, float]


def _check_range(name: str, r: Range | None, low: float = 0.0) -> None:
    if r is not None and not (low <= r[0] <= r[1]):
        raise ValueError(f"{name} must satisfy {low} <= low <= high, got {r}")


class DomainRandomizationParams(BaseModel):
    """Domain randomization of the tracking env (module docstring); set a part to null to disable it."""

    model_config = ConfigDict(extra="forbid")

    mass_pct: float | None = Field(
        10.0, ge=0, lt=100, description="eps_m, %: body masses (and inertias) scaled by U[1 - eps, 1 + eps] per body at reset [T1 robot 10; humanoid T1?]"
    )
    ground_friction: Range | None = Field((0.5, 1.25), description="ground sliding friction U[lo, hi] per env at reset [P randomized; range X]")
    push_bodies: list[str] | None = Field(
        None, description="bodies that get pushed [P: root, head, hands, feet]; None = the root and the bodies named *head*, *hand*, *foot*"
    )
    push_interval_s: Range | None = Field((1.0, 5.0), description="time between pushes of an env, s [X]; null = no pushes")
    push_duration_s: Range = Field((0.1, 0.2), description="how long a push is held, s (at least one control step) [X]")
    push_force_max_mg: float = Field(0.5, ge=0, description="push force magnitude U[0, this] x total mass x g, N [X]")
    push_torque_max: float = Field(20.0, ge=0, description="push torque magnitude U[0, this], N m [X]")

    @model_validator(mode="after")
    def _ranges(self) -> DomainRandomizationParams:
        _check_range("ground_friction", self.ground_friction, 1e-6)
        _check_range("push_interval_s", self.push_interval_s, 1e-6)
        _check_range("push_duration_s", self.push_duration_s)
        return self


class VmpRewardWeights(BaseModel):
    """Reward weights (Eq. 6-8) [T1, humanoid column; the robot column is h 0, v 2, q 7, alive 30,
    da 1.5, dda 0.45, tau 1e-4]."""

    model_config = ConfigDict(extra="forbid")

    h: float = Field(0.5, ge=0, description="c^h, root height [T1 0.5]")
    theta: float = Field(1.0, ge=0, description="c^theta, root orientation ||R - R^||_F^2 [T1 1.0]")
    v: float = Field(1.0, ge=0, description="c^v, root linear + angular velocity [T1 1.0]")
    q: float = Field(1.0, ge=0, description="c^q, joint angles [T1 1.0]")
    qd: float = Field(0.1, ge=0, description="c^qd, joint velocities [T1 0.1]")
    p: float = Field(1.0, ge=0, description="c^p, root-relative end-effector positions [T1 1.0]")
    alive: float = Field(6.0, description="c^alive, constant bonus per step [T1 6.0]")
    da: float = Field(0.1, ge=0, description="c^da, action rate |a_t - a_{t-1}|^2 [T1 0.1]")
    dda: float = Field(
        0.01,
        ge=0,
        description="c^dda, action acceleration |a_t - 2 a_{t-1} + a_{t-2}|^2 [T1 0.01]",
    )
    tau: float = Field(1e-5, ge=0, description="c^tau, applied joint torque |tau|^2 [T1 1e-5]")


class VmpTrackerParams(BaseModel):
    """The tracking env and policy interface (module docstring). Tags: [P] paper, [T1] Table 1, [D] ours."""

    model_config = ConfigDict(extra="forbid")

    conditioning: Conditioning = Field(
        "LM",
        description="policy conditioning [P ablations]: M = m_t; M5 / M10 = m_t plus the next 5 / 10 frames; "
        "L = z_t only; LM = m_t and z_t (the paper's method)",
    )
    future_heading: Literal["current", "own"] = Field(
        "current",
        description="M5/M10: future frames in the heading frame of m_t ('current', the window convention) or their own [D]",
    )
    action: Literal["absolute", "residual"] = Field(
        "absolute",
        description="'absolute' = PD targets offset + scale * a (normalized map to the joint ranges; [P] the policy outputs "
        "absolute PD targets) or 'residual' = reference pose + a [D]",
    )
    action_clip: float | None = Field(
        None,
        gt=0,
        description="clamp raw actions to [-clip, clip] (the env's Box bounds); None: unbounded",
    )
    prev_actions: int = Field(
        2,
        ge=0,
        le=2,
        description="previous actions in the observation [P: a_{t-1}, a_{t-2}]",
    )
    sixd: Literal["zhou", "tan_norm"] = Field("zhou", description="6-D rotations in the proprioception [P: Zhou et al.]")
    reward: VmpRewardWeights = Field(default_factory=VmpRewardWeights)
    reward_std_min: float = Field(
        0.05,
        ge=0,
        description="floor on the standardization std used by the reward, natural units (m, rad, m/s, rad/s) [D]: the VAE's "
        "statistics floor features that never vary in its data at ~1e-6, which would turn any error there into ~1e12",
    )
    only_positive_rewards: bool = Field(
        False,
        description="clip each step's total reward at 0 from below [D, legged_gym's only_positive_rewards]: Eq. 6 sums "
        "squared errors over every standardized dimension, so early in training the step reward is far below zero "
        "(measured here: about -86 per step against the +6 alive bonus) and ending the episode as soon as the "
        "termination allows is what PPO learns (episodes stayed at the 3-s minimum); [P] no clipping",
    )
    reward_form: Literal["paper", "exp"] = Field(
        "paper",
        description="tracking terms: 'paper' = -c_g e_g (Eq. 6) or 'exp' = +c_g exp(-exp_scale e_g / n_g) with n_g the "
        "group's feature dimensions [D: a DeepMimic/PHC-style bounded kernel; not in the paper]",
    )
    exp_scale: float = Field(2.0, gt=0, description="k of reward_form 'exp' (per mean squared standardized error) [D]")
    smoothness_on: Literal["targets", "actions"] = Field(
        "targets",
        description="what the action-rate / acceleration penalties see: PD targets in rad ([P] a_t = PD targets) or raw actions [D]",
    )
    termination_threshold: float = Field(0.2, gt=0, description="t^p, m [T1: 0.2 humanoid, 0.3 robot]")
    termination_persist_s: float = Field(3.0, gt=0, description="f, s: the deviation must persist this long [T1: 3.0]")
    termination_norm: Literal["max_euclidean", "inf"] = Field(
        "max_euclidean",
        description="end-effector deviation: max over end effectors of the distance, or the inf-norm of the stacked vector [D]",
    )
    episode_length_s: float = Field(30.0, gt=0, description="T, s: time limit (truncation, bootstrapped) [T1: 30 s]")
    reference_jump: bool = Field(
        True,
        description="at a clip's end jump to a random frame of a new clip without resetting the simulation [P]; false: truncate",
    )
    randomization: DomainRandomizationParams | None = Field(
        None,
        description="domain randomization [P section 4.9: body masses, ground friction, random pushes; "
        "mocap_vmp.randomization]; null = off. The actuator model of Eqs. 9-11 is the simulator's actuator_model option",
    )


@dataclass(frozen=True)
class ConditioningSpec:
    use_m: bool
    future: int
    use_z: bool


def conditioning_spec(mode: str) -> ConditioningSpec:
    """What each ablation feeds the policy (module docstring)."""
    table = {
        "M": ConditioningSpec(True, 0, False),
        "M5": ConditioningSpec(True, 5, False),
        "M10": ConditioningSpec(True, 10, False),
        "L": ConditioningSpec(False, 0, True),
        "LM": ConditioningSpec(True, 0, True),
    }
    if mode not in table:
        raise ValueError(f"unknown conditioning {mode!r}; choose one of {', '.join(table)}")
    return table[mode]


def conditioning_dim(mode: str, feature_dim: int, latent_dim: int) -> int:
    c = conditioning_spec(mode)
    return (feature_dim * (1 + c.future) if c.use_m else 0) + (latent_dim if c.use_z else 0)
