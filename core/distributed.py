"""Data-parallel training on ``torch.distributed``: process-group helpers shared by the trainers.

Launch any spec with torchrun (one process per "rank"; ``torchrun`` is the same as
``python -m torch.distributed.run``)::

    torchrun --nproc_per_node 2 -m mocap run spec.yaml --out runs/x

Without torchrun (``WORLD_SIZE`` unset or 1) every helper here is a no-op and training is exactly
the single-process code path. Under torchrun:

* :func:`init` joins the process group from torchrun's environment variables (``RANK``,
  ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``, ``MASTER_PORT``): ``gloo`` for CPU training,
  ``nccl`` with one GPU per local rank for CUDA.
* Trainers that declare ``data_parallel = True`` (``ppo``, ``distill``) run on every rank with
  their own environments (seed :func:`rank_seed`), the initial weights broadcast from rank 0
  (:func:`broadcast_module`), gradients averaged before each optimizer step
  (:func:`average_gradients`; a non-finite gradient or loss on any rank makes every rank skip the
  minibatch), running normalizers merged exactly (:func:`sync_normalizers`), episode statistics
  reduced for logging (:func:`reduce_metrics`). Other trainers run on rank 0 alone (:func:`solo`)
  while the other ranks wait.
* Only rank 0 (:func:`is_main`) writes checkpoints, ``metrics.jsonl``, TensorBoard, the report,
  ``stages.json`` and ``DONE.json``; the other ranks print nothing on stdout.

``MOCAP_DIST_TIMEOUT`` (seconds, default 7 days) bounds how long a rank waits for the others (e.g.
while rank 0 trains a stage alone). ``MOCAP_DIST_DEBUG_DIR``: each rank writes the digest of its
final weights there (``<trainer>-rank<r>.txt``; used by the tests).
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import math
import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from datetime import timedelta
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

DEFAULT_TIMEOUT_S = 7 * 24 * 3600
_solo_depth = 0  # > 0 inside solo(): this process behaves as a single-process run


# ------------------------------------------------------------------------------- the group
def launched() -> bool:
    """True when this process was started by torchrun with more than one process."""
    try:
        return int(os.environ.get("WORLD_SIZE", "1")) > 1
    except ValueError:
        return False


def _group_ready() -> bool:
    import torch.distributed as dist

    return dist.is_available() and dist.is_initialized()


def active() -> bool:
    """True when collectives are in use: the process group is up with >1 ranks and not in :func:`solo`."""
    return _solo_depth == 0 and _group_ready() and world_size() > 1


def world_size() -> int:
    """Number of processes training together (1 without torchrun or inside :func:`solo`)."""
    if _solo_depth:
        return 1
    if _group_ready():
        import torch.distributed as dist

        return int(dist.get_world_size())
    return int(os.environ.get("WORLD_SIZE", "1")) if launched() else 1


def rank() -> int:
    """This process's rank (0 without torchrun or inside :func:`solo`)."""
    if _solo_depth:
        return 0
    if _group_ready():
        import torch.distributed as dist

        return int(dist.get_rank())
    return int(os.environ.get("RANK", "0")) if launched() else 0


def local_rank() -> int:
    return int(os.environ.get("LOCAL_RANK", "0")) if launched() else 0


def is_main() -> bool:
    """True on the process that writes the run's files and prints (rank 0, or a single process)."""
    return rank() == 0


def init(device: torch.device | None = None) -> torch.device:
    """Join torchrun's process group (once) and return this rank's device.

    Without torchrun it returns ``device`` (default CPU) and does nothing. A CUDA ``device`` becomes
    ``cuda:<LOCAL_RANK>`` with the ``nccl`` backend; anything else uses ``gloo``.
    """
    device = torch.device(device) if device is not None else torch.device("cpu")
    if not launched():
        return device
    import torch.distributed as dist

    from mocap.pipeline import StageFailed  # a launch that cannot work is the user's to fix

    if device.type == "cuda":
        count = torch.cuda.device_count()
        if local_rank() >= count:
            raise StageFailed(
                f"rank {rank()} has LOCAL_RANK {local_rank()} but this node has {count} CUDA device(s): start at most one process per GPU (--nproc_per_node)"
            )
        device = torch.device("cuda", local_rank())
        torch.cuda.set_device(device)
    if _group_ready():
        return device
    missing = [v for v in ("RANK", "MASTER_ADDR", "MASTER_PORT") if not os.environ.get(v)]
    if missing:
        raise StageFailed(
            f"WORLD_SIZE={os.environ.get('WORLD_SIZE')} but {', '.join(missing)} not set: launch with torchrun "
            "(or python -m torch.distributed.run), or unset WORLD_SIZE for a single process"
        )
    backend = "nccl" if device.type == "cuda" else "gloo"
    timeout = timedelta(seconds=float(os.environ.get("MOCAP_DIST_TIMEOUT", DEFAULT_TIMEOUT_S)))
    dist.init_process_group(backend=backend, timeout=timeout)
    atexit.register(cleanup)
    return device


