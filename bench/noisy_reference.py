"""Plot imitation from noisy references: success and MPJPE-g against the noise level.

Each input is the JSON of ``mocap eval-noisy TARGET --json F`` (one line per file, labelled with its
target and smoothing):

    mocap eval-noisy checkpoints/imitator_amp_v2 --json bench/results/noisy_reference_imitator_amp_v2.json
    mocap eval-noisy checkpoints/imitator_amp_v2 --smooth 0.5 --json bench/results/noisy_reference_imitator_amp_v2_smooth0.5.json
    python bench/noisy_reference.py bench/results/noisy_reference_imitator_amp_v2.json \\
        bench/results/noisy_reference_imitator_amp_v2_smooth0.5.json --out bench/results/noisy_reference.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def label(result: dict) -> str:
    smooth = result.get("smooth", 1.0)
    return f"{result.get('evaluated', '?')}" + (f", smoothing a = {smooth:g}" if smooth != 1 else ", raw stream")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", type=Path, nargs="+", help="`mocap eval-noisy --json` outputs")
    parser.add_argument("--out", type=Path, default=Path("bench/results/noisy_reference.png"))
    args = parser.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for path in args.results:
        result = json.loads(path.read_text())
        rows = [r for r in result["levels"] if isinstance(r["level"], int)]
        x = [r["level"] for r in rows]
        axes[0].plot(x, [r["aggregate"]["succeeded"] for r in rows], "o-", label=label(result))
        axes[1].plot(x, [r["aggregate"]["mpjpe_g"] for r in rows], "s-", label=label(result))
        total = rows[0]["aggregate"]["total"] if rows else 0
    ticks = sorted({r["level"] for p in args.results for r in json.loads(p.read_text())["levels"] if isinstance(r["level"], int)})
    names = []
    for k in ticks:
        n = next(r["noise"] for p in args.results for r in json.loads(p.read_text())["levels"] if r["level"] == k)
        names.append(f"{k}\n{n['joint_deg']:g}°/{n['root_deg']:g}°/{100 * n['root_m']:g}cm/{100 * n['drop_prob']:g}%")
    for ax in axes:
        ax.set_xticks(ticks, names, fontsize=8)
        ax.set_xlabel("noise level (joint jitter / root jitter / root cm / dropped frames)")
        ax.legend(fontsize=8)
    axes[0].set_ylabel(f"clips tracked (of {total})")
    axes[1].set_ylabel("MPJPE-g against the clean clip, all clips (mm)")
    fig.suptitle("imitation from noisy references (mocap-noisy-reference-v1)")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
