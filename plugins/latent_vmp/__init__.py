"""VMP (Serifi et al., SCA 2024): the motion VAE over windows of kinematic frames (stage I) and the
latent-conditioned tracking policy (stage II).

Modules: :mod:`.features` (per-frame features, windows, heading normalization, standardization),
:mod:`.vae` (the 1-D convolutional beta-VAE, its loss and schedules), :mod:`.latent`
(:class:`VmpLatent`), :mod:`.trainer` (the ``supervised`` trainer, stage I), :mod:`.tracking`
(stage II: the tracking env, reward, termination, conditioning ablations, the ``vmp_tracker``
component and :class:`VmpImitator`), :mod:`.track_trainer` (the ``vmp_track`` trainer: both stages
on the latent stage, writing ``vmp.pt``), :mod:`.metrics` (joint MAE in degrees; the latent-space metrics LDA accuracy and mutual
information), :mod:`.randomization` (the tracking env's domain randomization), :mod:`.task` (VMP as
a task action space: z -> decoded window -> frozen tracker -> PD targets; beyond the paper),
:mod:`.plugin` (registration). The actuator model of Eqs. 9-11 is the ``mujoco`` simulator's
``actuator_model`` option (:mod:`mocap_sim_mujoco.actuators`).
"""
