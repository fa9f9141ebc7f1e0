"""The ``vmp_track`` trainer: VMP's two stages as one ``latent``-stage trainer.

The pipeline runs ``imitator -> latent -> task``, so a tracker trained in the imitator stage could
not see the VAE. This trainer, run on the spec's ``latent: {name: vmp}`` stage, does both:

1. **Stage I** in ``<workdir>/vae``: the ``supervised`` trainer (:class:`SupervisedTrainer`,
   params ``vae``) on a sub-context whose workdir is that folder; skipped once ``vae/vae.pt``
   exists (its own ``vmp.pt`` resumes an interrupted VAE run). Metrics go to ``metrics.jsonl``
   under the stage name ``latent/vae``; its reconstruction table is published with the stage.
2. **Stage II** in ``<workdir>/tracker``: PPO (:class:`~mocap.rl.ppo.PPOTrainer`, params ``ppo``)
   on :class:`~mocap_vmp.tracking.VmpTrackingEnv` (params ``tracker``) built with the trained VAE;
   PPO's ``ppo.pt`` resumes it exactly. Metrics under the stage name ``latent/tracker``.
3. ``<workdir>/vmp.pt``: the VAE exactly as stage 1's ``vae.pt`` holds it (format, ``latent``,
   ``config``, ``frame_latents``, ``clip_names``, ...), so ``make_vmp`` loads it as before, plus
   ``tracker``: ``{"params", "policy_config", "policy_state", "metrics"}`` (the PPO policy with
   its observation normalizer). That file is the stage's checkpoint.

A Ctrl-C during either part saves that part's checkpoint and returns; running the stage again
continues where it stopped.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


from mocap import trainer_scaffold as scaffold
from mocap.checkpoint import load_checkpoint, save_checkpoint
from mocap.interfaces import StageResult, Trainer
from mocap.rl.ppo import PPOTrainer
from mocap_vmp.tracking import TRACKER_KEY, VmpTracker
from mocap_vmp.trainer import FINAL_NAME, SupervisedTrainer
from mocap_vmp.vmp_params import VmpTrackParams

FORMAT = "mocap_vmp.vmp/1"
COMBINED_NAME = "vmp.pt"
VAE_DIR = "vae"
TRACKER_DIR = "tracker"


class VmpTrackTrainer(Trainer):
    """Trains the VMP VAE, then the latent-conditioned tracking policy (module docstring)."""

    def __init__(self, params: VmpTrackParams | None = None):
        self.params = params or VmpTrackParams()

    def run(self, ctx: Any) -> StageResult:
        from mocap_vmp.latent import VmpLatent

        p = self.params
        combined, _ = scaffold.begin(ctx, None, COMBINED_NAME)  # workdir and seeds; each part sets its threads
        workdir = combined.parent
        if combined.is_file():
            data = load_checkpoint(combined)
            if data.get("format") == FORMAT and data.get(TRACKER_KEY) is not None:
                return StageResult(checkpoint=combined, metrics=dict(data.get("metrics") or {}))

        # ------------------------------------------------------------------ stage I: the VAE
        vae_dir = workdir / VAE_DIR
        vae_file = vae_dir / FINAL_NAME
        if not vae_file.is_file():
            vae_ctx = ctx.phase("vae", workdir=vae_dir)
            try:
                res = SupervisedTrainer(p.vae).run(vae_ctx)
            finally:
                vae_ctx.log.close()
            if not vae_file.is_file():  # stopped (Ctrl-C): vae/vmp.pt resumes it
                return StageResult(
                    checkpoint=res.checkpoint,
                    metrics={f"vae/{k}": v for k, v in res.metrics.items()},
                )
        latent = ctx.stage_component(checkpoint=vae_file)
        if not isinstance(latent, VmpLatent):
            raise TypeError(f"the vmp_track trainer trains the vmp latent, got {type(latent).__name__}")
        vae_data = load_checkpoint(vae_file)

        # --------------------------------------------------------- stage II: the tracking policy
        tracker = VmpTracker(p.tracker, ctx.skeleton, latent=latent)
        sub = ctx.phase("tracker", workdir=workdir / TRACKER_DIR, env_factory=lambda n: tracker.make_env(ctx, n))
        try:
            res = PPOTrainer(p.ppo).run(sub)
        finally:
            sub.log.close()
        if ctx.should_stop() or res.checkpoint is None or Path(res.checkpoint).name != "policy.pt":
            return StageResult(checkpoint=res.checkpoint, metrics=res.metrics)
        policy = load_checkpoint(Path(res.checkpoint))

        metrics = {
            **{f"vae/{k}": float(v) for k, v in (vae_data.get("metrics") or {}).items()},
            **{f"tracker/{k}": float(v) for k, v in res.metrics.items()},
        }
        payload = {k: v for k, v in vae_data.items() if k not in ("versions", "spec")}
        payload.update(
            {
                "format": FORMAT,
                "metrics": metrics,
                TRACKER_KEY: {
                    "params": p.tracker.model_dump(mode="json"),
                    "policy_config": policy["config"],
                    "policy_state": policy["state_dict"],
                    "metrics": dict(res.metrics),
                },
            }
        )
        save_checkpoint(combined, payload, spec_yaml=ctx.spec_yaml())
        return StageResult(checkpoint=combined, metrics=metrics)


__all__ = ["VmpTrackParams", "VmpTrackTrainer"]