def cleanup() -> None:
    """Leave the process group (safe to call twice or without one)."""
    if _group_ready():
        import torch.distributed as dist

        with contextlib.suppress(Exception):
            dist.destroy_process_group()


@contextlib.contextmanager
def solo() -> Iterator[None]:
    """Within the block this process acts as a single-process run (no collectives): rank 0 uses it
    to train a stage whose trainer is not data-parallel while the other ranks wait."""
    global _solo_depth
    _solo_depth += 1
    try:
        yield
    finally:
        _solo_depth -= 1


def rank_seed(seed: int, rank_: int | None = None) -> int:
    """The seed of one rank, derived from the stage seed: rank 0 keeps ``seed`` (so a single-process
    run is unchanged), rank r > 0 gets an independent 32-bit seed."""
    r = rank() if rank_ is None else int(rank_)
    if r == 0:
        return int(seed)
    return int.from_bytes(hashlib.sha256(f"{int(seed)}:rank:{r}".encode()).digest()[:4], "little")


def _comm_device() -> torch.device:
    import torch.distributed as dist

    if dist.get_backend() == "nccl":
        return torch.device("cuda", torch.cuda.current_device())
    return torch.device("cpu")


# ------------------------------------------------------------------------------ collectives
def barrier() -> None:
    if active():
        import torch.distributed as dist

        dist.barrier()


def all_reduce_sum(t: Tensor) -> Tensor:
    """The element-wise sum of ``t`` over ranks (a new tensor on ``t``'s device; ``t`` itself when alone)."""
    if not active():
        return t
    import torch.distributed as dist

    buf = t.detach().to(_comm_device()).clone()
    dist.all_reduce(buf, op=dist.ReduceOp.SUM)
    return buf.to(t.device)


def all_reduce_mean(t: Tensor) -> Tensor:
    return all_reduce_sum(t) / world_size() if active() else t


def any_true(flag: bool) -> bool:
    """True when ``flag`` is true on any rank (every rank gets the same answer)."""
    if not active():
        return bool(flag)
    return bool(all_reduce_sum(torch.tensor([1.0 if flag else 0.0], dtype=torch.float64)).item() > 0)


def all_gather_tensor(t: Tensor) -> list[Tensor]:
    """Every rank's ``t`` (same shape and dtype on all ranks), in rank order."""
    if not active():
        return [t]
    import torch.distributed as dist

    buf = t.detach().to(_comm_device()).contiguous()
    out = [torch.empty_like(buf) for _ in range(world_size())]
    dist.all_gather(out, buf)
    return [o.to(t.device) for o in out]


def broadcast_object(obj: Any, src: int = 0) -> Any:
    """Rank ``src``'s (picklable) ``obj`` on every rank."""
    if not active():
        return obj
    import torch.distributed as dist

    box = [obj]
    dist.broadcast_object_list(box, src=src, device=_comm_device() if dist.get_backend() == "nccl" else None)
    return box[0]


def all_gather_object(obj: Any) -> list[Any]:
    """Every rank's (picklable) ``obj``, in rank order."""
    if not active():
        return [obj]
    import torch.distributed as dist

    out: list[Any] = [None] * world_size()
    dist.all_gather_object(out, obj)
    return out


def gather_object(obj: Any, dst: int = 0) -> list[Any] | None:
    """Every rank's ``obj`` in rank order on rank ``dst``; None elsewhere."""
    if not active():
        return [obj]
    import torch.distributed as dist

    out: list[Any] | None = [None] * world_size() if rank() == dst else None
    dist.gather_object(obj, out, dst=dst)
    return out


