"""Offscreen video of humanoid poses: kinematic playback of clips and recordings of simulator rollouts.

:class:`VideoRecorder` compiles a render-only MuJoCo model from a skeleton (:func:`render_mjcf`):
the humanoid of :func:`~mocap_sim_mujoco.mjcf.build_mjcf`, a checkered floor with 0.5 m squares, a
sky gradient, a spot light that follows the humanoid and casts its shadow, and, with ``ghost=True``,
a second copy of the humanoid (every name prefixed ``ghost/``) with semi-transparent geoms that
collide with nothing, for showing the reference next to a simulated humanoid. The model is never
stepped: each :meth:`VideoRecorder.add_frame` writes the pose(s) into ``qpos``, runs
``mj_kinematics`` (plus ``mj_comPos``/``mj_camlight`` for the lights) and renders one frame with
:class:`mujoco.Renderer`. Markers (goals, targets) are spheres added to the scene. Poses are
``(root_pos (3,), root_rot (4,) wxyz, dof_pos (D,))`` triples, or anything :func:`as_pose` turns
into one (a :class:`~mocap.state.HumanoidState`/``MotionFrames`` row, a simulator ``qpos``).

Headless rendering: MuJoCo picks its OpenGL backend when ``mujoco`` is *imported*, from the
``MUJOCO_GL`` environment variable. This module sets ``MUJOCO_GL=egl`` (unless it is set already)
before importing mujoco, which only helps if nothing imported mujoco earlier; set ``MUJOCO_GL=egl``
(or ``osmesa``) in the environment, or before the first ``import mujoco``, to be safe. When mujoco
was imported earlier without ``MUJOCO_GL``, the recorder switches mujoco's context class to the
backend ``MUJOCO_GL`` now names before its first OpenGL call (best effort). If no context can be
created, :class:`RenderUnavailable` (a :class:`~mocap.cli.UserError`: one message, no traceback in
the CLI) says what to set and install.

Camera: ``"track"`` follows the root with an exponentially smoothed look-at point (time constant
``smoothing`` seconds) from a fixed azimuth/elevation; ``"fixed"`` looks at the first frame's root
and stays there. The default azimuth (90 degrees) looks along +y, so a humanoid walking along +x
moves from left to right.

Output: :meth:`VideoRecorder.save` writes ``.mp4`` (H.264 via imageio-ffmpeg, ``libx264``,
``yuv420p``; odd sizes are padded by one pixel) or ``.gif`` (looping). Frames are kept in memory
until then (about 0.9 MB per frame at 640x480).
"""

from __future__ import annotations

import math
import os

os.environ.setdefault("MUJOCO_GL", "egl")  # must happen before the first `import mujoco` of the process

import copy  # noqa: E402
import xml.etree.ElementTree as ET  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Sequence  # noqa: E402

import numpy as np  # noqa: E402

from mocap.errors import UserError  # noqa: E402


class RenderUnavailable(UserError):
    """No offscreen OpenGL context could be created (no EGL/OSMesa, or the wrong ``MUJOCO_GL``)."""


def _gl_hint() -> str:
    return (
        "set MUJOCO_GL=egl (or MUJOCO_GL=osmesa) in the environment before mujoco is imported, and install "
        "the system OpenGL library it needs (EGL: libegl1 / libegl-mesa0 or an NVIDIA driver; "
        "OSMesa: libosmesa6)"
    )


try:
    import mujoco  # noqa: E402
except Exception as _exc:  # noqa: BLE001 - mujoco loads the MUJOCO_GL backend at import; a missing library breaks it
    raise RenderUnavailable(f"cannot import mujoco with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}: {type(_exc).__name__}: {_exc}. {_gl_hint()}") from None

from mocap.humanoids.common import rest_root_height  # noqa: E402
from mocap.skeleton import Skeleton  # noqa: E402
from mocap_sim_mujoco.mjcf import FLOOR_GEOM, ROOT_JOINT, build_mjcf, model_index  # noqa: E402

__all__ = ["VideoRecorder", "RenderUnavailable", "render_mjcf", "as_pose", "GHOST_PREFIX", "VIDEO_SUFFIXES"]

GHOST_PREFIX = "ghost/"
GHOST_GROUP = 1  # geom group of the ghost's geoms (hidden on frames without a ghost pose)
VIDEO_SUFFIXES = (".mp4", ".gif")
DEFAULT_GHOST_RGBA = (0.35, 0.65, 1.0, 0.35)
DEFAULT_MARKER_RGBA = (0.95, 0.15, 0.15, 1.0)

