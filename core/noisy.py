"""Imitation from noisy references (PHC's avatar use case) and ``mocap eval-noisy``.

PHC drives avatars from poses a video estimator produces; those poses jitter, and frames go
missing. This module makes such a stream from clean clips with synthetic estimator noise and
evaluates an imitator that sees only the noisy stream, measured against the *clean* clip — the
structure of PHC's noisy-input table (success and MPJPE per input quality), with synthetic noise
at several levels instead of one estimator's output.

Noise model (:func:`noisy_clip`), per source frame of a clip, independently:

* **joint-rotation jitter**: every non-root local rotation is multiplied on the left by
  ``exp(r)``, ``r ~ N(0, sigma^2 I_3)`` (a rotation vector, ``sigma = joint_deg`` in radians); the
  motion library then projects onto each joint's DoFs as for any clip;
* **root jitter**: the root orientation likewise (``root_deg``) and the root position by
  ``N(0, root_m^2 I_3)`` metres;
* **dropped frames**: with probability ``drop_prob`` a frame is lost and the stream repeats the
  previous frame it delivered (a lost frame reaches the consumer as a repeated one, as a video
  pipeline holding its last estimate does); frame 0 is always delivered.

Reference velocities are whatever the motion library derives from the noisy frames (finite
differences), which is what a consumer of an estimator's stream gets. A looping clip keeps its
clean cycle offset (the noisy last frame is the noisy first frame moved by the clean offset), so
the ``--loop`` protocol does not drift because of one noisy frame.

Consumer-side smoothing (``smooth``, off by default; not in PHC): a causal exponential filter of
the delivered stream, as a live avatar would apply (:func:`smooth_clip`): ``p_k = p_(k-1) + a (x_k -
p_(k-1))`` for the root position and ``q_k = slerp(q_(k-1), x_k, a)`` for every rotation, ``a`` in
(0, 1] (1: no smoothing). It trades jitter for a lag of about ``(1 - a) / a`` frames.

Consumer-side velocities (``velocities``, default: the policy's own motion settings): the reference
velocities the policy observes are derived from the delivered frames by the motion library, with
forward differences or PHC's code's Gaussian-smoothed central differences
(:class:`~mocap.motion.sources.ReferenceVelocityParams`). Forward differences turn 1 cm of root
jitter at 30 fps into ~0.4 m/s of velocity noise per axis; ``central_smoothed`` reads about 3 ``velocity_sigma``
frames ahead of each frame (offline clips have them; a live stream pays them as latency).

Protocol (:func:`evaluate_noisy`): for each level, the same imitation protocol as ``mocap eval``
(:func:`mocap.imitation_eval.evaluate_imitator`: every clip once from its first frame, deterministic
actions, failure when the mean body error exceeds 0.5 m) with the policy observing the noisy
clip and every metric (success, MPJPE-g, MPJPE-l, PA-MPJPE, velocity and acceleration errors)
computed against the clean clip. The humanoid starts in the clean first frame, so a level's
numbers measure what the noisy stream does to tracking, not a bad initial state. Level 0 is the
clean reference, i.e. ``mocap eval``'s numbers.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any, Optional

import numpy as np
import typer
from pydantic import BaseModel, ConfigDict, Field

from mocap.hooks import hookimpl
from mocap.motion.sources import VelocityMode

# torch is imported by the functions that use it: loading the plugin (``mocap --help``) imports no torch

PROTOCOL = "mocap-noisy-reference-v1"


class NoiseLevel(BaseModel):
    """One input quality: standard deviations of the jitter and the share of dropped frames."""

    model_config = ConfigDict(extra="forbid")
    joint_deg: float = Field(0.0, ge=0, description="joint-rotation jitter: std of each rotation-vector component, degrees")
    root_deg: float = Field(0.0, ge=0, description="root-orientation jitter, degrees (same form)")
    root_m: float = Field(0.0, ge=0, description="root-position jitter: std per axis, metres")
    drop_prob: float = Field(0.0, ge=0, lt=1, description="probability that a frame is lost (the previous one repeats)")

    @property
    def clean(self) -> bool:
        return self.joint_deg == 0 and self.root_deg == 0 and self.root_m == 0 and self.drop_prob == 0


#: The default levels of ``mocap eval-noisy`` (level 0 is the clean clip). Level 3 is about a
#: monocular video estimator's error scale (joint rotations off by ~10 degrees, root by ~5 cm).
DEFAULT_LEVELS: tuple[NoiseLevel, ...] = (
    NoiseLevel(),
    NoiseLevel(joint_deg=2.0, root_deg=1.0, root_m=0.01, drop_prob=0.02),
    NoiseLevel(joint_deg=5.0, root_deg=2.0, root_m=0.02, drop_prob=0.05),
    NoiseLevel(joint_deg=10.0, root_deg=4.0, root_m=0.05, drop_prob=0.10),
)


def _jitter(q: np.ndarray, deg: float, rng: np.random.Generator) -> np.ndarray:
    if deg == 0:
        return q
    import torch

    from mocap.rotations import quat_from_rotvec, quat_mul, quat_normalize

    rv = rng.normal(0.0, math.radians(deg), size=q.shape[:-1] + (3,))
    out = quat_mul(quat_from_rotvec(torch.from_numpy(rv)), torch.from_numpy(q).to(torch.float64))
    return quat_normalize(out).numpy()


def delivered_frames(num_frames: int, drop_prob: float, rng: np.random.Generator) -> np.ndarray:
    """Index of the source frame the stream shows at each frame: itself, or when it is lost, the
    previous delivered one (frame 0 is always delivered)."""
    lost = rng.random(num_frames) < drop_prob
    lost[0] = False
    idx = np.arange(num_frames)
    idx[lost] = 0
    return np.maximum.accumulate(idx)


def noisy_clip(clip: Any, level: NoiseLevel, rng: np.random.Generator) -> Any:
    """``clip`` as a noisy estimator would deliver it (module docstring); the clean clip for level 0."""
    if level.clean:
        return clip
    T = clip.num_frames
    root_pos = clip.root_pos + rng.normal(0.0, level.root_m, size=clip.root_pos.shape) if level.root_m else clip.root_pos.copy()
    root_rot = _jitter(clip.root_rot, level.root_deg, rng)
    joint_rot = _jitter(clip.joint_rot, level.joint_deg, rng)
    if clip.loop:  # keep the clean cycle offset (module docstring)
        offset = clip.root_pos[-1] - clip.root_pos[0]
        root_pos[-1] = root_pos[0] + offset
        root_rot[-1], joint_rot[-1] = root_rot[0], joint_rot[0]
    keep = delivered_frames(T, level.drop_prob, rng)
    if clip.loop:
        keep[-1] = T - 1  # the wrap frame stays the next cycle's first frame
    return replace(clip, root_pos=root_pos[keep], root_rot=root_rot[keep], joint_rot=joint_rot[keep])


def smooth_clip(clip: Any, alpha: float) -> Any:
    """Causal exponential smoothing of ``clip`` (module docstring); ``alpha = 1`` returns it unchanged.

    A looping clip's last frame stays its first frame moved by the cycle offset (the wrap)."""
    if not 0 < alpha <= 1:
        raise ValueError(f"smoothing alpha must be in (0, 1], got {alpha:g}")
    if alpha == 1:
        return clip
    import torch

    from mocap.rotations import quat_slerp

    pos = clip.root_pos.copy()
    root = torch.from_numpy(clip.root_rot).to(torch.float64).clone()
    joints = torch.from_numpy(clip.joint_rot).to(torch.float64).clone()
    for k in range(1, clip.num_frames):
        pos[k] = pos[k - 1] + alpha * (clip.root_pos[k] - pos[k - 1])
        root[k] = quat_slerp(root[k - 1], root[k], alpha)
        joints[k] = quat_slerp(joints[k - 1], joints[k], alpha)
    root_rot, joint_rot = root.numpy(), joints.numpy()
    if clip.loop:
        pos[-1] = pos[0] + (clip.root_pos[-1] - clip.root_pos[0])
        root_rot[-1], joint_rot[-1] = root_rot[0], joint_rot[0]
    return replace(clip, root_pos=pos, root_rot=root_rot, joint_rot=joint_rot)


