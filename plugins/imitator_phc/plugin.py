"""Entry point of the ``phc`` imitator plugin (group ``mocap``: ``imitator_phc = "mocap_phc.plugin"``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from mocap.hooks import hookimpl
from mocap.plugins import lazy
from mocap_phc.phc_params import PHCParams
from mocap_phc.pmcp_params import PMCPParams


@hookimpl
def register_imitators(register: Any) -> None:
    register(
        "phc",
        lazy("mocap_phc.imitator:make_phc"),
        params=PHCParams,
        description="PHC/PHC+ imitator: proprioception + next-frame imitation goal -> PD targets; "
        "RSI, relaxed early termination, hard-negative clip sampling (paper/code switches)",
    )


@hookimpl
def register_trainers(register: Any) -> None:
    register(
        "pmcp",
        lazy("mocap_phc.pmcp:make_pmcp"),
        params=PMCPParams,
        description="PHC's PMCP in one stage: progressive primitives (each on the clips the previous one fails, until "
        "plateau), then a composer over the frozen primitives; writes pmcp.pt (a phc checkpoint) and pmcp.md",
    )


@hookimpl
def register_commands(app: Any) -> None:
    @app.command("recover")
    def recover_command(
        target: Annotated[
            Path, typer.Argument(help="what `mocap eval` accepts: a policy.pt, a latent checkpoint, checkpoints/<name>, a run directory, a spec")
        ],
        trials: Annotated[int, typer.Option("--trials", help="fallen starts, simulated in parallel")] = 64,
        seconds: Annotated[float, typer.Option("--seconds", help="time allowed to recover, s")] = 10.0,
        reference: Annotated[
            str, typer.Option("--reference", help="'still': a standing frame held, PHC Table 4 (default); 'clip': the clip played, a moving target")
        ] = "still",
        clip: Annotated[
            Optional[str],
            typer.Option("--clip", help="'still': hold this clip's last frame (default: the stillest standing frame); 'clip': the clip (default: walk)"),
        ] = None,
        far_prob: Annotated[float, typer.Option("--far-prob", help="share of trials also 2-5 m away from the reference")] = 0.5,
        seed: Annotated[int, typer.Option("--seed")] = 0,
        json_out: Annotated[Optional[Path], typer.Option("--json", help="write the result as JSON")] = None,
        video: Annotated[Optional[Path], typer.Option("--video", help="write a video of one trial (reference as a ghost)")] = None,
        video_trial: Annotated[
            str, typer.Option("--video-trial", help="the trial --video shows: an index, or 'best' (the first to recover, else the closest)")
        ] = "0",
        imitator_only: Annotated[bool, typer.Option("--imitator-only", help="for a latent space: evaluate the imitator it was distilled from")] = False,
        planner: Annotated[
            str,
            typer.Option(
                "--planner",
                help="'none': the imitator gets the protocol's reference (PHC Table 4); 'getup': when down it is given a get-up clip "
                "aligned to how it lies, then walks back (mocap_phc.recovery_planner; not PHC's P(F)); 'getup-pose': the same, "
                "with the get-up clip's time following the humanoid's pose (getup_clock 'pose')",
            ),
        ] = "none",
    ) -> None:
        """Recovery rate: from fallen (and far) states, the share that gets up and back within 0.5 m of the reference."""
        import json

        from rich.console import Console
        from rich.progress import Progress

        from mocap.eval_targets import build_evaluation_target, load_evaluation_target
        from mocap.paths import check_output_file, write_output_text
        from mocap.plugins import get_plugins
        from mocap_phc.recovery_eval import RecoveryEvalParams, evaluate_recovery
        from mocap_phc.recovery_planner import GetUpPlanner, GetUpPlannerParams

        if json_out is not None:  # output paths before the rollouts
            check_output_file(json_out, "--json")
        if video is not None:
            check_output_file(video, "--video", video=True)
        console = Console(stderr=True)
        plugins = get_plugins()
        info = load_evaluation_target(target, plugins)
        loaded = build_evaluation_target(info, plugins, use_latent=not imitator_only)
        from mocap.errors import UserError

        if reference not in ("still", "clip"):
            raise UserError(f"--reference must be 'still' or 'clip', not {reference!r}")
        if clip is not None and clip not in loaded.library.clip_names:
            raise UserError(f"--clip: no clip {clip!r} in the motion set (clips: {', '.join(loaded.library.clip_names)})")
        if video_trial != "best" and not (video_trial.isdigit() and int(video_trial) < trials):
            raise UserError(f"--video-trial must be 'best' or a trial index below --trials ({trials}), not {video_trial!r}")
        plans = {"none": None, "getup": GetUpPlannerParams(), "getup-pose": GetUpPlannerParams(getup_clock="pose")}
        if planner not in plans:
            raise UserError(f"--planner must be one of {', '.join(plans)}, not {planner!r}")
        plan = plans[planner]
        if plan is not None:
            try:  # the planner needs get-up clips and a looping approach clip in the target's motion set
                GetUpPlanner(loaded.library, plan, 1, 1.0 / 30.0)
            except ValueError as err:
                raise UserError(f"{target}: --planner {planner}: {err}; it runs on the motion set the policy was trained on") from None
        params = RecoveryEvalParams(trials=trials, seconds=seconds, reference=reference, clip=clip, far_prob=far_prob, seed=seed, planner=plan)
        recorder = None
        if video is not None:
            probe = loaded.make_sim(1)
            recorder = probe.make_recorder(ghost=True)
            probe.close()
        with Progress(console=console, transient=True) as bar:
            task = bar.add_task("recovery rollouts", total=int(round(seconds * 30)))
            res = evaluate_recovery(
                loaded.policy,
                loaded.library,
                loaded.make_sim,
                loaded.skeleton,
                params,
                recorder=recorder,
                progress=lambda: bar.advance(task),
                video_trial=video_trial if video_trial == "best" else int(video_trial),
            )
        res["evaluated"] = str(target)
        if recorder is not None and video is not None:
            recorder.save(video)
            res["video"] = str(video)
        print(
            f"recovery rate {res['recovery_rate']:.1%} of {res['trials']} fallen starts within {res['seconds']:g} s "
            f"(fallen near: {res['fallen_near_recovery_rate']:.1%}, fallen and far: {res['fallen_far_recovery_rate']:.1%}); "
            f"root back within 0.5 m: {res['root_back_rate']:.1%}; time to recover {res['time_to_recover_s']:.2f} s; "
            f"reference: {res['clip']} "
            + (f"held at {res['reference_time_s']:.2f} s (standing still)" if res["reference"] == "still" else "played from its first frame")
            + (f"; get-up planner: stood up {res['stood_up_rate']:.1%}" if plan is not None else "")
        )
        if json_out is not None:
            write_output_text(json_out, json.dumps(res, indent=2) + "\n", "--json")
