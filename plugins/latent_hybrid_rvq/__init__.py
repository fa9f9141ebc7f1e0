"""Hybrid latent space with residual vector quantization (Bae, Won, Lim, Hwang, Kim; CGF 2025).

Modules: :mod:`~mocap.quantizers` (``VectorQuantizer``, ``ResidualVQ``),
:mod:`~mocap_hybrid_rvq.model` (``HybridLatent``, ``HybridParams``, checkpoints) and
:mod:`~mocap_hybrid_rvq.plugin` (registers the ``hybrid_rvq`` latent space).
"""
