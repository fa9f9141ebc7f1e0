"""Hard-negative clip sampling shared by every trainer that samples clips (PHC+, distillation)."""

from __future__ import annotations

import torch
from torch import Tensor


def failure_weights(fail_counts: Tensor, base: Tensor, floor: float) -> Tensor:
    """Clip sampling probabilities ``(1 − floor) f / Σf + floor · b`` (``b`` normalized; ``b`` when Σf = 0).

    Sums to 1; with ``floor = 0`` the support is exactly the clips that failed (PHC+); with
    ``floor > 0`` every clip with ``b_c > 0`` keeps at least ``floor · b_c``.
    """
    f = fail_counts.to(torch.float64).clamp_min(0.0)
    b = base.to(torch.float64)
    b = b / b.sum()
    total = f.sum()
    if float(total) <= 0.0:
        return b.clone()
    w = (1.0 - floor) * f / total + floor * b
    return w / w.sum()
