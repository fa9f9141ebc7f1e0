"""What the bundled clips ask of the amp humanoid's shoulders, per shoulder variant.

For each variant of the ``amp`` humanoid (``shoulder_turns``, ``shoulder_order``) and each bundled
clip, from the :class:`~mocap.motion.library.MotionLibrary`'s reference DoFs (unwrapped within the
clip, the clip's mean in (-pi, pi]):

* ``frames_outside``: the share of frames where a shoulder hinge's reference leaves its range (the PD
  target is clamped there, so the pose cannot be reached);
* ``first_outside_s``: when that first happens;
* ``max_speed``: the fastest shoulder hinge, rad/s (forward differences at the clip's rate);
* ``winding``: looping clips whose shoulder reference is carried on by whole turns per cycle;
* ``branch_search_max_speed`` (the ``yxz`` variants): the same after choosing, per frame, the
  smoother of the decomposition's two branches by a Viterbi search over the clip (the middle angle
  then ranges beyond +-90 deg): whether the fast swings are a choice of branch or the order's.

Also, per variant: every clip's speed of the fastest hinge that is not a shoulder, for scale. Writes
JSON (``--out``) and prints a table.

    python bench/shoulder_references.py --out bench/results/shoulder_references.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import torch

VARIANTS: dict[str, dict[str, object]] = {
    "yxz, +-180 deg (default; checkpoints up to imitator_amp_v5)": {},
    "yxz, 8 turns": {"shoulder_turns": 8.0},
    "xzy, +-180 deg": {"shoulder_order": "xzy"},
    "xzy, 8 turns (specs/imitator/continue_v4_shoulders.yaml)": {"shoulder_turns": 8.0, "shoulder_order": "xzy"},
}
TWO_PI = 2 * math.pi


def _wrap(v: torch.Tensor) -> torch.Tensor:
    return torch.remainder(v + math.pi, TWO_PI) - math.pi


def branch_search(d: torch.Tensor) -> torch.Tensor:
    """(T, 3) y-x-z angles of one joint -> the path over the two Euler branches ``(a, b, c)`` and
    ``(a + pi, pi - b, c + pi)`` with the least summed squared step (Viterbi; steps wrapped to
    (-pi, pi]), unwrapped along the path."""
    other = torch.stack([d[:, 0] + math.pi, math.pi - d[:, 1], d[:, 2] + math.pi], 1)
    cand = torch.stack([d, other], 1)  # (T, 2, 3)
    cost = torch.zeros(2, dtype=d.dtype)
    back = []
    for t in range(1, len(d)):
        step = _wrap(cand[t][None, :, :] - cand[t - 1][:, None, :])  # (previous, current, 3)
        total = cost[:, None] + step.square().sum(-1)
        cost, arg = total.min(0)
        back.append(arg)
    j = int(cost.argmin())
    path = [j]
    for arg in reversed(back):
        j = int(arg[j])
        path.append(j)
    path.reverse()
    out = [cand[0, path[0]]]
    for t in range(1, len(d)):
        out.append(out[-1] + _wrap(cand[t, path[t]] - cand[t - 1, path[t - 1]]))
    return torch.stack(out)


def measure(params: dict[str, object]) -> dict[str, object]:
    from mocap.motion.library import MotionLibrary
    from mocap.plugins import get_plugins

    plugins = get_plugins()
    sk = plugins.get("humanoid", "amp").build(params)
    lib = MotionLibrary(plugins.get("motion_source", "deepmimic").build({}).load(sk), sk, dtype=torch.float64)
    names = list(sk.dof_names)
    lo = torch.tensor([h.range[0] for h in sk.hinges], dtype=torch.float64)
    hi = torch.tensor([h.range[1] for h in sk.hinges], dtype=torch.float64)
    shoulder = [i for i, n in enumerate(names) if "shoulder" in n]
    other = [i for i in range(len(names)) if i not in shoulder]
    order = str(params.get("shoulder_order", "yxz"))
    clips: dict[str, dict[str, object]] = {}
    for c, clip in enumerate(lib.clip_names):
        rows = lib.frame_clip == c
        d = lib.dof_pos[rows]
        fps = float(lib.fps[c])
        out = ((d < lo) | (d > hi))[:, shoulder].any(1)
        first = int(torch.nonzero(out)[0]) / fps if bool(out.any()) else None
        entry: dict[str, object] = {
            "frames_outside": round(float(out.double().mean()), 3),
            "first_outside_s": None if first is None else round(first, 3),
            "max_speed": round(float(d[:, shoulder].diff(dim=0).abs().max()) * fps, 1),
            "max_speed_other_hinges": round(float(d[:, other].diff(dim=0).abs().max()) * fps, 1),
            "winding": bool(lib.cycle_dof_winding[c, shoulder].any()),
        }
        if order == "yxz":
            speeds = []
            for side in ("right", "left"):
                cols = [names.index(f"{side}_shoulder_{a}") for a in "yxz"]
                speeds.append(float(branch_search(d[:, cols]).diff(dim=0).abs().max()) * fps)
            entry["branch_search_max_speed"] = round(max(speeds), 1)
        clips[clip] = entry
    return {"params": params, "clips": clips}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("bench/results/shoulder_references.json"))
    args = ap.parse_args(argv)
    result = {"source": "deepmimic (the 15 bundled clips)", "units": {"max_speed": "rad/s", "first_outside_s": "s"}, "variants": {}}
    for label, params in VARIANTS.items():
        m = measure(params)
        result["variants"][label] = m
        clips = m["clips"]
        bad = [n for n, e in clips.items() if e["frames_outside"]]
        fast = max(e["max_speed"] for e in clips.values())
        print(f"{label}: shoulders outside their range in {len(bad)} clips {bad}; fastest shoulder {fast} rad/s")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
