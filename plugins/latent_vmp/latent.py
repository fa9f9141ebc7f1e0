"""VMP's latent space (stage I): the window encoder, the N(0, I) prior, the task action = z.

:class:`VmpLatent` holds the VAE and the feature standardization statistics (buffers, saved with
the weights). Its :meth:`~VmpLatent.encoder` reads ``obs.extra["window"]``: (N, 2W+1, F)
heading-normalized, **unstandardized** features as :meth:`~VmpLatent.windows` computes them from a
motion library; it standardizes them itself. The VAE's own window decoder is
:meth:`~VmpLatent.decode_window`.

The decoder of the LatentSpace interface (PD targets from proprioception and z) exists for a latent
loaded with a tracking policy (a ``vmp_track`` ``vmp.pt``): ``z`` is decoded into a window whose
centre frame, with ``z``, conditions the frozen tracker (:mod:`mocap_vmp.task`; this hierarchical
use goes beyond the paper, where VMP only tracks references). The task action is ``z`` itself
(``task_action: latent``, default) or a residual around the current window's encoding
(``task_action: residual``); :meth:`~VmpLatent.random_action` samples z ~ N(0, I). For imitation the
tracker is :class:`mocap_vmp.tracking.VmpImitator`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mocap.interfaces import Box, LatentSample, LatentSpace
from mocap.skeleton import Skeleton
from mocap.state import Observations
from mocap_vmp.features import (
    FeatureLayout,
    destandardize,
    frame_features,
    resolve_end_effectors,
    standardize,
    window_features,
    window_rows,
)
from mocap_vmp.vae import MotionVAE
from mocap_vmp.vmp_params import VmpParams

ARCHITECTURE_KEYS = ("window_half", "latent_dim", "channels", "res_blocks", "downsample", "dilation_growth", "end_effectors")


class VmpLatent(LatentSpace):
    """The VMP window VAE as a :class:`~mocap.interfaces.LatentSpace` (module docstring)."""

    samples_prior = True  # random_action samples the prior

    ee_index: Tensor  # buffers (register_buffer in __init__)
    feat_mean: Tensor
    feat_std: Tensor

    def __init__(self, params: VmpParams, skeleton: Skeleton):
        super().__init__()
        self.params = params
        self.skeleton = skeleton
        ee = resolve_end_effectors(skeleton, params.end_effectors)
        self.layout = FeatureLayout(skeleton.num_dofs, ee)
        self.register_buffer("ee_index", torch.tensor([skeleton.body_index(n) for n in ee], dtype=torch.long), persistent=False)
        F = self.layout.dim
        self.window = 2 * params.window_half + 1
        self.latent_dim = params.latent_dim
        self.vae = MotionVAE(F, self.window, params.latent_dim, params.channels, params.res_blocks, params.downsample, params.dilation_growth)
        self.register_buffer("feat_mean", torch.zeros(F))
        self.register_buffer("feat_std", torch.ones(F))
        #: (total_frames, d_z) per-frame latents of the training library (set after training / loading)
        self.frame_latents: Tensor | None = None
        self.clip_names: list[str] = []
        #: the vmp_track trainer's tracking policy entry of a combined vmp.pt (None for stage-1-only files)
        self.tracker: dict[str, Any] | None = None
        self.checkpoint_path: Path | None = None
        self._decoder_cache: Any = None

    def as_imitator(self, library: Any, dt: float | None = None, device: Any = "cpu") -> Any:
        """The trained tracking policy (stage 2) as an Imitator over ``library`` (``mocap eval`` uses
        it for a spec whose latent space imitates on its own), or None for a stage-1-only latent."""
        if self.tracker is None or self.checkpoint_path is None:
            return None
        from mocap_vmp.tracking import vmp_imitator

        return vmp_imitator(self.checkpoint_path, self.skeleton, library, device=device, dt=dt)

    @property
    def config(self) -> dict[str, Any]:
        d = self.params.model_dump(mode="json")
        d["end_effectors"] = list(self.layout.end_effectors)
        return d

    # ----------------------------------------------------------------------------- features
    def library_frame_features(self, lib: Any) -> Tensor:
        """(total_frames, F) every frame of ``lib`` in its own heading frame (for the statistics)."""
        return frame_features(lib, self.ee_index.to(lib.root_pos.device))

    def set_statistics(self, mean: Tensor, std: Tensor) -> None:
        self.feat_mean.copy_(mean)
        self.feat_std.copy_(std)

    def windows(self, lib: Any, centres: Tensor) -> Tensor:
        """(N, 2W+1, F) unstandardized windows centred at packed rows ``centres`` of motion library ``lib``."""
        rows = window_rows(lib, centres, self.params.window_half)
        return window_features(lib, rows, self.ee_index.to(rows.device))

    def standardize(self, window: Tensor) -> Tensor:
        return standardize(window, self.feat_mean, self.feat_std)

    def destandardize(self, window: Tensor) -> Tensor:
        return destandardize(window, self.feat_mean, self.feat_std)

    # -------------------------------------------------------------------------- LatentSpace
    def encoder(self, obs: Observations) -> LatentSample:
        """Posterior N(mu, sigma^2) of the window ``obs.extra["window"]`` (N, 2W+1, F) (unstandardized);
        ``z`` is the mean or a sample per ``latent_for_policy``."""
        window = obs.extra.get("window") if obs.extra else None
        if window is None:
            raise KeyError('the vmp encoder reads obs.extra["window"], an (N, 2W+1, F) motion window (VmpLatent.windows)')
        if window.shape[-2:] != (self.window, self.layout.dim):
            raise ValueError(f"vmp window must be (N, {self.window}, {self.layout.dim}), got {tuple(window.shape)}")
        mu, logvar = self.vae.encode(self.standardize(window.to(self.feat_mean)))
        std = torch.exp(0.5 * logvar)
        z = mu if self.params.latent_for_policy == "mean" else mu + std * torch.randn_like(mu)
        return LatentSample(mean=mu, std=std, z=z)

    def decoder(self, obs: Observations, z: Tensor) -> Tensor:
        """(N, D) PD targets from proprioception and ``z`` through the loaded tracking policy (:meth:`decode_action`)."""
        return self.decode_action(obs, z)

    def prior(self, obs: Observations) -> LatentSample:
        """N(0, I), independent of the state."""
        n = obs.proprio.shape[0]
        zeros = torch.zeros(n, self.latent_dim, device=self.feat_mean.device)
        return LatentSample(mean=zeros, std=torch.ones_like(zeros), z=zeros)

    @property
    def task_action_space(self) -> Box:
        """A task policy acts in the latent space: Box(d_z), unbounded or +-``task_action_clip``
        (``z`` itself, or the residual around the current encoding; :mod:`mocap_vmp.task`)."""
        c = self.params.task_action_clip
        return Box((self.latent_dim,)) if c is None else Box((self.latent_dim,), -float(c), float(c))

    def to_latent(self, obs: Observations, task_action: Tensor) -> Tensor:
        """``z = a`` (``task_action: latent``) or ``z = current_latent(obs) + a`` (``residual``)."""
        a = task_action.float().to(self.feat_mean.device)
        c = self.params.task_action_clip
        if c is not None:
            a = a.clamp(-c, c)
        if self.params.task_action == "residual":
            return self.current_latent(obs) + a
        return a

    @torch.no_grad()
    def current_latent(self, obs: Observations) -> Tensor:
        """(N, d_z) the posterior mean of the current window: the simulated frame reconstructed from
        ``obs.proprio`` (:func:`mocap_vmp.task.features_from_proprio`) repeated 2W+1 times."""
        from mocap_vmp.task import features_from_proprio

        feat = features_from_proprio(obs.proprio.to(self.feat_mean), self.skeleton, self.ee_index).to(self.feat_mean)
        window = feat[:, None, :].expand(-1, self.window, -1)
        mu, _ = self.vae.encode(self.standardize(window))
        return mu

    @property
    def decodes_pd_targets(self) -> bool:
        """True when a tracking policy is loaded: :meth:`decoder` / :meth:`decode_action` return PD targets."""
        return self.tracker is not None

    def _tracker_decoder(self) -> Any:
        if self.tracker is None:
            raise NotImplementedError(
                "vmp: decoding z to PD targets needs VMP's stage II tracking policy: load a vmp.pt of the vmp_track trainer "
                "(a stage-1-only VAE decodes only windows: decode_window)"
            )
        if getattr(self, "_decoder_cache", None) is None:
            from mocap_vmp.task import TrackerDecoder

            self._decoder_cache = TrackerDecoder(self, self.tracker)
        return self._decoder_cache

    def decode_action(self, obs: Observations, z: Tensor) -> Tensor:
        """(N, D) PD targets: the frozen tracker conditioned on the centre frame of ``decode_window(z)`` and ``z``."""
        return self._tracker_decoder()(obs.proprio, z)

    def random_action(self, obs: Observations, noise_scale: float = 1.0, generator: torch.Generator | None = None) -> Tensor:
        """PD targets of a random step: ``z ~ N(0, noise_scale^2 I)`` (the VAE prior) decoded by :meth:`decode_action`."""
        n = obs.proprio.shape[0]
        eps = torch.randn(n, self.latent_dim, generator=generator, device="cpu" if generator is None else generator.device)
        return self.decode_action(obs, noise_scale * eps.to(self.feat_mean))

    def reset_envs(self, env_ids: Tensor) -> None:
        """Envs ``env_ids`` were reset: their tracker action history restarts (hold the current pose)."""
        if self.tracker is not None:
            self._tracker_decoder().reset_envs(env_ids)

    def task_state_dict(self) -> dict[str, Any]:
        """The per-env tracker action history (for an exact resume of a task env)."""
        dec = self._decoder_cache
        if dec is None or dec.hist is None:
            return {}
        return {"hist": dec.hist.clone(), "fresh": dec._fresh.clone()}

    def load_task_state_dict(self, state: dict[str, Any]) -> None:
        if state:
            dec = self._tracker_decoder()
            dec.hist, dec._fresh = state["hist"].clone(), state["fresh"].clone()

    # ---------------------------------------------------------------------------- the VAE
    def decode_window(self, z: Tensor) -> Tensor:
        """(N, 2W+1, F) unstandardized window decoded from ``z``; the orientation channels are the
        6-D of the Gram-Schmidt matrix."""
        from mocap.rotations import matrix_to_sixd, sixd_to_matrix

        y = self.destandardize(self.vae.decode(z))
        s = self.layout.theta
        return torch.cat((y[..., : s.start], matrix_to_sixd(sixd_to_matrix(y[..., s])), y[..., s.stop :]), -1)

    @torch.no_grad()
    def encode_library(self, lib: Any, batch: int = 1024) -> Tensor:
        """(total_frames, d_z) posterior means of the window centred at every frame of every clip."""
        out = []
        for s in range(0, lib.total_frames, batch):
            centres = torch.arange(s, min(s + batch, lib.total_frames), device=lib.root_pos.device)
            mu, _ = self.vae.encode(self.standardize(self.windows(lib, centres).to(self.feat_mean.device)))
            out.append(mu)
        return torch.cat(out)


def make_vmp(
    params: VmpParams | None = None,
    *,
    skeleton: Skeleton,
    checkpoint: str | Path | None = None,
    device: torch.device | str = "cpu",
) -> VmpLatent:
    """Registry factory: an untrained VMP latent, or with ``checkpoint`` (the supervised trainer's ``vae.pt``
    or its resumable ``vmp.pt``, or the ``vmp_track`` trainer's combined ``vmp.pt``) the trained one with
    its per-frame latents, in eval mode. A combined file's tracking policy is kept, unbuilt, in
    ``latent.tracker`` (a dict; None otherwise): build it with :func:`mocap_vmp.tracking.vmp_imitator`."""
    params = params or VmpParams()
    latent = VmpLatent(params, skeleton)
    if checkpoint is not None:
        from mocap.checkpoint import CheckpointError, embedded_humanoid, load_checkpoint

        saved = load_checkpoint(Path(checkpoint))
        state = saved.get("latent")
        if state is None:
            raise CheckpointError(f"{checkpoint}: not a vmp checkpoint (no 'latent' entry; format {saved.get('format')!r})")
        config = saved.get("config") or {}
        diff = [k for k in ARCHITECTURE_KEYS if k in config and config[k] != latent.config[k]]
        if diff:
            detail = ", ".join(f"{k}: checkpoint {config[k]!r} vs spec {latent.config[k]!r}" for k in diff)
            trained = embedded_humanoid(saved)
            where = f"; it was trained for humanoid {trained}, the spec asks for {skeleton.name}" if trained not in (None, skeleton.name) else ""
            raise CheckpointError(f"{checkpoint}: the saved vmp latent does not match the spec ({detail}){where}")
        try:
            latent.load_state_dict(state)
        except RuntimeError as exc:
            raise CheckpointError(f"{checkpoint}: not the weights of this vmp latent ({exc})") from None
        latent.frame_latents = saved.get("frame_latents")
        latent.clip_names = list(saved.get("clip_names") or [])
        latent.tracker = saved.get("tracker")
        latent.checkpoint_path = Path(checkpoint)
        latent.eval()
    return latent.to(device)


__all__ = ["VmpLatent", "VmpParams", "make_vmp"]
