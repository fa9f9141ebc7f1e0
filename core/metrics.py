"""Imitation metrics with one definition, explicit units and a protocol id.

Every metric takes a :class:`Trajectories` pair — simulated and reference body positions
(T, N, B, 3) in metres, world frame, at ``fps`` — and returns a per-episode (N,) tensor. Frames
where ``mask`` (T, N) is False (after an episode ended) are ignored. Definitions (PHC Sec. 4
"Metrics", after UHC; the official code's ``compute_metrics_lite``, smpl_sim/smpllib/smpl_eval.py):

* ``mpjpe_g``: mean over valid frames and bodies of ``||p_sim - p_ref||``, mm.
* ``mpjpe_l``: the same after subtracting each pose's root (body 0) position, mm.
* ``pa_mpjpe``: the same after a per-frame similarity Procrustes alignment (scale, rotation,
  translation) of the simulated pose onto the reference, mm.
* ``vel_err``: mean ``||(p_{t+1} - p_t)_sim - (p_{t+1} - p_t)_ref||``, mm/frame at ``fps``
  (PHC's unit; multiply by fps for mm/s).
* ``acc_err``: mean ``||(p_{t-1} - 2 p_t + p_{t+1})_sim - (...)_ref||``, mm/frame² at ``fps``.
* ``rot_err``: mean over bodies of the geodesic angle between the simulated and reference world
  body orientations, degrees (needs the rotations in the trajectories; NaN without them).
* ``success``: 1 if at no valid frame after ``grace_frames`` the mean body error exceeds
  ``threshold`` (0.5 m, PHC/PULSE evaluation), else 0. ``success_linf`` uses the max body error.

``PROTOCOL`` names this set of definitions; reports print it so numbers are never compared
across different protocols.
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor

from mocap.interfaces import Metric
from mocap.metric_params import BUILTIN_DISPLAY, BUILTIN_INFO, PROTOCOL, SuccessParams
from mocap.rotations import quat_angle_between
from mocap.state import Trajectories

__all__ = ["BUILTIN_DISPLAY", "BUILTIN_METRICS", "PROTOCOL", "SuccessParams", "default_metrics", "make_metric", "success"]


def _masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    """Mean over dim 0 of (T, N) ``values`` where ``mask``; NaN for an episode with no valid frame."""
    m = mask.to(values.dtype)
    total = (values * m).sum(0)
    count = m.sum(0)
    return torch.where(count > 0, total / count.clamp_min(1), torch.full_like(total, float("nan")))


def per_frame_error(sim: Tensor, ref: Tensor) -> Tensor:
    """(T, N) mean over bodies of the Euclidean error, in the inputs' unit."""
    return torch.linalg.vector_norm(sim - ref, dim=-1).mean(-1)


def mpjpe_global(tr: Trajectories) -> Tensor:
    return 1000.0 * _masked_mean(per_frame_error(tr.sim, tr.ref), tr.valid())


def mpjpe_local(tr: Trajectories) -> Tensor:
    sim = tr.sim - tr.sim[..., :1, :]
    ref = tr.ref - tr.ref[..., :1, :]
    return 1000.0 * _masked_mean(per_frame_error(sim, ref), tr.valid())


def procrustes_align(source: Tensor, target: Tensor) -> Tensor:
    """Similarity-align ``source`` (..., B, 3) onto ``target``: argmin over s, R, t of ||s R x + t - y||.

    Umeyama's closed form: centre both, SVD of the cross-covariance, a reflection fix on the
    last singular vector, scale = trace(S D) / var(source).
    """
    mu_s = source.mean(-2, keepdim=True)
    mu_t = target.mean(-2, keepdim=True)
    xs, xt = source - mu_s, target - mu_t
    cov = xt.transpose(-1, -2) @ xs  # (..., 3, 3) = sum_b y_b x_b^T
    u, sig, vh = torch.linalg.svd(cov)
    d = torch.ones_like(sig)
    d[..., -1] = torch.sign(torch.linalg.det(u @ vh))
    d[..., -1] = torch.where(d[..., -1] == 0, torch.ones_like(d[..., -1]), d[..., -1])
    rot = u @ torch.diag_embed(d) @ vh
    var_s = (xs**2).sum((-1, -2))
    scale = (sig * d).sum(-1) / var_s.clamp_min(1e-12)
    return scale[..., None, None] * (xs @ rot.transpose(-1, -2)) + mu_t


