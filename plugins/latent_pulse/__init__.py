"""PULSE latent space (Luo et al., ICLR 2024, arXiv:2310.04582): encoder E(z | s^p, s^g), decoder
D(a | s^p, z) and learnable prior R(z | s^p), distilled online from an imitator by the core ``distill``
trainer and reused as a residual action space by downstream tasks.

Modules:

* :mod:`mocap_pulse.losses`: the pure math of Eq. 3 (diagonal-Gaussian KL, reparameterization,
  L_regu, L_action, the β schedule);
* :mod:`mocap_pulse.latent`: :class:`~mocap_pulse.latent.PulseParams` (every paper/code switch and
  the Table 3 / App. C.3 ablations), the networks and :class:`~mocap_pulse.latent.PulseLatent`;
* :mod:`mocap_pulse.vq`: the App. C.3 VQ variant's partitioned quantizer (the hybrid_rvq plugin's
  :class:`~mocap.quantizers.VectorQuantizer`, imported);
* :mod:`mocap_pulse.rl_term`: the Table 3 row 4 ablation, a PPO term on the imitation reward added to
  distillation (the distill trainer's optional RL hook);
* :mod:`mocap_pulse.plugin`: the entry point registering the ``pulse`` latent space.
"""
