"""Height-field terrain for the MuJoCo simulator: generation, MJCF, and height queries in torch.

One terrain is shared by every env (all envs occupy the same world coordinates in separate
``MjData``). It is a square MuJoCo ``hfield`` of half extent ``size`` centred on the origin, sampled
every ``resolution`` metres; it replaces the floor plane and its geom is named ``floor`` (so
``ModelIndex.floor_geom`` and the contact sensors find "the ground" either way). Outside the square
there is no ground.

Kinds (heights in metres, always >= 0; a square of half side ``flat_radius`` around the origin
stays at height 0 so that envs can spawn there):

* ``flat``: 0 everywhere (a height field, e.g. to test the height-map observation pipeline);
* ``rough``: i.i.d. uniform noise in ``[0, amplitude]`` per grid point, optionally smoothed with a
  ``smoothing`` x ``smoothing`` box filter (cells);
* ``stairs``: flights along x on both sides of the spawn square: ``steps_per_flight`` steps of
  ``step_height`` up, each ``step_width`` deep, then as many down, repeated (a pyramid profile
  along ``|x|``; constant in y). Step edges are one grid cell wide slopes (height fields have no
  vertical faces);
* ``slopes``: a triangle wave along ``|x|``: up at gradient ``slope`` (rise / run) for
  ``slope_length`` metres, then down, repeated;
* ``obstacles``: ``obstacle_count`` axis-aligned blocks scattered uniformly over the square, each
  with sides ``U[obstacle_size]`` and height ``U[obstacle_height]`` (overlaps take the higher);
  discrete obstacles as in Rudin et al. 2021 (sides are one-cell slopes, as for stairs).

Height queries follow MuJoCo's own triangulation of the height field: grid cell ``(i, j)`` (row
``i`` along y, column ``j`` along x) is split along its diagonal from ``(i, j)`` to
``(i + 1, j + 1)``, and heights are linear on each of the two triangles. :meth:`Terrain.height_at`
therefore matches a downward ``mj_ray`` to floating-point precision (tested). Points outside the
square are clamped to its edge.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from mocap_sim_mujoco.mujoco_params import TerrainParams

if TYPE_CHECKING:  # pragma: no cover
    import mujoco

__all__ = ["Terrain", "TerrainParams", "TERRAIN_HFIELD"]

TERRAIN_HFIELD = "terrain"


class Terrain:
    """Heights of a :class:`TerrainParams` terrain on its grid, plus MJCF and torch queries.

    Attributes:
        params: the parameters.
        heights: (n, n) float64 numpy array, m; row ``i`` is ``y = -size + i * spacing``, column
            ``j`` is ``x = -size + j * spacing``.
        spacing: actual grid spacing (``2 size / (n - 1)``), m.
    """

    def __init__(self, params: TerrainParams, seed: int = 0):
        self.params = params
        n = max(2, int(round(2 * params.size / params.resolution)) + 1)
        self.n = n
        self.size = float(params.size)
        self.spacing = 2 * self.size / (n - 1)
        self.heights = self._generate(params, np.random.default_rng(params.seed if params.seed is not None else seed))
        self.max_height = float(self.heights.max())
        self._cache: dict[tuple[torch.dtype, torch.device], Tensor] = {}

    # ---------------------------------------------------------------------------- generation
    def _generate(self, p: TerrainParams, rng: np.random.Generator) -> np.ndarray:
        coords = -self.size + self.spacing * np.arange(self.n)
        x = np.broadcast_to(coords[None, :], (self.n, self.n))
        y = np.broadcast_to(coords[:, None], (self.n, self.n))
        ax = np.abs(x) - p.flat_radius  # distance past the spawn square along x
        if p.kind == "flat":
            h = np.zeros((self.n, self.n))
        elif p.kind == "rough":
            h = rng.uniform(0.0, p.amplitude, size=(self.n, self.n))
            if p.smoothing > 1:
                k = p.smoothing
                pad = np.pad(h, ((k // 2, k - 1 - k // 2),) * 2, mode="edge")
                c = np.cumsum(np.cumsum(np.pad(pad, ((1, 0), (1, 0))), 0), 1)
                h = (c[k:, k:] - c[:-k, k:] - c[k:, :-k] + c[:-k, :-k]) / (k * k)
        elif p.kind == "stairs":
            step = np.floor(np.maximum(ax, 0.0) / p.step_width)
            period = 2 * p.steps_per_flight
            phase = np.mod(step, period)
            h = p.step_height * np.where(phase <= p.steps_per_flight, phase, period - phase)
        elif p.kind == "slopes":
            d = np.maximum(ax, 0.0)
            phase = np.mod(d, 2 * p.slope_length)
            h = p.slope * np.where(phase <= p.slope_length, phase, 2 * p.slope_length - phase)
        elif p.kind == "obstacles":
            h = np.zeros((self.n, self.n))
            lo_s, hi_s = sorted(p.obstacle_size)
            lo_h, hi_h = sorted(p.obstacle_height)
            for _ in range(p.obstacle_count):
                cx, cy = rng.uniform(-self.size, self.size, 2)
                sx, sy = rng.uniform(lo_s, hi_s, 2)
                height = rng.uniform(lo_h, hi_h)
                block = (np.abs(x - cx) <= 0.5 * sx) & (np.abs(y - cy) <= 0.5 * sy)
                h = np.where(block, np.maximum(h, height), h)
        else:  # pragma: no cover - pydantic restricts kind
            raise ValueError(f"unknown terrain kind {p.kind!r}")
        flat = (np.abs(x) <= p.flat_radius) & (np.abs(y) <= p.flat_radius)
        h = np.where(flat, 0.0, h)
        return np.ascontiguousarray(np.maximum(h, 0.0), dtype=np.float64)

    # ---------------------------------------------------------------------------------- MJCF
    @property
    def elevation(self) -> float:
        """The hfield's elevation scale (``size[2]``): the maximum height, or 1 mm when flat."""
        return max(self.max_height, 1e-3)

    def asset_xml(self) -> str:
        """The ``<asset>`` element declaring the height field (data is written after compiling)."""
        s = f"{self.size:.9g}"
        return f'<asset><hfield name="{TERRAIN_HFIELD}" nrow="{self.n}" ncol="{self.n}" size="{s} {s} {self.elevation:.9g} 0.5"/></asset>'

    def geom_xml(self, name: str, friction: float) -> str:
        return (
            f'<geom name="{name}" type="hfield" hfield="{TERRAIN_HFIELD}" pos="0 0 0" material="grid" '
            f'contype="1" conaffinity="1" friction="{friction:.9g} 0.005 0.0001"/>'
        )

    def write_model(self, model: mujoco.MjModel) -> None:
        """Fill the compiled model's ``hfield_data`` (normalised to [0, 1] by the elevation)."""
        import mujoco

        hid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_HFIELD, TERRAIN_HFIELD)
        adr, nrow, ncol = model.hfield_adr[hid], model.hfield_nrow[hid], model.hfield_ncol[hid]
        model.hfield_data[adr : adr + nrow * ncol] = (self.heights / self.elevation).ravel().astype(np.float32)

    # ------------------------------------------------------------------------------- queries
    def heights_tensor(self, dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu") -> Tensor:
        key = (dtype, torch.device(device))
        if key not in self._cache:
            # the model stores float32 data times the elevation: query exactly what MuJoCo collides with
            data = (self.heights / self.elevation).astype(np.float32).astype(np.float64) * self.elevation
            self._cache[key] = torch.as_tensor(data, dtype=dtype, device=device)
        return self._cache[key]

    def height_at(self, xy: Tensor) -> Tensor:
        """Ground height (...) at world points ``xy`` (..., 2), MuJoCo's triangulation (module doc)."""
        dtype = xy.dtype if xy.is_floating_point() else torch.float32
        h = self.heights_tensor(dtype, xy.device)
        n = self.n
        u = ((xy[..., 0] + self.size) / self.spacing).clamp(0.0, n - 1.0)
        v = ((xy[..., 1] + self.size) / self.spacing).clamp(0.0, n - 1.0)
        j = torch.floor(u).long().clamp(max=n - 2)
        i = torch.floor(v).long().clamp(max=n - 2)
        fu, fv = u - j, v - i
        flat = h.reshape(-1)
        base = i * n + j
        h00, h01 = flat[base], flat[base + 1]
        h10, h11 = flat[base + n], flat[base + n + 1]
        lower = fu >= fv  # triangle (00, 01, 11)
        return torch.where(lower, h00 + fu * (h01 - h00) + fv * (h11 - h01), h00 + fv * (h10 - h00) + fu * (h11 - h10))

    def height_map(self, center: Tensor, heading: Tensor, shape: tuple[int, int] = (11, 11), spacing: float = 0.1) -> Tensor:
        """Heights (N, H, W) on an ``H x W`` grid centred on ``center`` (N, 2), turned by ``heading`` (N,).

        Grid point ``(a, b)`` sits at ``((a - (H - 1) / 2) s, (b - (W - 1) / 2) s)`` in the heading
        frame (first index along the heading direction, second to the left), ``s = spacing``.
        """
        return height_map(self.height_at, center, heading, shape, spacing)


def grid_offsets(shape: tuple[int, int], spacing: float, dtype: torch.dtype, device: torch.device) -> Tensor:
    """(H, W, 2) local grid offsets of :meth:`Terrain.height_map`."""
    H, W = shape
    a = (torch.arange(H, dtype=dtype, device=device) - (H - 1) / 2) * spacing
    b = (torch.arange(W, dtype=dtype, device=device) - (W - 1) / 2) * spacing
    return torch.stack(torch.meshgrid(a, b, indexing="ij"), dim=-1)


def height_map(height_at, center: Tensor, heading: Tensor, shape: tuple[int, int], spacing: float) -> Tensor:  # type: ignore[no-untyped-def]
    """Shared implementation of the local height map for any ``height_at`` function."""
    local = grid_offsets(shape, spacing, center.dtype, center.device)  # (H, W, 2)
    c, s = torch.cos(heading)[:, None, None], torch.sin(heading)[:, None, None]
    x = c * local[..., 0] - s * local[..., 1] + center[:, None, None, 0]
    y = s * local[..., 0] + c * local[..., 1] + center[:, None, None, 1]
    return height_at(torch.stack((x, y), dim=-1))