def pa_mpjpe(tr: Trajectories) -> Tensor:
    aligned = procrustes_align(tr.sim, tr.ref)
    return 1000.0 * _masked_mean(per_frame_error(aligned, tr.ref), tr.valid())


def velocity_error(tr: Trajectories) -> Tensor:
    dv = (tr.sim[1:] - tr.sim[:-1]) - (tr.ref[1:] - tr.ref[:-1])
    valid = tr.valid()
    return 1000.0 * _masked_mean(torch.linalg.vector_norm(dv, dim=-1).mean(-1), valid[1:] & valid[:-1])


def acceleration_error(tr: Trajectories) -> Tensor:
    def acc(p: Tensor) -> Tensor:
        return p[:-2] - 2 * p[1:-1] + p[2:]

    da = acc(tr.sim) - acc(tr.ref)
    valid = tr.valid()
    return 1000.0 * _masked_mean(torch.linalg.vector_norm(da, dim=-1).mean(-1), valid[2:] & valid[1:-1] & valid[:-2])


def rotation_error(tr: Trajectories) -> Tensor:
    """Mean over bodies of the geodesic angle between simulated and reference body orientations,
    degrees (``2 acos |<q_sim, q_ref>|``; sign-invariant). NaN when the rotations were not recorded."""
    if tr.sim_rot is None or tr.ref_rot is None:
        return torch.full((tr.sim.shape[1],), float("nan"), dtype=tr.sim.dtype, device=tr.sim.device)
    angle = torch.rad2deg(quat_angle_between(tr.sim_rot, tr.ref_rot)).mean(-1)
    return _masked_mean(angle, tr.valid())


def success(tr: Trajectories, threshold: float = 0.5, grace_frames: int = 0, reduce: str = "mean", bodies: Sequence[int] | None = None) -> Tensor:
    """(N,) 1.0 where the episode never exceeded ``threshold`` metres (mean or max over bodies; over
    the body indices ``bodies`` only when given, e.g. PHC's 20 evaluation bodies on smpl)."""
    err = torch.linalg.vector_norm(tr.sim - tr.ref, dim=-1)
    if bodies is not None:
        err = err[..., list(bodies)]
    per_frame = err.mean(-1) if reduce == "mean" else err.amax(-1)
    valid = tr.valid().clone()
    valid[:grace_frames] = False
    failed = ((per_frame > threshold) & valid).any(0)
    return (~failed).to(tr.sim.dtype)


# ----------------------------------------------------------------------- registered metrics
class _FnMetric(Metric):
    def __init__(self, name: str, unit: str, fn, **kwargs):
        self.name, self.unit, self._fn, self._kwargs = name, unit, fn, kwargs

    def __call__(self, tr: Trajectories) -> Tensor:  # type: ignore[override]
        return self._fn(tr, **self._kwargs)


def _success_metric(params: SuccessParams, reduce: str, bodies: Sequence[int] | None = None) -> Metric:
    name = "success" if reduce == "mean" else "success_linf"
    return _FnMetric(name, "fraction", success, threshold=params.threshold, grace_frames=params.grace_frames, reduce=reduce, bodies=bodies)


_FUNCTIONS = {
    "mpjpe_g": mpjpe_global,
    "mpjpe_l": mpjpe_local,
    "pa_mpjpe": pa_mpjpe,
    "vel_err": velocity_error,
    "acc_err": acceleration_error,
    "rot_err": rotation_error,
}
#: name -> (unit, function, description) of every built-in metric (units and descriptions: :mod:`mocap.metric_params`)
BUILTIN_METRICS = {name: (unit, _FUNCTIONS[name], description) for name, (unit, description) in BUILTIN_INFO.items()}


def make_metric(name: str) -> Metric:
    unit, fn, _ = BUILTIN_METRICS[name]
    return _FnMetric(name, unit, fn)


def default_metrics(success_bodies: Sequence[int] | None = None, threshold: float = 0.5) -> list[Metric]:
    """The built-in metrics plus ``success`` at ``threshold`` (over ``success_bodies`` when given)."""
    return [make_metric(n) for n in BUILTIN_METRICS] + [_success_metric(SuccessParams(threshold=threshold), "mean", success_bodies)]