Pose = tuple[np.ndarray, np.ndarray, np.ndarray]


# --------------------------------------------------------------------------------------- model
def _floor_and_assets(floor_size: float) -> tuple[str, str]:
    worldbody = (
        f'    <geom name="{FLOOR_GEOM}" type="plane" size="{floor_size:g} {floor_size:g} 0.1" material="render_grid" rgba="1 1 1 1" '
        'contype="1" conaffinity="1"/>'
    )
    # texuniform: texrepeat counts checker squares per metre (measured: "1 1" gives 1 m squares),
    # so "2 2" gives 0.5 m squares.
    assets = (
        "  <asset>\n"
        '    <texture name="render_grid" type="2d" builtin="checker" rgb1="0.82 0.84 0.86" rgb2="0.58 0.62 0.68" '
        'width="512" height="512"/>\n'
        '    <material name="render_grid" texture="render_grid" texrepeat="2 2" texuniform="true" specular="0.1"/>\n'
        '    <texture name="render_sky" type="skybox" builtin="gradient" rgb1="0.62 0.74 0.88" rgb2="0.95 0.97 1.0" '
        'width="64" height="512"/>\n'
        "  </asset>\n"
        '  <visual><quality shadowsize="4096"/><map znear="0.02" zfar="60"/></visual>\n'
        # the model's extent scales near/far planes and shadow depth ranges: a humanoid-sized value
        # (the computed one is the floor's) keeps the shadow map's depth precise (no speckles)
        '  <statistic extent="2"/>'
    )
    return worldbody, assets


# A spot light that follows the humanoid (``trackcom``: fixed world offset from its centre of mass)
# and casts its shadow on the floor; the world lights of build_mjcf then cast none (the shadow map of
# a directional light spans the whole 100 m floor, too coarse to show anything).
_KEY_LIGHT = dict(
    name="render_key",
    mode="trackcom",
    pos="-1.5 -2.5 4.5",
    dir="0.3 0.5 -0.8",
    diffuse="0.45 0.45 0.45",
    specular="0.15 0.15 0.15",
    cutoff="50",
    exponent="2",
    castshadow="true",
)


def _ghost_body(body: ET.Element, rgba: Sequence[float]) -> ET.Element:
    """A copy of the humanoid's root ``body`` renamed ``ghost/...``, collision-free, ``rgba``, group 1."""
    ghost = copy.deepcopy(body)
    color = " ".join(f"{float(c):g}" for c in rgba)
    for el in ghost.iter():
        if "name" in el.attrib:
            el.set("name", GHOST_PREFIX + el.get("name", ""))
        if el.tag == "geom":
            el.set("contype", "0")
            el.set("conaffinity", "0")
            el.set("rgba", color)
            el.set("group", str(GHOST_GROUP))
    return ghost


def render_mjcf(
    skeleton: Skeleton,
    *,
    ghost: bool = False,
    ghost_rgba: Sequence[float] = DEFAULT_GHOST_RGBA,
    floor_size: float = 50.0,
) -> str:
    """MJCF of the render model: :func:`build_mjcf`'s humanoid, a checkered floor, a key light
    following the humanoid and, with ``ghost``, a second humanoid (module doc)."""
    floor, assets = _floor_and_assets(floor_size)
    root = ET.fromstring(build_mjcf(skeleton, floor=False, extra_worldbody=floor, extra_xml=assets))
    worldbody = root.find("worldbody")
    body = worldbody.find("body") if worldbody is not None else None
    if worldbody is None or body is None:
        raise ValueError("generated MJCF has no humanoid body")
    for light in worldbody.findall("light"):
        light.set("castshadow", "false")
        light.set("diffuse", "0.35 0.35 0.35")
        light.set("specular", "0.1 0.1 0.1")
    for headlight in root.iter("headlight"):
        headlight.attrib.update(ambient="0.25 0.25 0.25", diffuse="0.3 0.3 0.3", specular="0.05 0.05 0.05")
    key = ET.Element("light", _KEY_LIGHT)
    body.insert(0, key)
    if ghost:
        g = _ghost_body(body, ghost_rgba)
        g.remove(g.find("light"))  # type: ignore[arg-type]
        worldbody.append(g)
    return ET.tostring(root, encoding="unicode")


