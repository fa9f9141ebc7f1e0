"""VMP (Serifi et al., SCA 2024): the motion VAE over windows of kinematic frames (stage I) and the
latent-conditioned tracking policy (stage II).

Modules: :mod:`.features` (per-frame features, windows, heading normalization, standardization),
:mod:`.vae` (the 1-D convolutional beta-VAE, its loss and schedules), :mod:`.latent`
(:class:`VmpLatent`), :mod:`.trainer` (the ``supervised`` trainer, stage I), :mod:`.tracking`
(stage II: the tracking env, reward, termination, conditioning ablations, the ``vmp_tracker``
component and :class:`VmpImitator`), :mod:`.track_trainer` (the ``vmp_track`` trainer: both stages
on the latent stage, writing ``vmp.pt``), :mod:`.metrics` (joint MAE in degrees), :mod:`.plugin`
(registration).
"""
