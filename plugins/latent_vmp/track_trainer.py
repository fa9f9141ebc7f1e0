"""The ``vmp_track`` trainer: VMP's two stages as one ``latent``-stage trainer.

The pipeline runs ``imitator -> latent -> task``, so a tracker trained in the imitator stage could
not see the VAE. This trainer, run on the spec's ``latent: {name: vmp}`` stage, does both:

1. **Stage I** in ``<workdir>/vae``: the ``supervised`` trainer (:class:`SupervisedTrainer`,
   params ``vae``) on a sub-context whose workdir is that folder; skipped once ``vae/vae.pt``
   exists (its own ``vmp.pt`` resumes an interrupted VAE run). Metrics go to ``metrics.jsonl``
   under the stage name ``latent/vae``; its reconstruction table is published with the stage.
2. **Stage II**, optionally warm-started (params ``distill``; :mod:`mocap_vmp.tracker_distill`) by
   distilling the spec's trained imitator into the tracking policy in ``<workdir>/tracker_distill``
   (its ``distill.pt`` resumes it; its ``policy.pt`` is PPO's ``init_policy``), then in
   ``<workdir>/tracker``: PPO (:class:`~mocap.rl.ppo.PPOTrainer`, params ``ppo``)
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
from mocap.interfaces import Imitator, StageResult, Trainer
from mocap.pipeline import StageFailed
from mocap.rl.ppo import PPOTrainer
from mocap_vmp.tracking import TRACKER_KEY, VmpTracker
from mocap_vmp.trainer import FINAL_NAME, SupervisedTrainer
from mocap_vmp.vmp_params import VmpTrackParams

FORMAT = "mocap_vmp.vmp/1"
COMBINED_NAME = "vmp.pt"
VAE_DIR = "vae"
TRACKER_DIR = "tracker"
DISTILL_DIR = "tracker_distill"
DISTILL_EVAL = "eval.json"


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
        ppo_params = p.ppo
        distilled = workdir / DISTILL_DIR / "policy.pt"
        if p.distill is not None:  # PPO starts from the warm start (a resumed PPO phase restores its own ppo.pt)
            if not (workdir / TRACKER_DIR / "ppo.pt").is_file() and self._distill(ctx, p, latent, workdir / DISTILL_DIR) is None:
                return StageResult(checkpoint=workdir / DISTILL_DIR / "distill.pt", metrics={})  # stopped: distill.pt resumes it
            ppo_params = ppo_params.model_copy(update={"init_policy": distilled})
        sub = ctx.phase("tracker", workdir=workdir / TRACKER_DIR, env_factory=lambda n: tracker.make_env(ctx, n))
        try:
            res = PPOTrainer(ppo_params).run(sub)
        finally:
            sub.log.close()
        if ctx.should_stop() or res.checkpoint is None or Path(res.checkpoint).name != "policy.pt":
            return StageResult(checkpoint=res.checkpoint, metrics=res.metrics)
        policy = load_checkpoint(Path(res.checkpoint))

        metrics = {
            **{f"vae/{k}": float(v) for k, v in (vae_data.get("metrics") or {}).items()},
            **{f"tracker/{k}": float(v) for k, v in res.metrics.items()},
        }
        if p.distill is not None and distilled.is_file():  # the warm start's last statistics and budget
            extra = load_checkpoint(distilled).get("extra") or {}
            metrics.update({f"distill/{k}": float(v) for k, v in (extra.get("metrics") or {}).items()})
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

    @staticmethod
    def _distill(ctx: Any, p: VmpTrackParams, latent: Any, workdir: Path) -> Path | None:
        """The DAgger warm start (:mod:`mocap_vmp.tracker_distill`): ``<workdir>/policy.pt``, or None when stopped."""
        from mocap_vmp.tracker_distill import TrackerDistiller

        assert p.distill is not None
        upstream = ctx.upstream.get("imitator")
        try:
            teacher = ctx.stage_component("imitator", checkpoint=upstream.checkpoint if upstream else None)
        except KeyError:
            raise StageFailed(
                "vmp_track distill: the warm start needs a teacher: add an `imitator:` section (a trained imitator or its checkpoint) to the spec"
            ) from None
        if not isinstance(teacher, Imitator):
            raise StageFailed(f"vmp_track distill: the imitator stage gives a {type(teacher).__name__}, not a trained imitator")
        # the teacher's goal is the reference's global pose: no jumps to another clip's frame (module docstring)
        tracker = VmpTracker(p.tracker.model_copy(update={"reference_jump": False}), ctx.skeleton, latent=latent)
        sub = ctx.phase("tracker_distill", workdir=workdir)
        env = tracker.make_env(ctx, p.distill.num_envs)
        try:
            model = PPOTrainer(p.ppo).build_model(env.obs_dim, env.action_space)
            policy_path = TrackerDistiller(p.distill, p.ppo.gamma, p.ppo.gae_lambda).run(sub, env, teacher, model)
            if policy_path is not None and not (workdir / DISTILL_EVAL).is_file():
                _evaluate_distilled(ctx, p, latent, env.library, policy_path, workdir / DISTILL_EVAL)
            return policy_path
        finally:
            env.close()
            sub.log.close()


def _evaluate_distilled(ctx: Any, p: VmpTrackParams, latent: Any, library: Any, policy_path: Path, out: Path) -> None:
    """The distilled policy (before PPO) under the imitation protocol: ``out`` (JSON) and one console line."""
    import json

    from mocap.evaluation import ImitationEvalParams
    from mocap.imitation_eval import evaluate_imitator
    from mocap.rl.networks import load_policy
    from mocap_vmp.tracking import VmpImitator

    imitator = VmpImitator(p.tracker, ctx.skeleton, latent, load_policy(policy_path), library)
    table = evaluate_imitator(imitator, library, lambda n: ctx.build("simulator", skeleton=ctx.skeleton, num_envs=n, seed=ctx.seed), ImitationEvalParams())
    out.write_text(json.dumps(table, indent=1, default=float) + "\n", encoding="utf-8")
    agg = table["aggregate"]
    ctx.console.print(f"tracker distill: the distilled policy (before PPO) tracks {agg['succeeded']}/{agg['total']} clips; {out}")


__all__ = ["VmpTrackParams", "VmpTrackTrainer"]