# ---------------------------------------------------------------------------------------- poses
def _np(x: Any) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def as_pose(x: Any, *, row: int = 0, num_dofs: int | None = None, index: Any = None) -> Pose:
    """``(root_pos (3,), root_rot (4,) wxyz, dof_pos (D,))`` float64 arrays from a pose-like ``x``.

    Accepted: a ``(root_pos, root_rot, dof_pos)`` triple; a :class:`~mocap.state.HumanoidState` (or
    ``MotionFrames``/``SimState``), row ``row`` when batched; a MuJoCo ``qpos`` vector, laid out by
    ``index`` (a :class:`~mocap_sim_mujoco.mjcf.ModelIndex` of the simulator's model) or, without
    one, as ``[root_pos, root_rot, dof_pos]`` (``7 + D`` numbers, the layout of generated models).
    """
    if hasattr(x, "root_pos") and hasattr(x, "root_rot") and hasattr(x, "dof_pos"):
        rp, rr, dp = _np(x.root_pos), _np(x.root_rot), _np(x.dof_pos)
        if rp.ndim == 2:
            rp, rr, dp = rp[row], rr[row], dp[row]
        return rp.reshape(3), rr.reshape(4), dp.reshape(-1)
    if isinstance(x, (tuple, list)) and len(x) == 3:
        rp, rr, dp = (_np(v) for v in x)
        return rp.reshape(3), rr.reshape(4), dp.reshape(-1)
    q = _np(x)
    if q.ndim == 2:
        q = q[row]
    if q.ndim != 1:
        raise ValueError(f"cannot read a pose from an array of shape {q.shape}")
    if index is not None:
        a = int(index.root_qpos)
        return q[a : a + 3].copy(), q[a + 3 : a + 7].copy(), q[np.asarray(index.dof_qpos)].copy()
    if num_dofs is not None and q.shape[0] != 7 + num_dofs:
        raise ValueError(f"qpos has {q.shape[0]} numbers; expected 7 + {num_dofs} (pass index= for other layouts)")
    return q[:3].copy(), q[3:7].copy(), q[7:].copy()


# ------------------------------------------------------------------------------------- renderer
def _align_gl_backend() -> None:
    """If mujoco was imported before ``MUJOCO_GL`` was set, use the backend it names now (best effort).

    Only switches from the default (GLFW) to ``egl``/``osmesa``, and must run before any OpenGL call:
    a failed GLFW attempt can leave the process unable to create another context.
    """
    wanted = os.environ.get("MUJOCO_GL", "").lower().strip()
    if wanted not in ("egl", "osmesa"):
        return
    try:
        from mujoco.rendering.classic import gl_context  # type: ignore[import-not-found]
    except ImportError:
        return
    chosen = str(getattr(gl_context, "_MUJOCO_GL", wanted)).lower().strip()
    if chosen == wanted:
        return
    try:
        if wanted == "egl":
            from mujoco.egl import GLContext  # type: ignore[import-not-found]
        else:
            from mujoco.osmesa import GLContext  # type: ignore[import-not-found]
    except Exception:  # noqa: BLE001 - the Renderer attempt below reports the failure
        return
    gl_context.GLContext = GLContext
    gl_context._MUJOCO_GL = wanted


_gl_failure: str | None = None  # set by the first failed context: a second attempt can abort the process


def _make_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    global _gl_failure
    if _gl_failure is not None:
        raise RenderUnavailable(_gl_failure)
    _align_gl_backend()
    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as exc:  # noqa: BLE001 - every backend fails differently (ImportError, FatalError, ...)
        backend = os.environ.get("MUJOCO_GL") or "(unset: glfw, needs a display)"
        detail = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        _gl_failure = f"cannot create an offscreen OpenGL context for rendering (MUJOCO_GL={backend}): {detail}. {_gl_hint()}"
        raise RenderUnavailable(_gl_failure) from None


