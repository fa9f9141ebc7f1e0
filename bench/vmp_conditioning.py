"""VMP's Table 2 at small scale: the tracking policy conditioned on m_t and z_t (LM, the paper's
method) vs on m_t alone (M), same VAE, reward and budget (specs/latent/vmp_amp.yaml and
specs/latent/vmp_amp_m.yaml).

Each tracker is evaluated with the project's imitation protocol (every bundled clip once from its
first frame, deterministic actions) plus VMP's joint MAE in degrees::

    python bench/vmp_conditioning.py --lm checkpoints/vmp_amp_v2 --m checkpoints/vmp_amp_m \\
        --out bench/results/vmp_conditioning.json

It writes the JSON and, next to it, a per-clip bar plot (``.png``). The paper's claim (Table 2):
LM has a lower mean joint MAE than M. The JSON also has a one-sided sign test on the number of
clips where LM is lower (one seed per policy: per-clip counts are the only spread measured here).

Two joint MAEs are reported. ``joint_mae_deg`` is the protocol's: each clip's frames until that
policy fails, so a policy that stays up longer is also scored on later, harder frames. The paper's
trackers do not fall, so it has no such bias; ``equal_frames`` removes it here: per clip, both
policies are scored on the frames both track (the shorter of the two episodes).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path


def rollout(loaded):
    """The protocol's rollout of every clip of a built evaluation target (one env per clip,
    deterministic): its Trajectories."""
    import torch
    from mocap.imitation_eval import episode_frames, rollout_imitation

    lib = loaded.library
    ids = torch.arange(lib.num_clips)
    sim = loaded.make_sim(len(ids))
    try:
        out = rollout_imitation(sim, lib, loaded.policy, ids, episode_frames(lib, ids, sim.dt, None), threshold=0.5)
    finally:
        sim.close()
    return out.traj


def equal_frames_joint_mae(a, b, skeleton) -> tuple[list[float], list[float], list[int]]:
    """Per clip joint MAE (deg) of trajectories ``a`` and ``b`` on the frames valid in both."""
    from mocap.state import Trajectories
    from mocap_vmp.metrics import joint_mae_deg

    T = min(a.sim.shape[0], b.sim.shape[0])
    both = a.valid()[:T] & b.valid()[:T]

    def cut(tr):
        return Trajectories(tr.sim[:T], tr.ref[:T], tr.fps, both, tr.sim_rot[:T], tr.ref_rot[:T])

    return (
        joint_mae_deg(cut(a), skeleton).tolist(),
        joint_mae_deg(cut(b), skeleton).tolist(),
        both.sum(0).tolist(),
    )


def sign_test_p(k: int, n: int) -> float:
    """One-sided sign test: P(X >= k) for X ~ Binomial(n, 1/2), the chance that a policy no better
    than the other is lower on at least ``k`` of ``n`` clips."""
    if not 0 <= k <= n:
        raise ValueError(f"sign test: need 0 <= k <= n, got k={k}, n={n}")
    return sum(math.comb(n, i) for i in range(k, n + 1)) / 2**n


def plot(result: dict, out: Path) -> None:
    """Per-clip joint MAE of LM and M (own tracked frames, and the frames both track) as bars;
    a clip each policy tracks to its end is marked with a dot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result["LM"]["clips"])
    x = list(range(len(names)))
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.2), sharey=True)
    panels = (
        (
            "own tracked frames",
            {k: [result[k]["clips"][n]["joint_mae_deg"] for n in names] for k in ("LM", "M")},
            result["LM"]["joint_mae_deg"],
            result["M"]["joint_mae_deg"],
        ),
        (
            "frames both track",
            {k: [result["equal_frames"]["clips"][n][k] for n in names] for k in ("LM", "M")},
            result["equal_frames"]["LM"],
            result["equal_frames"]["M"],
        ),
    )
    for ax, (title, vals, mean_lm, mean_m) in zip(axes, panels):
        for off, key, color in ((-0.2, "LM", "tab:blue"), (0.2, "M", "tab:orange")):
            mean = mean_lm if key == "LM" else mean_m
            ax.bar([i + off for i in x], vals[key], width=0.4, color=color, label=f"{key} (mean {mean:.2f}°)")
            ok = [i for i, n in enumerate(names) if result[key]["clips"][n]["success"]]
            ax.plot([i + off for i in ok], [vals[key][i] + 0.3 for i in ok], "k.", ms=5)
        ax.set_xticks(x, names, rotation=60, ha="right", fontsize=8)
        ax.set_title(f"joint MAE per clip, {title}")
        ax.legend(fontsize=8)
    axes[0].set_ylabel("joint MAE (deg); dot: clip tracked to its end")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)


