"""Offscreen rendering: VideoRecorder (MP4/GIF, ghost, markers, pose inputs) and `mocap render`."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import imageio.v2 as iio2  # noqa: E402
import imageio.v3 as iio  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
import typer  # noqa: E402
from typer.testing import CliRunner  # noqa: E402

from mocap.cli import UserError  # noqa: E402
from mocap.motion.deepmimic import DeepMimicParams, DeepMimicSource  # noqa: E402
from mocap.motion.library import MotionLibrary  # noqa: E402
from mocap.plugins import get_plugins  # noqa: E402
from mocap_sim_mujoco.commands import register_commands  # noqa: E402

try:  # a MUJOCO_GL backend whose system library is missing breaks `import mujoco` itself
    from mocap_sim_mujoco.render import GHOST_PREFIX, RenderUnavailable, VideoRecorder, as_pose, render_mjcf
except UserError as exc:
    pytest.skip(f"no offscreen OpenGL: {exc}", allow_module_level=True)

import mujoco  # noqa: E402

W, H = 160, 120


@pytest.fixture(scope="module")
def skeleton():
    return get_plugins().get("humanoid", "amp").build({})


@pytest.fixture(scope="module")
def walk(skeleton):
    """10 frames of the walk clip, 0.1 s apart."""
    mset = DeepMimicSource(DeepMimicParams(clips=["walk"])).load(skeleton)
    lib = MotionLibrary(mset.clips, skeleton)
    return lib.frames(torch.zeros(10, dtype=torch.long), torch.arange(10) * 0.1)


def recorder(skeleton, **kw) -> VideoRecorder:
    try:
        return VideoRecorder(skeleton, width=W, height=H, fps=10, **kw)
    except RenderUnavailable as exc:
        pytest.skip(f"no offscreen OpenGL: {exc}")


def test_render_model_has_collision_free_ghost(skeleton):
    model = mujoco.MjModel.from_xml_string(render_mjcf(skeleton, ghost=True))
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in range(model.ngeom)]
    ghost = np.array([n.startswith(GHOST_PREFIX) for n in names])
    assert ghost.sum() == sum(len(b.geoms) for b in skeleton.bodies)
    assert (model.geom_contype[ghost] == 0).all() and (model.geom_conaffinity[ghost] == 0).all()
    assert (model.geom_rgba[ghost, 3] < 1).all()
    assert model.nq == 2 * (7 + skeleton.num_dofs)


def test_mp4_and_gif_roundtrip(skeleton, walk, tmp_path):
    with recorder(skeleton) as rec:
        for i in range(10):
            frame = rec.add_frame(walk.root_pos[i], walk.root_rot[i], walk.dof_pos[i])
            assert frame.shape == (H, W, 3) and frame.dtype == np.uint8
        mp4, gif = rec.save(tmp_path / "walk.mp4"), rec.save(tmp_path / "walk.gif")
        frames = np.stack(rec.frames)
    assert mp4.stat().st_size > 2000 and gif.stat().st_size > 2000
    decoded = [f for f in iio2.get_reader(mp4)]
    assert len(decoded) == 10 and decoded[0].shape == (H, W, 3)
    g = iio.imread(gif)
    assert g.shape[0] == 10 and g.shape[1:3] == (H, W)
    # the humanoid moves: consecutive frames differ, and the video frames match the recorded ones
    assert np.abs(frames[0].astype(int) - frames[5].astype(int)).max() > 60
    assert np.abs(np.asarray(decoded[5], dtype=float) - frames[5]).mean() < 6


def test_ghost_and_markers_change_pixels(skeleton, walk):
    pose = (walk.root_pos[0], walk.root_rot[0], walk.dof_pos[0])
    ghost = (walk.root_pos[0] + torch.tensor([0.5, -0.5, 0.0]), walk.root_rot[0], walk.dof_pos[0])
    with recorder(skeleton, ghost=True, camera="fixed") as rec:
        plain = rec.render(*pose).astype(int)
        with_ghost = rec.render(*pose, ghost=ghost).astype(int)
        again = rec.render(*pose).astype(int)  # the ghost is hidden on frames without a ghost pose
        marked = rec.render(*pose, markers=[[0.0, -1.0, 0.5]]).astype(int)
        styled = rec.render(*pose, markers=[((0.0, -1.0, 0.5), (0.1, 0.9, 0.1, 1.0), 0.1)]).astype(int)
    assert (np.abs(with_ghost - plain).sum(-1) > 30).sum() > 100
    assert np.array_equal(plain, again)
    assert (np.abs(marked - plain).sum(-1) > 30).sum() > 5
    green = (np.abs(styled - plain).sum(-1) > 30) & (styled[..., 1] > styled[..., 0] + 50)
    assert green.sum() > 5
    with recorder(skeleton) as rec, pytest.raises(ValueError, match="ghost=True"):
        rec.render(*pose, ghost=ghost)


def test_pose_inputs_agree(skeleton, walk):
    qpos = np.concatenate([walk.root_pos[3].numpy(), walk.root_rot[3].numpy(), walk.dof_pos[3].numpy()])
    for a, b in zip(as_pose(walk, row=3), as_pose(qpos)):
        np.testing.assert_allclose(a, b, atol=1e-6)
    with recorder(skeleton, camera="fixed") as rec:
        a = rec.render(walk.root_pos[3], walk.root_rot[3], walk.dof_pos[3])
        assert np.array_equal(a, rec.render(qpos))
        assert np.array_equal(a, rec.render(walk.index(slice(3, 4))))
        with pytest.raises(ValueError, match="unsupported video"):
            rec.save("clip.avi")


def _cli_app() -> typer.Typer:
    app = typer.Typer()

    @app.callback()
    def _root() -> None:  # a group, so that `render` is a subcommand as in `mocap render`
        pass

    register_commands(app)
    return app


def test_cli_render(skeleton, tmp_path):
    recorder(skeleton).close()  # skip without OpenGL
    out = tmp_path / "walk.gif"
    args = ["render", "--motion", "walk", "--out", str(out), "--seconds", "0.3", "--fps", "10", "--width", "96", "--height", "64"]
    res = CliRunner().invoke(_cli_app(), args)
    assert res.exit_code == 0, res.output
    assert str(out) in res.output
    assert iio.imread(out).shape[:3] == (4, 64, 96)


def test_cli_unknown_motion_lists_names():
    res = CliRunner().invoke(_cli_app(), ["render", "--motion", "moonwalk"])
    assert res.exit_code == 2
    text = " ".join(res.output.split())  # rich may wrap the message
    assert "moonwalk" in text and "walk" in text and "backflip" in text and "cartwheel" in text