class VideoRecorder:
    """Renders humanoid poses into frames and saves them as MP4 or GIF (module doc).

    Args:
        skeleton: the humanoid.
        width, height: frame size, pixels.
        fps: frame rate of the saved video (and of the camera smoothing), Hz.
        ghost: add a second, semi-transparent, collision-free humanoid for a reference pose.
        camera: ``"track"`` (follow the root, smoothed) or ``"fixed"`` (look at the first frame's root).
        distance: camera distance, m (default: 4.5 x the rest pelvis height, 4 m for ``amp``).
        azimuth, elevation: camera angles, degrees (90 / -12: from the side, slightly above).
        smoothing: time constant of the tracking camera, s (0: rigidly attached to the root).
        ghost_rgba: colour of the ghost.
        marker_radius, marker_rgba: default size and colour of marker spheres.

    Use as a context manager (or call :meth:`close`) to free the OpenGL context early.
    """

    def __init__(
        self,
        skeleton: Skeleton,
        *,
        width: int = 640,
        height: int = 480,
        fps: float = 30,
        ghost: bool = False,
        camera: str = "track",
        distance: float | None = None,
        azimuth: float = 90.0,
        elevation: float = -12.0,
        smoothing: float = 0.3,
        ghost_rgba: Sequence[float] = DEFAULT_GHOST_RGBA,
        marker_radius: float = 0.06,
        marker_rgba: Sequence[float] = DEFAULT_MARKER_RGBA,
    ):
        if camera not in ("track", "fixed"):
            raise ValueError(f"camera must be 'track' or 'fixed', got {camera!r}")
        if not (16 <= int(width) <= 8192 and 16 <= int(height) <= 8192):
            raise ValueError(f"frame size {width}x{height} out of range (16..8192 pixels)")
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps}")
        self.skeleton = skeleton
        self.width, self.height, self.fps = int(width), int(height), float(fps)
        self.ghost = bool(ghost)
        self.camera_mode = camera
        self.smoothing = float(smoothing)
        self.marker_radius = float(marker_radius)
        self.marker_rgba = np.asarray(marker_rgba, dtype=np.float32).reshape(4)
        self.frames: list[np.ndarray] = []

        self.xml = render_mjcf(skeleton, ghost=self.ghost, ghost_rgba=ghost_rgba)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.model.vis.global_.offwidth = max(self.width, int(self.model.vis.global_.offwidth))
        self.model.vis.global_.offheight = max(self.height, int(self.model.vis.global_.offheight))
        self.data = mujoco.MjData(self.model)
        self.index = model_index(self.model, skeleton)
        if self.ghost:
            jid = lambda n: mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, GHOST_PREFIX + n)  # noqa: E731
            self._ghost_root = int(self.model.jnt_qposadr[jid(ROOT_JOINT)])
            self._ghost_dofs = np.array([self.model.jnt_qposadr[jid(n)] for n in skeleton.dof_names], dtype=np.int64)

        self._renderer: mujoco.Renderer | None = _make_renderer(self.model, self.height, self.width)
        self._option = mujoco.MjvOption()
        self.cam = mujoco.MjvCamera()
        self.cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        self.cam.distance = float(distance) if distance is not None else 4.5 * rest_root_height(skeleton)
        self.cam.azimuth = float(azimuth)
        self.cam.elevation = float(elevation)
        self._lookat: np.ndarray | None = None

    # ---------------------------------------------------------------------------------- frames
    @property
    def num_frames(self) -> int:
        return len(self.frames)

    def _set_pose(self, pose: Pose, root: int, dofs: np.ndarray) -> None:
        rp, rr, dp = pose
        if dp.shape[0] != len(dofs):
            raise ValueError(f"dof_pos has {dp.shape[0]} values; skeleton {self.skeleton.name!r} has {len(dofs)} DoFs")
        n = float(np.linalg.norm(rr))
        self.data.qpos[root : root + 3] = rp
        self.data.qpos[root + 3 : root + 7] = rr / n if n > 0 else (1.0, 0.0, 0.0, 0.0)
        self.data.qpos[dofs] = dp

    def _update_camera(self, root_pos: np.ndarray) -> None:
        if self._lookat is None:
            self._lookat = root_pos.copy()
        elif self.camera_mode == "track":
            a = 1.0 if self.smoothing <= 0 else 1.0 - math.exp(-1.0 / (self.fps * self.smoothing))
            self._lookat += a * (root_pos - self._lookat)
        self.cam.lookat[:] = self._lookat

    def render(self, root_pos: Any, root_rot: Any = None, dof_pos: Any = None, *, ghost: Any = None, markers: Any = None) -> np.ndarray:
        """One frame (H, W, 3) uint8 of the pose, without recording it (see :meth:`add_frame`)."""
        if self._renderer is None:
            raise RuntimeError("the recorder is closed")
        nd = self.skeleton.num_dofs
        if root_rot is None and dof_pos is None:
            pose = as_pose(root_pos, num_dofs=nd)
        elif root_rot is None or dof_pos is None:
            raise ValueError("pass root_pos, root_rot and dof_pos together, or one pose-like (state row, qpos) alone")
        else:
            pose = as_pose((root_pos, root_rot, dof_pos))
        self._set_pose(pose, self.index.root_qpos, self.index.dof_qpos)
        self._option.geomgroup[GHOST_GROUP] = 0
        if ghost is not None:
            if not self.ghost:
                raise ValueError("a ghost pose needs VideoRecorder(..., ghost=True)")
            self._set_pose(as_pose(ghost, num_dofs=nd), self._ghost_root, self._ghost_dofs)
            self._option.geomgroup[GHOST_GROUP] = 1
        # bodies and geoms, then the lights (mj_camlight; the key light tracks the subtree centre of mass)
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)
        self._update_camera(pose[0])
        r = self._renderer
        r.update_scene(self.data, camera=self.cam, scene_option=self._option)
        if markers is not None:
            self._add_markers(r.scene, markers)
        return r.render().copy()

    def add_frame(self, root_pos: Any, root_rot: Any = None, dof_pos: Any = None, *, ghost: Any = None, markers: Any = None) -> np.ndarray:
        """Render and record one frame; returns it, (H, W, 3) uint8.

        Args:
            root_pos, root_rot, dof_pos: the humanoid's pose: (3,) m, (4,) wxyz, (D,) rad (numpy or
                torch). Or pass one pose-like as ``root_pos`` alone (a state row, a ``qpos``, a
                triple; see :func:`as_pose`).
            ghost: the ghost's pose (any pose-like), drawn only when given (needs ``ghost=True``).
            markers: (M, 3) points drawn as spheres (e.g. goals), or a list of ``(pos, rgba)`` or
                ``(pos, rgba, radius)`` tuples for individual colours/sizes.
        """
        frame = self.render(root_pos, root_rot, dof_pos, ghost=ghost, markers=markers)
        self.frames.append(frame)
        return frame

    def _add_markers(self, scene: mujoco.MjvScene, markers: Any) -> None:
        items: list[tuple[np.ndarray, np.ndarray, float]] = []
        first = markers[0] if isinstance(markers, (list, tuple)) and markers else None
        if isinstance(first, (list, tuple)) and len(first) in (2, 3) and np.ndim(first[0]) == 1:  # (pos, rgba[, radius])
            for m in markers:
                rgba = np.asarray(m[1], dtype=np.float32).reshape(4)
                items.append((_np(m[0]).reshape(3), rgba, float(m[2]) if len(m) == 3 else self.marker_radius))
        else:
            pts = _np(markers).reshape(-1, 3)
            items = [(p, self.marker_rgba, self.marker_radius) for p in pts]
        eye = np.eye(3).reshape(-1)
        for pos, rgba, radius in items:
            if scene.ngeom >= scene.maxgeom:
                break
            mujoco.mjv_initGeom(scene.geoms[scene.ngeom], int(mujoco.mjtGeom.mjGEOM_SPHERE), np.array([radius, 0.0, 0.0]), pos, eye, rgba)
            scene.ngeom += 1

    def clear(self) -> None:
        """Drop the recorded frames and reset the camera."""
        self.frames.clear()
        self._lookat = None

    # ------------------------------------------------------------------------------------ save
    def save(self, path: str | Path) -> Path:
        """Write the recorded frames to ``path``: ``.mp4`` (H.264, yuv420p) or ``.gif``; returns the path."""
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in VIDEO_SUFFIXES:
            raise ValueError(f"unsupported video file {path.name!r}: use one of {', '.join(VIDEO_SUFFIXES)}")
        if not self.frames:
            raise ValueError("no frames recorded")
        path.parent.mkdir(parents=True, exist_ok=True)
        if suffix == ".gif":
            import imageio.v3 as iio

            iio.imwrite(path, np.stack(self.frames), extension=".gif", duration=1000.0 / self.fps, loop=0)
            return path
        import imageio.v2 as iio2

        pad_h, pad_w = self.height % 2, self.width % 2
        writer = iio2.get_writer(
            str(path),
            format="FFMPEG",
            mode="I",
            fps=self.fps,
            codec="libx264",
            pixelformat="yuv420p",
            macro_block_size=1,
            quality=8,
            ffmpeg_log_level="error",
        )
        try:
            for f in self.frames:
                writer.append_data(np.pad(f, ((0, pad_h), (0, pad_w), (0, 0)), mode="edge") if pad_h or pad_w else f)
        finally:
            writer.close()
        return path

    def close(self) -> None:
        """Free the OpenGL context (the recorded frames stay available)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> "VideoRecorder":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass
