"""The ``supervised`` trainer: VMP stage I, the motion VAE on windows of the spec's motions.

Per iteration: ``batch_size`` window centres drawn uniformly over every frame of every clip
([X]: the paper says "randomly sampled"), windows built from the motion library (edge-padded at
clip ends), standardized; loss = reconstruction (Eq. 3-4) + cyclical ``beta_eff`` * KL; one RAdam
step; one SGDR scheduler step.

Files in ``ctx.workdir``: ``vmp.pt`` (resumable: latent weights and statistics, optimizer,
scheduler, step, torch/numpy/python RNG states and the window sampler's generator; a resumed run
produces the same weights as an uninterrupted one), written every ``checkpoint_every`` steps, at
the end and when the user stops (Ctrl-C); at the end it also holds the per-frame latents of every
frame of every clip. ``vae.pt``: the final latent (weights, statistics, per-frame latents, clip
names and lengths), loaded by the ``vmp`` latent factory. Published: ``vmp_reconstruction.md``, a
per-clip, per-feature-group reconstruction table.
"""

from __future__ import annotations

import math
import time
from typing import Any

import torch

from mocap import trainer_scaffold as scaffold
from mocap.checkpoint import save_checkpoint
from mocap.interfaces import StageResult, Trainer
from mocap_vmp.features import GROUPS, clip_starts, feature_stats
from mocap_vmp.latent import VmpLatent
from mocap_vmp.vae import cyclical_beta, kl_divergence, per_frame_errors, reconstruction_loss
from mocap_vmp.vmp_params import SupervisedParams
from mocap.rng import rng_state

CHECKPOINT_FORMAT = "mocap_vmp.supervised/1"
CHECKPOINT_NAME = "vmp.pt"
FINAL_NAME = "vae.pt"
TABLE_NAME = "vmp_reconstruction.md"


class SupervisedTrainer(Trainer):
    """Trains ``ctx.stage_component()`` (a :class:`VmpLatent`) on windows of ``ctx.build("motions")``."""

    def __init__(self, params: SupervisedParams | None = None):
        self.params = params or SupervisedParams()

    def run(self, ctx: Any) -> StageResult:
        from mocap.motion.library import MotionLibrary

        p = self.params
        ckpt_path, device = scaffold.begin(ctx, p.torch_threads, CHECKPOINT_NAME)
        workdir = ckpt_path.parent
        latent = ctx.stage_component()
        if not isinstance(latent, VmpLatent):
            raise TypeError(f"the supervised trainer trains a vmp latent, got {type(latent).__name__}")
        lib = MotionLibrary(ctx.build("motions").load(ctx.skeleton), ctx.skeleton, device=device)
        latent = latent.to(device)
        optimizer = torch.optim.RAdam(latent.parameters(), lr=p.lr)
        scheduler = torch.optim.lr_scheduler.CosineAnnealingWarmRestarts(optimizer, T_0=p.sgdr_t0, T_mult=p.sgdr_t_mult, eta_min=p.sgdr_eta_min)
        sampler = torch.Generator(device="cpu").manual_seed(ctx.seed)
        step = 0
        ck = scaffold.resume_from(ctx, ckpt_path, CHECKPOINT_FORMAT, "vmp", map_location=device)
        if ck is not None:
            latent.load_state_dict(ck["latent"])
            optimizer.load_state_dict(ck["optimizer"])
            scheduler.load_state_dict(ck["scheduler"])
            sampler.set_state(ck["sampler"])
            step = int(ck["step"])
            scaffold.resumed(ctx, "vmp", step, ck["rng"])
        else:
            mean, std = feature_stats(latent.library_frame_features(lib), latent.layout, latent.params.std_min)
            latent.set_statistics(mean, std)

        frame_latents: torch.Tensor | None = None

        def save(final: bool = False) -> None:
            save_checkpoint(
                ckpt_path,
                {
                    "format": CHECKPOINT_FORMAT,
                    "step": step,
                    "latent": latent.state_dict(),
                    "config": latent.config,
                    "optimizer": optimizer.state_dict(),
                    "scheduler": scheduler.state_dict(),
                    "sampler": sampler.get_state(),
                    "rng": rng_state(),
                    "params": p.model_dump(mode="json"),
                    "frame_latents": None if frame_latents is None else frame_latents.cpu(),
                    "clip_names": list(lib.clip_names),
                    "finished": final,
                },
                spec_yaml=ctx.spec_yaml(),
            )

        total = lib.total_frames
        last: dict[str, float] = {}
        t_start = time.perf_counter()
        while step < p.num_iterations:
            latent.train()
            centres = torch.randint(0, total, (p.batch_size,), generator=sampler).to(device)
            x = latent.standardize(latent.windows(lib, centres))
            recon, mu, logvar = latent.vae(x)
            rec, groups = reconstruction_loss(recon, x, latent.layout)
            kl = kl_divergence(mu, logvar)
            beta = cyclical_beta(step, p.num_iterations, p.beta, p.kl_cycles, p.kl_ramp_ratio)
            loss = rec + beta * kl
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if p.max_grad_norm is not None:
                torch.nn.utils.clip_grad_norm_(latent.parameters(), p.max_grad_norm)
            lr = optimizer.param_groups[0]["lr"]
            optimizer.step()
            scheduler.step()
            step += 1
            last = {
                "loss": float(loss.detach()),
                "rec_loss": float(rec.detach()),
                "kl": float(kl.detach()),
                "beta": beta,
                "lr": lr,
                **{f"rec/{g}": float(v.detach()) for g, v in groups.items()},
                "steps_per_s": step / max(time.perf_counter() - t_start, 1e-9),
            }
            ctx.log.log(step, **last)
            if step % p.print_every == 0 or step == p.num_iterations:
                ctx.console.print(f"vmp step {step}/{p.num_iterations}  rec {last['rec_loss']:.4f}  kl {last['kl']:.3f}  beta {beta:.2e}  lr {lr:.2e}")
            stop = ctx.should_stop()
            if stop or step % p.checkpoint_every == 0:
                save()
            if stop:
                ctx.console.print(f"vmp: stopped at step {step}; checkpoint {ckpt_path}")
                return StageResult(checkpoint=ckpt_path, metrics=_metrics(last, step))

        latent.eval()
        frame_latents = latent.encode_library(lib, p.latent_batch)
        table, summary = reconstruction_table(latent, lib, p.latent_batch)
        ctx.publish(TABLE_NAME).write_text(table)
        save(final=True)
        metrics = {**_metrics(last, step), **summary}
        if lib.num_clips >= 2:  # paper section 5.4, labels = the clip names
            from mocap_vmp.metrics import label_metrics

            lm = label_metrics(frame_latents, lib.frame_clip)
            metrics.update({"latent/lda_accuracy": lm["lda_accuracy"], "latent/mutual_information": lm["mutual_information"]})
        final = workdir / FINAL_NAME
        save_checkpoint(
            final,
            {
                "format": "mocap_vmp.vae/1",
                "latent": latent.state_dict(),
                "config": latent.config,
                "frame_latents": frame_latents.cpu(),
                "clip_names": list(lib.clip_names),
                "clip_num_frames": lib.num_frames.cpu(),
                "metrics": metrics,
            },
            spec_yaml=ctx.spec_yaml(),
        )
        return StageResult(checkpoint=final, metrics=metrics)


