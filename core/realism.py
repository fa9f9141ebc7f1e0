"""A fixed realism judge (issue 61): a discriminator trained on the motion data alone, so that every cell
of every comparison is scored by the same judge and no policy ever shaped it.

Its input is the motion-matching feature (:mod:`mocap.naturalness`): a transition ``(s_{t-1}, s_t)`` of
PHC proprioception in the heading frame, standardized by the training data's mean and std (kept in
the checkpoint). It is trained with binary cross-entropy (AMP's discriminator objective, Peng et al.
2021, without the policy side): **positives** are the clips' transitions at the control rate from
random times; **negatives** are the same transitions spoilt in ways a controller spoils motion, never
a policy's rollouts (:func:`spoilt_transitions`):

* body positions moved by Gaussian noise of 1-10 cm (jitter);
* velocities scaled by 0-0.5 or 1.5-3 (a pose moving at the wrong speed, a frozen pose);
* body rotations turned by random angles of 0.05-0.5 rad (a distorted pose);
* the second state taken 3-10 control steps later (motion too fast) or from another clip (a jump).

``realism`` of a rollout is the mean over its transitions of ``sigmoid(D(x))``, in (0, 1): near 1 for
the data, near 0 for what the judge tells apart from it.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from mocap.motion.library import MotionLibrary
from mocap.observations import SixD, proprioception
from mocap.rotations import quat_from_axis_angle, quat_mul, quat_normalize
from mocap.state import HumanoidState

JUDGE_FORMAT = "mocap.realism_judge/1"


class RealismJudge(nn.Module):
    """An MLP on standardized transition features; ``score`` gives sigmoid(logit) in (0, 1)."""

    mean: Tensor
    std: Tensor

    def __init__(self, feature_dim: int, hidden: tuple[int, ...] = (256, 128), mean: Tensor | None = None, std: Tensor | None = None):
        super().__init__()
        self.feature_dim, self.hidden = int(feature_dim), tuple(int(h) for h in hidden)
        self.register_buffer("mean", torch.zeros(feature_dim) if mean is None else mean.float().clone())
        self.register_buffer("std", torch.ones(feature_dim) if std is None else std.float().clamp_min(1e-6).clone())
        layers: list[nn.Module] = []
        width = self.feature_dim
        for h in self.hidden:
            layers += [nn.Linear(width, h), nn.ReLU()]
            width = h
        layers.append(nn.Linear(width, 1))
        self.net = nn.Sequential(*layers)

    def logits(self, x: Tensor) -> Tensor:
        z = ((x.float() - self.mean) / self.std).clamp(-10.0, 10.0)
        return self.net(z).squeeze(-1)

    @torch.no_grad()
    def score(self, x: Tensor, chunk: int = 8192) -> Tensor:
        """(M,) sigmoid of the logits of (M, F) transitions."""
        return torch.cat([torch.sigmoid(self.logits(x[s : s + chunk])) for s in range(0, len(x), chunk)]) if len(x) else torch.zeros(0)


def _frames(lib: MotionLibrary, clips: Tensor, times: Tensor) -> HumanoidState:
    return lib.frames(clips, times.double())


def frame_pairs(lib: MotionLibrary, n: int, dt: float, gen: torch.Generator, gap: Tensor | None = None) -> tuple[HumanoidState, HumanoidState, Tensor]:
    """``n`` frame pairs (t, t + gap dt) of random clips and times, gap 1 unless given."""
    clips = torch.randint(0, lib.num_clips, (n,), generator=gen)
    gap = torch.ones(n) if gap is None else gap
    span = (lib.durations[clips].float() - gap * dt).clamp_min(0.0)
    t0 = torch.rand(n, generator=gen) * span
    return _frames(lib, clips, t0), _frames(lib, clips, t0 + gap * dt), clips


def transitions(a: HumanoidState, b: HumanoidState, sixd: SixD = "zhou") -> Tensor:
    """(N, 2P) features ``(s_a, s_b)``: each state's proprioception in its own heading frame."""
    return torch.cat([proprioception(a, sixd), proprioception(b, sixd)], -1).float()


def real_transitions(lib: MotionLibrary, n: int, dt: float, gen: torch.Generator, sixd: SixD = "zhou") -> Tensor:
    a, b, _ = frame_pairs(lib, n, dt, gen)
    return transitions(a, b, sixd)


def _rand(n: int, lo: float, hi: float, gen: torch.Generator) -> Tensor:
    return lo + (hi - lo) * torch.rand(n, generator=gen)