def noisy_library(
    library: Any, level: NoiseLevel, seed: int, smooth: float = 1.0, velocities: VelocityMode | None = None, velocity_sigma: float | None = None
) -> Any:
    """A :class:`~mocap.motion.library.MotionLibrary` of the noisy versions of ``library``'s clips
    (same order, device, dtype and interpolation), smoothed by the consumer's filter when ``smooth``
    is below 1; ``seed`` fixes the noise. ``velocities`` / ``velocity_sigma``: how its velocities are
    derived (None: as ``library``'s)."""
    from mocap.motion.library import MotionLibrary

    rng = np.random.default_rng(seed)
    clips = [smooth_clip(noisy_clip(c, level, rng), smooth) for c in library.clips]
    rule: VelocityMode = velocities if velocities is not None else library.velocities
    return MotionLibrary(
        clips, library.skeleton, device=library.device, dtype=library.dtype,
        loop_heading=library.loop_heading, body_interp=library.body_interp,
        velocities=rule,
        velocity_sigma=velocity_sigma if velocity_sigma is not None else library.velocity_sigma,
    )  # fmt: skip


def evaluate_noisy(
    policy: Any,
    library: Any,
    make_sim: Any,
    levels: list[NoiseLevel] | tuple[NoiseLevel, ...] = DEFAULT_LEVELS,
    *,
    seed: int = 0,
    num_envs: int = 64,
    horizon: float | None = None,
    smooth: float = 1.0,
    velocities: VelocityMode | None = None,
    velocity_sigma: float | None = None,
    console: Any = None,
) -> dict[str, Any]:
    """The protocol of the module docstring: one imitation-evaluation table per level.

    ``policy``: an imitator, or a function ``library -> imitator`` for a policy bound to the clips
    it tracks (VMP's tracker reads its windows from a library; it gets the noisy one).
    """
    from mocap.evaluation import ImitationEvalParams
    from mocap.imitation_eval import evaluate_imitator
    from mocap.interfaces import Imitator
    from mocap.metrics import default_metrics

    if not levels:
        raise ValueError("evaluate_noisy needs at least one noise level")
    params = ImitationEvalParams(num_envs=num_envs, horizon=horizon, video=False)
    rows = []
    for i, level in enumerate(levels):
        index = DEFAULT_LEVELS.index(level) if level in DEFAULT_LEVELS else len(DEFAULT_LEVELS) + i
        same = level.clean and smooth == 1 and velocities is None and velocity_sigma is None
        observed = None if same else noisy_library(library, level, seed + index, smooth, velocities, velocity_sigma)
        actor = policy if isinstance(policy, Imitator) else policy(observed if observed is not None else library)
        table = evaluate_imitator(actor, library, make_sim, params, default_metrics(), console, observed=observed)
        rows.append(
            {
                "level": index if level in DEFAULT_LEVELS else f"custom {i}",
                "noise": level.model_dump(),
                "aggregate": table["aggregate"],
                "clips": table["clips"],
            }
        )
    return {
        "protocol": PROTOCOL,
        "imitation_protocol": table["protocol"],
        "seed": seed,
        "smooth": smooth,
        "velocities": velocities or library.velocities,
        "velocity_sigma": velocity_sigma if velocity_sigma is not None else library.velocity_sigma,
        "horizon": table["horizon"],
        "units": table["units"],
        "levels": rows,
    }


