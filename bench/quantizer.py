"""Our :class:`~mocap.quantizers.ResidualVQ` vs ``vector_quantize_pytorch.ResidualVQ``
at the same configuration, measured in one run.

Configuration (Hybrid-RVQ paper Sec. 4.2, Sec. 5.2 and Table 5: N = 8 codebooks × K = 1024 codes,
commitment weight 1; our [DEFAULT] choices where the paper does not specify: D = 32, EMA decay 0.99,
dead-code threshold 2, k-means initialization (10 iterations) on the first batch), straight-through
gradients (the reference's rotation trick off).
Quantizer dropout is off in both, so every step runs all N levels (a dropout depth drawn
differently by the two libraries would make the timings incomparable).

For each batch size B (default 256, 1024, 4096, 16384), on the same synthetic data (a seeded
mixture of 256 anisotropic Gaussians in R^D, a stand-in for a latent distribution):

* **time**: one training step = forward in training mode (assignment, EMA update, dead-code reset)
  + backward of ``(w · quantized).sum() + commitment`` to the input. Both quantizers are stepped
  alternately on the same batches; the first ``--warmup`` steps (k-means initialization
  included) are not timed; reported: the median and the best of the timed steps, in ms, and
  **ratio = ours / reference** (of the medians; < 1 means ours is faster);
* **quantization error**: after training, in eval mode, on a held-out set of ``--heldout``
  samples: relative MSE ``mean ‖x − Q(x)‖² / mean ‖x‖²`` at full depth, and the fraction of
  level-1 codes used on the held-out set.

Ratios within one run are comparable; absolute numbers from different runs or machines are not.
``vector-quantize-pytorch`` is a benchmark-only dependency (``pip install vector-quantize-pytorch``);
it is not a dependency of ``mocap``. Results go to ``bench/results/quantizer.json``.

``--relative 0.1 0.25`` adds arms of ours with ``dead_threshold_mode="relative"`` (the threshold a
fraction of the mean use per code, batch / codebook size) on the same batches.

Usage: ``python bench/quantizer.py [--quick] [--sizes 256 1024 4096 16384] [--threads T] [--steps S]
[--dead-threshold 2] [--relative 0.1 0.25]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

import torch
from mocap.quantizers import ResidualVQ
from torch import Tensor

RESULTS = Path(__file__).parent / "results" / "quantizer.json"


def make_data(dim: int, seed: int, clusters: int = 256) -> Callable[[int], Tensor]:
    """A sampler of (B, dim) float32 batches from a fixed mixture of anisotropic Gaussians."""
    gen = torch.Generator().manual_seed(seed)
    centres = torch.randn(clusters, dim, generator=gen) * 2.0
    scales = torch.rand(clusters, dim, generator=gen) * 0.5 + 0.05

    def sample(batch: int) -> Tensor:
        k = torch.randint(0, clusters, (batch,), generator=gen)
        return centres[k] + scales[k] * torch.randn(batch, dim, generator=gen)

    return sample


def build_ours(cfg: dict[str, Any], relative: float | None = None) -> torch.nn.Module:
    """Ours at the config's absolute dead-code threshold, or at ``relative`` x the mean use per code."""
    return ResidualVQ(
        cfg["dim"],
        cfg["num_quantizers"],
        cfg["codebook_size"],
        decay=cfg["decay"],
        dead_threshold=cfg["dead_threshold"] if relative is None else relative,
        dead_threshold_mode="absolute" if relative is None else "relative",
        init="kmeans",
        kmeans_iters=cfg["kmeans_iters"],
        dropout=False,
        commitment="per_level",
    )


def build_reference(cfg: dict[str, Any]) -> torch.nn.Module:
    from vector_quantize_pytorch import ResidualVQ as ReferenceRVQ

    return ReferenceRVQ(
        dim=cfg["dim"],
        num_quantizers=cfg["num_quantizers"],
        codebook_size=cfg["codebook_size"],
        decay=cfg["decay"],
        threshold_ema_dead_code=cfg["dead_threshold"],
        kmeans_init=True,
        kmeans_iters=cfg["kmeans_iters"],
        commitment_weight=1.0,
        rotation_trick=False,
        quantize_dropout=False,
    )


def step_ours(model: torch.nn.Module, x: Tensor, w: Tensor) -> None:
    x = x.clone().requires_grad_(True)
    out = model(x)
    ((w * out.quantized).sum() + out.losses["commit"]).backward()


def step_reference(model: torch.nn.Module, x: Tensor, w: Tensor) -> None:
    x = x.clone().unsqueeze(1).requires_grad_(True)  # (B, 1, D): one position per sample
    quantized, _, commit = model(x)
    ((w.unsqueeze(1) * quantized).sum() + commit.sum()).backward()


@torch.no_grad()
def evaluate(kind: str, model: torch.nn.Module, x: Tensor, codebook_size: int) -> dict[str, float]:
    model.eval()
    if kind == "ours":
        out = model(x)
        q, first = out.quantized, out.indices[:, 0]
    else:
        q, idx, _ = model(x.unsqueeze(1))
        q, first = q.squeeze(1), idx.squeeze(1)[:, 0]
    model.train()
    rel_mse = float((x - q).square().sum(-1).mean() / x.square().sum(-1).mean())
    used = float(torch.unique(first).numel() / codebook_size)
    return {"relative_mse": rel_mse, "level1_code_usage": used}


