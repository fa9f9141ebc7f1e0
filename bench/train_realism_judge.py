"""Train the fixed realism judge (``mocap.realism``) on the 15 bundled DeepMimic clips and validate it.

Writes ``OUT/judge.pt`` and ``OUT/validation.json``: the judge's mean score on real transitions of the
training clips, on the five held-out walker clips (real motion it never saw), on each kind of spoilt
transition, and on the training clips with growing body-position noise; the loss curve; the command;
the wall-clock and the load average.

    python bench/train_realism_judge.py --out checkpoints/realism_judge

Deterministic on one machine for a given ``--seed`` (one torch thread); another CPU gives other last
bits (the validation scores then agree to about 1e-3).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import torch


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    from mocap.motion.deepmimic import WALKER_CLIPS
    from mocap.motion.library import MotionLibrary
    from mocap.plugins import get_plugins
    from mocap.realism import real_transitions, save_judge, spoilt_transitions, train_judge

    plugins = get_plugins()
    amp = plugins.get("humanoid", "amp").build(None)
    source = plugins.get("motion_source", "deepmimic")
    bundled = MotionLibrary(source.build(None).load(amp), amp)
    walkers = MotionLibrary(source.build({"clips": list(WALKER_CLIPS)}).load(amp), amp)
    dt = 1.0 / 30.0
    load_before = os.getloadavg()
    t0 = time.time()
    judge, losses = train_judge(bundled, dt, steps=args.steps, seed=args.seed)
    seconds = time.time() - t0
    gen = torch.Generator().manual_seed(args.seed + 1)
    n = 5000
    scores = {
        "train_clips_real": float(judge.score(real_transitions(bundled, n, dt, gen)).mean()),
        "walker_clips_real_held_out": float(judge.score(real_transitions(walkers, n, dt, gen)).mean()),
    }
    spoilt = judge.score(spoilt_transitions(bundled, n, dt, gen))
    k = n // 5
    for i, kind in enumerate(("jitter", "wrong_speed", "distorted_pose", "too_fast", "jump")):
        scores[f"spoilt_{kind}"] = float(spoilt[i * k : (i + 1) * k if i < 4 else None].mean())
    noise = {}
    for sigma in (0.0, 0.005, 0.01, 0.02, 0.05, 0.1):
        noise[str(sigma)] = float(judge.score(_noisy(bundled, n, dt, sigma, gen)).mean())
    out_dir = args.out
    out_dir.mkdir(parents=True, exist_ok=True)
    record = {
        "command": "python bench/train_realism_judge.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "data": "the 15 bundled DeepMimic clips (pybullet), amp humanoid, transitions at 30 Hz",
        "steps": args.steps,
        "seed": args.seed,
        "wall_clock_s": round(seconds, 1),
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "loss_every_100_steps": losses,
        "mean_score": scores,
        "mean_score_with_body_noise_m": noise,
        "transitions_per_score": n,
    }
    save_judge(out_dir / "judge.pt", judge, extra={"validation": record})
    (out_dir / "validation.json").write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(scores, indent=2))
    print(f"wrote {out_dir / 'judge.pt'} and validation.json ({seconds:.0f} s)")
    return 0


def _noisy(lib, n, dt, sigma, gen):  # type: ignore[no-untyped-def]
    """Real transitions with every body position moved by N(0, sigma²) m."""
    import dataclasses

    from mocap.realism import frame_pairs, transitions

    a, b, _ = frame_pairs(lib, n, dt, gen)
    move = lambda s: s.body_pos + sigma * torch.randn(s.body_pos.shape, generator=gen).to(s.body_pos.dtype)  # noqa: E731
    pa, pb = move(a), move(b)
    return transitions(dataclasses.replace(a, body_pos=pa, root_pos=pa[:, 0]), dataclasses.replace(b, body_pos=pb, root_pos=pb[:, 0]))


if __name__ == "__main__":
    raise SystemExit(main())