def render_noisy(result: dict[str, Any]) -> Any:
    """A rich table: one row per level (noise, success, MPJPE-g/-l, PA-MPJPE, acceleration error)."""
    from rich.table import Table

    filt = f"; consumer smoothing a = {result['smooth']:g}" if result.get("smooth", 1.0) != 1 else ""
    if result.get("velocities", "forward") != "forward":
        filt += f"; velocities {result['velocities']} (sigma {result.get('velocity_sigma', 2.0):g} frames)"
    out = Table(title=f"imitation from noisy references ({result['horizon']}; errors against the clean clip{filt})")
    for col in ("level", "joint °", "root °", "root cm", "dropped", "success", "MPJPE-g mm", "MPJPE-l mm", "PA-MPJPE mm", "acc err"):
        out.add_column(col, justify="right")
    for row in result["levels"]:
        n, a = row["noise"], row["aggregate"]

        def f(key: str, a: dict[str, Any] = a) -> str:
            v = a.get(key)
            return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.1f}"

        out.add_row(
            str(row["level"]), f"{n['joint_deg']:g}", f"{n['root_deg']:g}", f"{100 * n['root_m']:g}", f"{100 * n['drop_prob']:g}%",
            f"{a['succeeded']}/{a['total']}", f("mpjpe_g"), f("mpjpe_l"), f("pa_mpjpe"), f("acc_err"),
        )  # fmt: skip
    return out