def run_size(cfg: dict[str, Any], batch: int, steps: int, warmup: int, heldout: Tensor, seed: int, relative: Sequence[float] = ()) -> dict[str, Any]:
    """One batch size: ours and the reference at the config's threshold (timed alternately), plus ours
    at each ``relative`` threshold (arms ``ours_relative_<t>``, same batches)."""
    sample = make_data(cfg["dim"], seed)
    torch.manual_seed(seed)
    models = {"ours": build_ours(cfg), "reference": build_reference(cfg)}
    models.update({f"ours_relative_{t:g}": build_ours(cfg, t) for t in relative})
    stepper = {k: step_reference if k == "reference" else step_ours for k in models}
    times: dict[str, list[float]] = {k: [] for k in models}
    for i in range(warmup + steps):
        x = sample(batch)
        w = torch.randn_like(x)
        order = list(models) if i % 2 == 0 else list(reversed(models))
        for kind in order:
            t0 = time.perf_counter()
            stepper[kind](models[kind], x, w)
            elapsed = time.perf_counter() - t0
            if i >= warmup:
                times[kind].append(elapsed * 1000.0)
    row: dict[str, Any] = {"batch": batch}
    for kind in models:
        row[kind] = {
            "median_ms": statistics.median(times[kind]),
            "best_ms": min(times[kind]),
            **evaluate("reference" if kind == "reference" else "ours", models[kind], heldout, cfg["codebook_size"]),
        }
    ref_mse = max(row["reference"]["relative_mse"], 1e-30)
    row["time_ratio"] = row["ours"]["median_ms"] / row["reference"]["median_ms"]
    row["error_ratio"] = row["ours"]["relative_mse"] / ref_mse
    for t in relative:
        row[f"error_ratio_relative_{t:g}"] = row[f"ours_relative_{t:g}"]["relative_mse"] / ref_mse
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="tiny smoke run (B = 256, 2 x 64 codes, few steps)")
    ap.add_argument("--sizes", nargs="+", type=int, default=None, help="batch sizes (default 256 1024 4096 16384)")
    ap.add_argument("--num-quantizers", type=int, default=None, help="N (default 8, --quick 2)")
    ap.add_argument("--codebook-size", type=int, default=None, help="K (default 1024, --quick 64)")
    ap.add_argument("--dim", type=int, default=32, help="code dimension D (default 32)")
    ap.add_argument("--steps", type=int, default=None, help="timed training steps per size (default 30, --quick 3)")
    ap.add_argument("--warmup", type=int, default=None, help="untimed first steps, k-means init included (default 20, --quick 2)")
    ap.add_argument("--heldout", type=int, default=None, help="held-out samples for the error (default 16384, --quick 1024)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's default)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dead-threshold", type=float, default=2.0, help="absolute dead-code threshold of both libraries (default 2)")
    ap.add_argument("--relative", nargs="*", type=float, default=[], help="extra arms: ours with dead_threshold_mode relative at these fractions")
    ap.add_argument("--out", type=Path, default=None, help="output JSON (default bench/results/quantizer.json; --quick: quantizer_quick.json)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    q = args.quick
    cfg = {
        "dim": args.dim,
        "num_quantizers": args.num_quantizers or (2 if q else 8),
        "codebook_size": args.codebook_size or (64 if q else 1024),
        "decay": 0.99,
        "dead_threshold": args.dead_threshold,
        "kmeans_iters": 10,
    }
    sizes = args.sizes or ([256] if q else [256, 1024, 4096, 16384])
    steps = args.steps or (3 if q else 30)
    warmup = args.warmup or (2 if q else 20)
    heldout = make_data(cfg["dim"], args.seed + 12345)(args.heldout or (1024 if q else 16384))
    out_path = args.out or (RESULTS.with_name("quantizer_quick.json") if q else RESULTS)

    load_before = os.getloadavg()[0]
    rows = []
    for batch in sizes:
        row = run_size(cfg, batch, steps, warmup, heldout, args.seed, args.relative)
        rows.append(row)
        for t in args.relative:
            r = row[f"ours_relative_{t:g}"]
            print(f"B={batch:6d}  ours, relative threshold {t:g}: rel. MSE {r['relative_mse']:.4f} (usage {r['level1_code_usage']:.2f})", flush=True)
        print(
            f"B={batch:6d}  ours {row['ours']['median_ms']:8.2f} ms  ref {row['reference']['median_ms']:8.2f} ms  "
            f"ratio {row['time_ratio']:.2f}  |  rel. MSE ours {row['ours']['relative_mse']:.4f}  "
            f"ref {row['reference']['relative_mse']:.4f}  (usage {row['ours']['level1_code_usage']:.2f} / "
            f"{row['reference']['level1_code_usage']:.2f})",
            flush=True,
        )
    versions = {}
    for name in ("torch", "vector-quantize-pytorch", "mocap"):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    result = {
        "benchmark": "quantizer",
        "quick": q,
        "config": cfg,
        "steps": steps,
        "warmup": warmup,
        "heldout": int(heldout.shape[0]),
        "threads": torch.get_num_threads(),
        "relative_thresholds": list(args.relative),
        "load_avg_1m_before": load_before,
        "load_avg_1m_after": os.getloadavg()[0],
        "machine": {"platform": platform.platform(), "processor": platform.processor(), "python": platform.python_version()},
        "versions": versions,
        "notes": "time_ratio = ours / reference (median ms of forward+backward training steps, same batches, "
        "interleaved); error = relative MSE at full depth on a held-out set after training",
        "results": rows,
    }
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out_path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