# ----------------------------------------------------------------------------- training
@torch.no_grad()
def broadcast_module(module: nn.Module, src: int = 0) -> None:
    """Copy rank ``src``'s parameters and buffers into every rank's ``module``."""
    if not active():
        return
    import torch.distributed as dist

    for t in [*module.parameters(), *module.buffers()]:
        buf = t.detach().to(_comm_device()).clone()
        dist.broadcast(buf, src=src)
        t.copy_(buf.to(t.device))


@torch.no_grad()
def average_gradients(params: Sequence[Tensor], *scalars: Tensor) -> tuple[Tensor, ...]:
    """Average the gradients of ``params`` over the ranks in place (one all-reduce), and return the
    rank-averaged ``scalars`` (e.g. the loss) from the same all-reduce.

    A non-finite value on any rank makes the average non-finite on every rank, so a
    :class:`~mocap.faults.FaultGuard` step given the averaged loss skips the minibatch everywhere.
    Alone it returns ``scalars`` unchanged and touches nothing.
    """
    if not active():
        return tuple(scalars)
    import torch.distributed as dist

    dev = _comm_device()
    pieces = [(p.grad if p.grad is not None else torch.zeros_like(p)).detach().reshape(-1).to(dev, torch.float32) for p in params]
    pieces += [s.detach().reshape(-1).to(dev, torch.float32) for s in scalars]
    flat = torch.cat(pieces) if pieces else torch.zeros(0, device=dev)
    dist.all_reduce(flat, op=dist.ReduceOp.SUM)
    flat /= world_size()
    offset = 0
    for p in params:
        n = p.numel()
        if p.grad is not None:  # (a parameter without a gradient has none on every rank: same loss)
            p.grad.copy_(flat[offset : offset + n].view_as(p))
        offset += n
    out = []
    for s in scalars:
        n = s.numel()
        out.append(flat[offset : offset + n].reshape(s.shape).to(s.device, s.dtype))
        offset += n
    return tuple(out)


def _normalizers(module: nn.Module) -> list[Any]:
    from mocap.rl.normalizer import RunningNormalizer

    return [m for m in module.modules() if isinstance(m, RunningNormalizer)]


@torch.no_grad()
def sync_normalizers(module: nn.Module, update: Callable[[], Any]) -> None:
    """Run ``update()`` (which folds this rank's batch into the running normalizers inside
    ``module``) so that every rank ends with the statistics of all ranks' batches together.

    Each normalizer's updates are captured as moments, exchanged (one all-gather), merged in rank
    order with the exact parallel-variance formula and applied identically everywhere. Alone it is
    just ``update()``.
    """
    if not active():
        update()
        return
    from mocap.rl.normalizer import combine_moments, empty_moments

    norms = _normalizers(module)
    with contextlib.ExitStack() as stack:
        captured = [stack.enter_context(n.capture()) for n in norms]
        update()
    if not norms:
        return
    dev = _comm_device()
    packed = []
    for norm, parts in zip(norms, captured):
        m = combine_moments(parts) if parts else empty_moments(norm.shape)
        packed += [m.count.reshape(1).to(dev), m.mean.reshape(-1).to(dev), m.var.reshape(-1).to(dev)]
    flat = torch.cat([p.to(torch.float64) for p in packed])
    per_rank = all_gather_tensor(flat)
    offset = 0
    from mocap.rl.normalizer import Moments

    for norm in norms:
        size = math.prod(norm.shape)
        parts = []
        for r_flat in per_rank:
            count = r_flat[offset]
            mean = r_flat[offset + 1 : offset + 1 + size].reshape(norm.shape)
            var = r_flat[offset + 1 + size : offset + 1 + 2 * size].reshape(norm.shape)
            parts.append(Moments(count, mean, var))
        offset += 1 + 2 * size
        norm.update_moments(combine_moments(parts))


def global_mean_std(x: Tensor) -> tuple[Tensor, Tensor]:
    """Mean and unbiased standard deviation of ``x`` over all ranks' elements (exact merge)."""
    from mocap.rl.normalizer import Moments, batch_moments, combine_moments

    local = batch_moments(x.reshape(-1), ())
    flat = torch.stack([local.count, local.mean, local.var])
    parts = [Moments(f[0], f[1], f[2]) for f in all_gather_tensor(flat)]
    m = combine_moments(parts)
    n = m.count.clamp_min(2.0)
    std = torch.sqrt(m.var * m.count / (n - 1))
    return m.mean.to(x.dtype), std.to(x.dtype)