def evaluate(target: Path) -> tuple[dict, object]:
    """The protocol's table and joint MAE of one tracker, and the built target (for :func:`rollout`)."""
    import torch
    from mocap.evaluation import ImitationEvalParams
    from mocap.eval_targets import build_evaluation_target, load_evaluation_target
    from mocap.imitation_eval import evaluate_imitator
    from mocap.metrics import default_metrics
    from mocap.plugins import get_plugins
    from mocap_vmp.metrics import JointMAE, latent_label_metrics

    torch.set_num_threads(1)
    plugins = get_plugins()
    info = load_evaluation_target(target, plugins)
    loaded = build_evaluation_target(info, plugins)
    table = evaluate_imitator(loaded.policy, loaded.library, loaded.make_sim, ImitationEvalParams(video=False), [*default_metrics(), JointMAE(loaded.skeleton)])
    agg = table["aggregate"]
    # the paper's section 5.4 latent metrics, labels = clip names (the same VAE under both trackers)
    label = latent_label_metrics(loaded.latent, loaded.library) if loaded.latent is not None and loaded.library.num_clips >= 2 else {}
    conditioning = info.resolved.spec.latent.trainer.params["tracker"]["conditioning"] if info.resolved.spec.latent.trainer else None
    return {
        "target": str(target),
        "conditioning": conditioning,
        "succeeded": agg["succeeded"],
        "total": agg["total"],
        "joint_mae_deg": agg["joint_mae"],
        "mpjpe_g": agg["mpjpe_g"],
        "tracked_s": agg.get("tracked_s"),
        "latent_metrics": label,
        "clips": {
            name: {"success": row["success"], "joint_mae_deg": row["joint_mae"], "mpjpe_g": row["mpjpe_g"], "tracked_s": row.get("tracked_s")}
            for name, row in table["clips"].items()
        },
    }, loaded


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lm", type=Path, required=True, help="the LM-conditioned VMP (checkpoint dir, run dir or latent file)")
    ap.add_argument("--m", type=Path, required=True, help="the M-conditioned VMP")
    ap.add_argument("--out", type=Path, default=Path("bench/results/vmp_conditioning.json"))
    args = ap.parse_args(argv)
    (lm, loaded_lm), (m, loaded_m) = evaluate(args.lm), evaluate(args.m)
    names = list(loaded_lm.library.clip_names)
    e_lm, e_m, n_frames = equal_frames_joint_mae(rollout(loaded_lm), rollout(loaded_m), loaded_lm.skeleton)
    equal = {
        "definition": "per clip, joint MAE (deg) of both policies on the frames both track; then the mean over clips",
        "LM": sum(e_lm) / len(e_lm),
        "M": sum(e_m) / len(e_m),
        "clips": {n: {"LM": x, "M": y, "frames": k} for n, x, y, k in zip(names, e_lm, e_m, n_frames)},
    }
    equal["lm_beats_m"] = bool(equal["LM"] < equal["M"])
    equal["clips_where_lm_is_lower"] = sum(x < y for x, y in zip(e_lm, e_m))
    both = [n for n in lm["clips"] if math.isfinite(lm["clips"][n]["joint_mae_deg"]) and math.isfinite(m["clips"][n]["joint_mae_deg"])]
    result = {
        "claim": "VMP Table 2: LM conditioning has a lower mean joint MAE than M",
        "protocol": "mocap-imitation-v1 + joint MAE (deg) over each clip's tracked frames",
        "LM": lm,
        "M": m,
        "lm_beats_m_on_joint_mae": bool(lm["joint_mae_deg"] < m["joint_mae_deg"]),
        "clips_where_lm_is_lower": sum(lm["clips"][n]["joint_mae_deg"] < m["clips"][n]["joint_mae_deg"] for n in both),
        "clips_compared": len(both),
        "equal_frames": equal,
    }
    result["sign_test_p"] = sign_test_p(result["clips_where_lm_is_lower"], len(both))
    equal["sign_test_p"] = sign_test_p(equal["clips_where_lm_is_lower"], len(e_lm))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    plot(result, args.out.with_suffix(".png"))
    print(
        f"LM: {lm['succeeded']}/{lm['total']} clips, joint MAE {lm['joint_mae_deg']:.2f} deg, MPJPE-g {lm['mpjpe_g']:.0f} mm\n"
        f"M:  {m['succeeded']}/{m['total']} clips, joint MAE {m['joint_mae_deg']:.2f} deg, MPJPE-g {m['mpjpe_g']:.0f} mm\n"
        f"LM lower on {result['clips_where_lm_is_lower']}/{result['clips_compared']} clips (sign test p = {result['sign_test_p']:.3f})\n"
        f"equal frames: LM {equal['LM']:.2f} deg, M {equal['M']:.2f} deg, LM lower on {equal['clips_where_lm_is_lower']}/{len(e_lm)} clips "
        f"(p = {equal['sign_test_p']:.3f})\n"
        f"VAE latent metrics (clip labels): {lm['latent_metrics']}; wrote {args.out}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
