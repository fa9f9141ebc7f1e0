"""VMP (Serifi et al., SCA 2024), stage I: the motion VAE over windows of kinematic frames.

Stage II (the latent-conditioned tracking policy) is not built yet. Modules: :mod:`.features`
(per-frame features, windows, heading normalization, standardization), :mod:`.vae` (the 1-D
convolutional beta-VAE, its loss and schedules), :mod:`.latent` (:class:`VmpLatent`),
:mod:`.trainer` (the ``supervised`` trainer), :mod:`.plugin` (registration).
"""
