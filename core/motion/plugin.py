"""Built-in motion sources and the ``mocap motions`` commands (entry point ``motion`` of group ``mocap``).

* ``deepmimic``: DeepMimic JSON clips, by default the 15 bundled with ``pybullet``, on ``amp``;
* ``amass``: the user's AMASS ``.npz`` files on ``smpl``;
* ``npz``: native clip files (:mod:`mocap.motion.clip`).
"""

from __future__ import annotations

from typing import Any

from mocap.hooks import hookimpl
from mocap.motion.amass import AmassParams, AmassSource
from mocap.motion.commands import motions_app
from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource
from mocap.motion.sources import NpzParams, NpzSource


@hookimpl
def register_motion_sources(register: Any) -> None:
    register(
        "deepmimic",
        DeepMimicSource,
        params=DeepMimicParams,
        description="DeepMimic JSON clips (15 bundled with pybullet: walk, run, jump, ...) on the amp humanoid",
    )
    register("amass", AmassSource, params=AmassParams, description="AMASS .npz files (SMPL poses, z up) on the smpl humanoid")
    register("npz", NpzSource, params=NpzParams, description="native mocap clip files (.npz, see mocap.motion.clip)")


@hookimpl
def register_commands(app: Any) -> None:
    app.add_typer(motions_app, name="motions")