def parse_levels(text: str) -> list[NoiseLevel]:
    """``"0,1,3"`` (indices into :data:`DEFAULT_LEVELS`) or ``"joint_deg:root_deg:root_m:drop_prob;..."``."""
    from mocap.errors import UserError

    text = text.strip()
    try:
        if ":" not in text:
            out = []
            for part in text.split(","):
                k = int(part)
                if not 0 <= k < len(DEFAULT_LEVELS):
                    raise UserError(f"--levels: level {k} does not exist (0..{len(DEFAULT_LEVELS) - 1})")
                out.append(DEFAULT_LEVELS[k])
            return out
        levels = []
        for part in text.split(";"):
            vals = [float(v) for v in part.split(":")]
            if len(vals) != 4:
                raise UserError(f"--levels: {part!r} needs 4 numbers joint_deg:root_deg:root_m:drop_prob")
            levels.append(NoiseLevel(joint_deg=vals[0], root_deg=vals[1], root_m=vals[2], drop_prob=vals[3]))
        return levels
    except UserError:
        raise
    except Exception as exc:  # noqa: BLE001 - ValueError from int/float, pydantic's ValidationError
        raise UserError(f"--levels {text!r}: {str(exc).splitlines()[0]}") from None


@hookimpl
def register_commands(app: Any) -> None:
    @app.command("eval-noisy")
    def eval_noisy_command(
        target: Annotated[Path, typer.Argument(help="what `mocap eval` accepts: a checkpoint, checkpoints/<name>, a run directory or a spec")],
        levels: Annotated[
            str, typer.Option("--levels", help="noise levels: indices of the default levels ('0,1,2,3') or 'joint_deg:root_deg:root_m:drop_prob;...'")
        ] = "0,1,2,3",
        seed: Annotated[int, typer.Option("--seed", help="seed of the noise (default level k uses seed + k)")] = 0,
        loop: Annotated[Optional[float], typer.Option("--loop", help="looping clips keep cycling for this many seconds")] = None,
        smooth: Annotated[float, typer.Option("--smooth", help="causal exponential smoothing of the stream, a in (0, 1] (1: none)")] = 1.0,
        velocities: Annotated[
            Optional[str],
            typer.Option("--velocities", help="how the stream's reference velocities are derived: forward or central_smoothed (default: the policy's)"),
        ] = None,
        velocity_sigma: Annotated[Optional[float], typer.Option("--velocity-sigma", help="frames, the Gaussian of central_smoothed")] = None,
        num_envs: Annotated[int, typer.Option(help="clips simulated in parallel")] = 64,
        json_out: Annotated[Optional[Path], typer.Option("--json", help="write the result as JSON")] = None,
        imitator_only: Annotated[bool, typer.Option("--imitator-only", help="for a latent space: evaluate the imitator it was distilled from")] = False,
    ) -> None:
        """Imitation from references with synthetic estimator noise (jitter, dropped frames), measured against the clean clips."""
        import json
        import sys

        from rich.console import Console

        from mocap.eval_targets import build_evaluation_target, load_evaluation_target
        from mocap.paths import check_output_file, write_output_text
        from mocap.plugins import get_plugins

        from mocap.errors import UserError

        chosen = parse_levels(levels)
        if not 0 < smooth <= 1:
            raise UserError(f"--smooth must be in (0, 1], got {smooth:g}")
        if velocities is not None and velocities not in ("forward", "central_smoothed"):
            raise UserError(f"--velocities must be forward or central_smoothed, not {velocities!r}")
        rule: VelocityMode | None = "forward" if velocities == "forward" else "central_smoothed" if velocities else None
        if velocity_sigma is not None and not 0 < velocity_sigma <= 100:
            raise UserError(f"--velocity-sigma must be in (0, 100] frames, got {velocity_sigma:g}")
        if json_out is not None:  # before the rollouts
            check_output_file(json_out, "--json")
        console = Console(stderr=True)
        plugins = get_plugins()
        info = load_evaluation_target(target, plugins)
        loaded = build_evaluation_target(info, plugins, use_latent=not imitator_only)
        policy: Any = loaded.policy
        if info.spec.imitator is None and loaded.latent is not None:
            probe = loaded.make_sim(1)
            dt = float(probe.dt)
            probe.close()
            policy = lambda lib: loaded.latent.as_imitator(lib, dt=dt)  # noqa: E731 - bound to the clips it tracks
        result = evaluate_noisy(
            policy, loaded.library, loaded.make_sim, chosen, seed=seed, num_envs=num_envs, horizon=loop, smooth=smooth,
            velocities=rule, velocity_sigma=velocity_sigma, console=console,
        )  # fmt: skip
        result["evaluated"] = str(target)
        stdout = Console(width=None if sys.stdout.isatty() else 160)
        stdout.print(render_noisy(result))
        if json_out is not None:
            write_output_text(json_out, json.dumps(result, indent=2) + "\n", "--json")
            stdout.print(f"wrote {json_out}")


__all__ = ["DEFAULT_LEVELS", "PROTOCOL", "NoiseLevel", "delivered_frames", "evaluate_noisy", "noisy_clip", "noisy_library", "parse_levels", "smooth_clip"]
