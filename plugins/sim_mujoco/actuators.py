"""VMP's actuator model (Serifi et al. 2024, Eqs. 9-11, from Grandia et al. 2024) as an option of the
``mujoco`` simulator.

With ``MujocoParams.actuator_model`` set, the simulator replaces MuJoCo's ``position`` actuators by
``motor`` actuators (gear 1, no ctrl or force limits) and computes the joint torques itself at
**every physics substep** from the PD targets ``a`` held over the control step::

    Eq. 9   tau_motor    = kp (a - q) - kd qd                          (a clamped to the joint range)
    Eq. 10  tau_friction = mu_s tanh(qd / qd_s) + mu_d qd
    Eq. 11  tau          = clamp(tau_motor; qd) - tau_friction

``clamp`` is the torque-speed envelope (VMP Sec. 4.1 "Characters", Eq. 11): the limit is ``tau_max`` for braking
and low speeds; in the driving direction above ``qd_tau_max`` it falls linearly and reaches 0 at
``qd_max`` (and stays 0 beyond, [X] the paper does not say)::

    tau_hi(qd) = tau_max                                         qd <= qd_tau_max
               = tau_max (qd_max - qd) / (qd_max - qd_tau_max)   qd_tau_max < qd < qd_max
               = 0                                               qd >= qd_max
    tau_lo(qd) = -tau_hi(-qd)
    clamp(tau) = min(max(tau, tau_lo(qd)), tau_hi(qd))

The functions here are pure (numpy arrays or floats, broadcasting); the simulator calls
:meth:`ActuatorModel.torque` once per substep on all envs at once.

Stability. MuJoCo's ``position`` actuators integrate their ``kv`` damping implicitly
(``implicitfast``); here the whole PD law, damping included, is an explicit force, so the physics
step must resolve the stiffest joint: roughly ``timestep < 2 I / kd`` for the lightest effective
joint inertia ``I`` (armature included). On the ``amp`` humanoid with its DeepMimic gains
1/120 s and 1/240 s fail (the humanoid cannot even stand), 1/480 s stands but rings, 1/600 s is
clean (table below): use ``timestep: 0.0016667, substeps: 20`` (a 30 Hz control step).
:func:`explicit_stability_ratio` gives
``max_j timestep kd_j / M_jj`` at the model's rest pose (2 is the linear bound); the simulator
refuses a model above ``max_stability_ratio`` (1.4).

Measured (amp, DeepMimic gains, 8 envs standing from the rest pose with PD targets = rest for 3 s;
ratio = max timestep kd / M_jj; "max qd" = largest joint speed seen)::

    timestep  substeps  ratio  root z after 3 s  max |qd|   (position actuators: 0.881 m, 0.0 rad/s)
    1/120     4         6.48   0.118 (collapsed)  27.0 rad/s
    1/240     8         3.24   0.091 (collapsed)  10.8 rad/s
    1/480     16        1.62   0.881              3.0 rad/s (rings)
    1/600     20        1.30   0.881              0.3 rad/s

With the paper's humanoid values for every joint (kp 100, kd 1.0, tau_max 500) the amp humanoid
(45 kg) cannot hold itself up (root 0.085 m after 3 s at 1/120 and at 1/600 s), and random targets
(sigma 1 rad) caused 29 instability resets in 8 x 90 steps at 1/120 s, none at 1/600 s: keep the
skeleton's gains (the default) unless the humanoid is rescaled.

The collapse at 1/120 and 1/240 s is the explicit damping oscillating (the simulator's NaN / speed
checks do not fire: the joints chatter at tens of rad/s and the body falls). Cost: about 6-9x
fewer env steps/s than position actuators at 1/120 s (one rollout call per substep instead of one
per control step, and 5x the substeps): 8 envs, 1 thread, on the shared 2-core machine about 1,600-2,300
env steps/s with position actuators at 1/120 s against 220-250 with the actuator model at 1/600 s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = [
    "ActuatorModel",
    "ActuatorModelParams",
    "applied_torque",
    "clamp_torque",
    "explicit_stability_ratio",
    "friction_torque",
    "pd_torque",
    "torque_limits",
]


class ActuatorModelParams(BaseModel):
    """Eqs. 9-11 (module docstring). Tags: [P] paper, [T1] its Table 1 (humanoid column), [X] ours.

    Gains and the torque limit default to the skeleton's per-hinge values (the ones the project's
    policies were trained with); set a number to use one value for every joint (the paper's humanoid:
    kp 100, kd 1.0, tau_max 500). Needs a small physics step: about ``timestep <= 1/555`` s for ``amp``
    with its gains (the simulator refuses larger; module docstring), e.g. ``timestep: 0.0016667, substeps: 20``.
    """

    model_config = ConfigDict(extra="forbid")

    kp: float | None = Field(None, gt=0, description="kappa_P, N m/rad; None = each hinge's kp [T1 humanoid: 100]")
    kd: float | None = Field(None, ge=0, description="kappa_D, N m s/rad; None = each hinge's kd [T1 humanoid: 1.0]")
    tau_max: float | None = Field(None, gt=0, description="constant torque limit, N m; None = each hinge's torque limit [T1 humanoid: 500]")
    qd_tau_max: float = Field(20.0, ge=0, description="speed where the driving-direction limit starts to fall, rad/s [T1: 20]")
    qd_max: float = Field(100.0, gt=0, description="speed where the driving-direction limit reaches 0, rad/s [T1: 100]")
    mu_s: float = Field(0.45, ge=0, description="static (Coulomb) friction, N m [T1: 0.45]")
    mu_d: float = Field(0.023, ge=0, description="viscous friction, N m s/rad [T1: 0.023]")
    qd_s: float = Field(0.1, gt=0, description="static activation velocity of the tanh, rad/s [T1: 0.1]")
    clamp_targets: bool = Field(True, description="clamp PD targets to the joint ranges, as the position actuators do [X]")
    max_stability_ratio: float = Field(
        1.4,
        gt=0,
        description="refuse a model whose explicit-damping ratio max_j timestep kd_j / M_jj (rest pose) exceeds this (2 is the linear stability bound) [X]",
    )

    @model_validator(mode="after")
    def _check_speeds(self) -> ActuatorModelParams:
        if self.qd_max <= self.qd_tau_max:
            raise ValueError(f"qd_max ({self.qd_max}) must exceed qd_tau_max ({self.qd_tau_max})")
        return self


# ---------------------------------------------------------------------------------- pure math
def pd_torque(kp, kd, target, q, qd):
    """Eq. 9: ``kp (target - q) - kd qd`` (the target velocity is zero)."""
    return kp * (target - q) - kd * qd


def friction_torque(qd, mu_s, mu_d, qd_s):
    """Eq. 10: ``mu_s tanh(qd / qd_s) + mu_d qd`` (odd in ``qd``)."""
    return mu_s * np.tanh(np.asarray(qd) / qd_s) + mu_d * np.asarray(qd)


def torque_limits(qd, tau_max, qd_tau_max, qd_max):
    """(lo, hi): the torque-speed envelope at joint speed ``qd`` (module docstring)."""
    qd = np.asarray(qd, dtype=np.float64)

    def upper(v):
        with np.errstate(divide="ignore", invalid="ignore"):
            ramp = np.clip((qd_max - v) / (np.asarray(qd_max) - np.asarray(qd_tau_max)), 0.0, 1.0)
        ramp = np.where(np.isfinite(ramp), ramp, np.where(v < qd_max, 1.0, 0.0))
        return tau_max * np.where(v <= qd_tau_max, 1.0, ramp)

    return -upper(-qd), upper(qd)


def clamp_torque(tau, qd, tau_max, qd_tau_max, qd_max):
    """``tau`` clipped into the envelope at speed ``qd``."""
    lo, hi = torque_limits(qd, tau_max, qd_tau_max, qd_max)
    return np.minimum(np.maximum(tau, lo), hi)


def applied_torque(target, q, qd, *, kp, kd, tau_max, qd_tau_max, qd_max, mu_s, mu_d, qd_s):
    """Eq. 11: ``clamp(pd_torque) - friction_torque``."""
    motor = pd_torque(kp, kd, target, q, qd)
    return clamp_torque(motor, qd, tau_max, qd_tau_max, qd_max) - friction_torque(qd, mu_s, mu_d, qd_s)


# ------------------------------------------------------------------------------ the model
@dataclass
class ActuatorModel:
    """Per-joint parameters (D,) of Eqs. 9-11 for one skeleton, in skeleton DoF order."""

    kp: np.ndarray
    kd: np.ndarray
    tau_max: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    params: ActuatorModelParams

    @classmethod
    def for_skeleton(cls, skeleton, params: ActuatorModelParams) -> ActuatorModel:
        hinges = skeleton.hinges
        D = len(hinges)

        def per_joint(value, attr):
            return np.full(D, float(value)) if value is not None else np.array([float(getattr(h, attr)) for h in hinges])

        return cls(
            kp=per_joint(params.kp, "kp"),
            kd=per_joint(params.kd, "kd"),
            tau_max=per_joint(params.tau_max, "torque_limit"),
            lo=np.array([float(h.range[0]) for h in hinges]),
            hi=np.array([float(h.range[1]) for h in hinges]),
            params=params,
        )

    def torque(self, target: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """(N, D) applied joint torques (Eq. 11) for PD targets ``target`` (N, D) at ``q``, ``qd`` (N, D)."""
        p = self.params
        a = np.clip(target, self.lo, self.hi) if p.clamp_targets else target
        return applied_torque(
            a, q, qd, kp=self.kp, kd=self.kd, tau_max=self.tau_max, qd_tau_max=p.qd_tau_max, qd_max=p.qd_max, mu_s=p.mu_s, mu_d=p.mu_d, qd_s=p.qd_s
        )


def to_motor_actuators(model, actuator_ids: np.ndarray) -> None:
    """Turn the given ``position`` actuators of a compiled ``model`` into unit-gain ``motor``
    actuators without ctrl or force limits (``ctrl`` is then the joint torque, N m)."""
    import mujoco

    ids = np.asarray(actuator_ids, dtype=np.int64)
    model.actuator_gaintype[ids] = int(mujoco.mjtGain.mjGAIN_FIXED)
    model.actuator_gainprm[ids] = 0.0
    model.actuator_gainprm[ids, 0] = 1.0
    model.actuator_biastype[ids] = int(mujoco.mjtBias.mjBIAS_NONE)
    model.actuator_biasprm[ids] = 0.0
    model.actuator_ctrllimited[ids] = 0
    model.actuator_forcelimited[ids] = 0


def explicit_stability_ratio(model, dof_qvel: np.ndarray, kd: np.ndarray, timestep: float) -> float:
    """``max_j timestep kd_j / M_jj`` at the model's rest pose (joint-space mass matrix diagonal,
    armature included): the explicit-damping step ratio of the stiffest joint (< 2 for stability of
    ``v' = (1 - h kd / M) v``)."""
    import mujoco

    d = mujoco.MjData(model)
    mujoco.mj_forward(model, d)
    M = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, d, M)
    diag = np.diag(M)[np.asarray(dof_qvel, dtype=np.int64)]
    return float(np.max(timestep * np.asarray(kd) / diag))