def spoilt_transitions(lib: MotionLibrary, n: int, dt: float, gen: torch.Generator, sixd: SixD = "zhou") -> Tensor:
    """``n`` negatives, a fifth of each kind of the module docstring."""
    k = max(1, n // 5)
    out = []
    a, b, _ = frame_pairs(lib, k, dt, gen)  # jitter
    sigma = _rand(k, 0.01, 0.1, gen)[:, None, None].double()
    noise = lambda s: s.body_pos + sigma.to(s.body_pos.dtype) * torch.randn(s.body_pos.shape, generator=gen).to(s.body_pos.dtype)  # noqa: E731
    pa, pb = noise(a), noise(b)
    out.append(transitions(replace(a, body_pos=pa, root_pos=pa[:, 0]), replace(b, body_pos=pb, root_pos=pb[:, 0]), sixd))
    a, b, _ = frame_pairs(lib, k, dt, gen)  # wrong speed
    slow = torch.rand(k, generator=gen) < 0.5
    factor = torch.where(slow, _rand(k, 0.0, 0.5, gen), _rand(k, 1.5, 3.0, gen))
    scale = lambda s, f: replace(s, body_lin_vel=s.body_lin_vel * f[:, None, None], body_ang_vel=s.body_ang_vel * f[:, None, None])  # noqa: E731
    out.append(transitions(scale(a, factor.to(a.body_lin_vel.dtype)), scale(b, factor.to(b.body_lin_vel.dtype)), sixd))
    a, b, _ = frame_pairs(lib, k, dt, gen)  # distorted pose
    turn = lambda s: replace(s, body_rot=quat_normalize(quat_mul(_random_turns(s.body_rot.shape[:2], gen).to(s.body_rot.dtype), s.body_rot)))  # noqa: E731
    out.append(transitions(turn(a), turn(b), sixd))
    a, b, _ = frame_pairs(lib, k, dt, gen, gap=torch.randint(3, 11, (k,), generator=gen).float())  # too fast
    out.append(transitions(a, b, sixd))
    a, _, _ = frame_pairs(lib, n - 4 * k, dt, gen)  # a jump to another frame
    c, _, _ = frame_pairs(lib, n - 4 * k, dt, gen)
    out.append(transitions(a, c, sixd))
    return torch.cat(out)


def _random_turns(shape: torch.Size, gen: torch.Generator) -> Tensor:
    axis = torch.randn(*shape, 3, generator=gen)
    angle = _rand(int(math.prod(shape)), 0.05, 0.5, gen).reshape(shape)
    return quat_from_axis_angle(axis / axis.norm(dim=-1, keepdim=True), angle)


def train_judge(
    lib: MotionLibrary, dt: float, *, steps: int = 3000, batch: int = 512, lr: float = 1e-3, seed: int = 0, sixd: SixD = "zhou"
) -> tuple[RealismJudge, list[float]]:
    """Train a judge on ``lib``'s clips (module docstring); returns it and its loss every 100 steps."""
    gen = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    reference = real_transitions(lib, 20_000, dt, gen, sixd)
    judge = RealismJudge(reference.shape[1], mean=reference.mean(0), std=reference.std(0))
    opt = torch.optim.Adam(judge.parameters(), lr=lr)
    bce = nn.BCEWithLogitsLoss()
    losses = []
    for step in range(steps):
        pos, neg = real_transitions(lib, batch, dt, gen, sixd), spoilt_transitions(lib, batch, dt, gen, sixd)
        logits = judge.logits(torch.cat([pos, neg]))
        loss = bce(logits, torch.cat([torch.ones(len(pos)), torch.zeros(len(neg))]))
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % 100 == 0 or step == steps - 1:
            losses.append(float(loss.detach()))
    judge.eval()
    return judge, losses


def save_judge(path: Path, judge: RealismJudge, extra: dict[str, Any] | None = None) -> None:
    from mocap.checkpoint import save_checkpoint

    config = {"feature_dim": judge.feature_dim, "hidden": list(judge.hidden)}
    save_checkpoint(path, {"format": JUDGE_FORMAT, "config": config, "state_dict": judge.state_dict(), **(extra or {})})


def load_judge(path: Path) -> RealismJudge:
    """The judge saved by :func:`save_judge` (a :class:`~mocap.errors.CheckpointError` for another file)."""
    from mocap.checkpoint import load_checkpoint
    from mocap.errors import CheckpointError

    data = load_checkpoint(path, expect=JUDGE_FORMAT, what="realism judge")
    config = data.get("config")
    try:
        judge = RealismJudge(int(config["feature_dim"]), tuple(int(h) for h in config["hidden"]))  # type: ignore[index]
        judge.load_state_dict(data["state_dict"])
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise CheckpointError(f"{path}: not a usable realism judge ({type(exc).__name__}: {str(exc)[:200]})") from None
    return judge.eval()


def default_judge_path() -> Path:
    """``checkpoints/realism_judge/judge.pt`` of the source tree mocap runs from (a clone)."""
    return Path(__file__).resolve().parents[1] / "checkpoints" / "realism_judge" / "judge.pt"


__all__ = [
    "JUDGE_FORMAT",
    "RealismJudge",
    "default_judge_path",
    "load_judge",
    "real_transitions",
    "save_judge",
    "spoilt_transitions",
    "train_judge",
    "transitions",
]