def _metrics(last: dict[str, float], step: int) -> dict[str, float]:
    out = {k: v for k, v in last.items() if k in ("loss", "rec_loss", "kl")}
    out["steps"] = float(step)
    return out


@torch.no_grad()
def reconstruction_table(latent: VmpLatent, lib: Any, batch: int = 1024) -> tuple[str, dict[str, float]]:
    """Markdown table: per clip, the mean per-frame squared error of each feature group over every
    window (centred at every frame, decoded from the posterior mean; standardized units, theta as
    ``||R - R'||_F^2``), plus the mean joint-angle error in degrees (natural units). Also the
    all-frame averages as metrics."""
    latent.eval()
    starts = clip_starts(lib).tolist()
    lengths = lib.num_frames.tolist()
    qs = latent.layout.slices["q"]
    rows, sums, count = [], {g: 0.0 for g in (*GROUPS, "q_deg")}, 0
    for name, s, n in zip(lib.clip_names, starts, lengths):
        acc = {g: 0.0 for g in (*GROUPS, "q_deg")}
        for b in range(s, s + n, batch):
            centres = torch.arange(b, min(b + batch, s + n), device=lib.root_pos.device)
            x = latent.standardize(latent.windows(lib, centres))
            mu, _ = latent.vae.encode(x)
            y = latent.vae.decode(mu)
            for g, e in per_frame_errors(y, x, latent.layout).items():
                acc[g] += float(e.mean(-1).sum())
            dq = (latent.destandardize(y)[..., qs] - latent.destandardize(x)[..., qs]).abs().mean((-1, -2))
            acc["q_deg"] += float(dq.sum()) * 180.0 / math.pi
        for g, v in acc.items():
            sums[g] += v
        count += n
        rows.append((name, n, {g: v / n for g, v in acc.items()}))
    head = "| clip | frames | " + " | ".join(GROUPS) + " | total | q MAE (deg) |\n"
    head += "|---|---:|" + "---:|" * (len(GROUPS) + 2) + "\n"
    lines = []
    for name, n, m in rows:
        tot = sum(m[g] for g in GROUPS)
        lines.append(f"| {name} | {n} | " + " | ".join(f"{m[g]:.4f}" for g in GROUPS) + f" | {tot:.4f} | {m['q_deg']:.2f} |")
    mean = {g: v / max(count, 1) for g, v in sums.items()}
    lines.append(f"| **all** | {count} | " + " | ".join(f"{mean[g]:.4f}" for g in GROUPS) + f" | {sum(mean[g] for g in GROUPS):.4f} | {mean['q_deg']:.2f} |")
    doc = (
        "# VMP stage I: window reconstruction\n\n"
        "Mean per-frame squared error per feature group over the window centred at every frame of each clip, decoded "
        "from the posterior mean (standardized units; theta: squared Frobenius distance of the rotation matrices, "
        "in [0, 8]); q MAE: mean absolute joint-angle error in degrees.\n\n"
    )
    summary = {f"recon/{g}": mean[g] for g in GROUPS}
    summary["recon/total"] = sum(mean[g] for g in GROUPS)
    summary["recon/q_mae_deg"] = mean["q_deg"]
    return doc + head + "\n".join(lines) + "\n", summary


__all__ = ["SupervisedParams", "SupervisedTrainer", "reconstruction_table"]