def check_inputs(guard: Any, **tensors: Tensor | None) -> bool:
    """:meth:`FaultGuard.check_inputs` agreed by all ranks: when any rank's batch has a non-finite
    input, every rank records the fault and skips the update."""
    if not active():
        return bool(guard.check_inputs(**tensors))
    reason = next((f"non-finite {k}" for k, t in tensors.items() if t is not None and not bool(torch.isfinite(t).all())), "")
    if any_true(bool(reason)):
        guard.fault(reason or "non-finite inputs on another rank")
        return False
    return True


def reduce_metrics(
    local: Mapping[str, float],
    *,
    sums: Iterable[str] = (),
    maxima: Iterable[str] = (),
    windows: Mapping[str, Sequence[float]] | None = None,
    window_prefix: str = "episode/",
) -> dict[str, float]:
    """Combine one iteration's log values of all ranks (every rank gets the same dict).

    Keys in ``sums`` are added, keys in ``maxima`` (e.g. wall times: the slowest rank sets the pace)
    take the maximum, the rest are averaged over the ranks that logged them. ``windows`` (episode
    statistics: key -> recent values) become ``<window_prefix><key>``: the mean over all ranks'
    values together.
    """
    sums, maxima = set(sums), set(maxima)
    win = {k: (float(sum(v)), len(v)) for k, v in (windows or {}).items() if len(v)}
    gathered = all_gather_object((dict(local), win))
    out: dict[str, float] = {}
    keys: list[str] = []
    for values, _ in gathered:
        keys += [k for k in values if k not in keys]
    for key in keys:
        vals = [float(v[key]) for v, _ in gathered if key in v]
        if key in sums:
            out[key] = float(sum(vals))
        elif key in maxima:
            out[key] = float(max(vals))
        else:
            out[key] = float(sum(vals) / len(vals))
    totals: dict[str, list[float]] = {}
    for _, w in gathered:
        for key, (s, n) in w.items():
            acc = totals.setdefault(key, [0.0, 0.0])
            acc[0] += s
            acc[1] += n
    for key, (s, n) in totals.items():
        out[f"{window_prefix}{key}"] = s / n
    return out


def state_digest(module: nn.Module | Mapping[str, Any]) -> str:
    """sha256 of a module's parameters and buffers, or of a ``state_dict`` (names, shapes, bytes of
    the tensors): equal iff bit-identical."""
    h = hashlib.sha256()
    state = module.state_dict() if isinstance(module, nn.Module) else module
    for name, t in state.items():
        if not isinstance(t, Tensor):
            continue
        h.update(name.encode())
        h.update(str(tuple(t.shape)).encode())
        h.update(t.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def assert_in_sync(module: nn.Module, what: str) -> str:
    """Check that every rank holds bit-identical weights (raises otherwise); returns the digest.

    With ``MOCAP_DIST_DEBUG_DIR`` set, each rank also writes ``<what>-rank<r>.txt`` with its digest.
    """
    digest = state_digest(module)
    debug_dir = os.environ.get("MOCAP_DIST_DEBUG_DIR")
    if debug_dir and (active() or launched()):
        path = Path(debug_dir) / f"{what}-rank{rank()}.txt"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(digest + "\n", encoding="utf-8")
    if active():
        digests = all_gather_object(digest)
        if len(set(digests)) != 1:
            raise RuntimeError(f"{what}: the ranks' weights diverged (digests {digests}); this is a bug in data-parallel training")
    return digest


__all__ = [
    "active",
    "all_gather_object",
    "all_gather_tensor",
    "all_reduce_mean",
    "all_reduce_sum",
    "any_true",
    "assert_in_sync",
    "average_gradients",
    "barrier",
    "broadcast_module",
    "broadcast_object",
    "check_inputs",
    "cleanup",
    "gather_object",
    "global_mean_std",
    "init",
    "is_main",
    "launched",
    "local_rank",
    "rank",
    "rank_seed",
    "reduce_metrics",
    "solo",
    "state_digest",
    "sync_normalizers",
    "world_size",
]
