"""Motion sources (DeepMimic, AMASS, native npz), the motion library and ``mocap motions``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import typer
from typer.testing import CliRunner

from mocap.humanoids.amp import amp_skeleton
from mocap.motion import plugin
from mocap.motion.amass import SMPL_JOINT_NAMES, AmassParams, AmassSource, load_amass_file
from mocap.motion.clip import Clip, MotionDataError
from mocap.motion.deepmimic import CLIP_NAMES, DeepMimicParams, DeepMimicSource, default_data_dir, load_deepmimic_file
from mocap.motion.library import MotionLibrary
from mocap.motion.sources import MotionSet, NpzParams, NpzSource
from mocap.rotations import heading_angle, quat_apply, quat_from_axis_angle

WALK_FILE = "humanoid3d_walk.txt"


@pytest.fixture(scope="module")
def bundled(amp) -> MotionSet:
    return DeepMimicSource().load(amp)


@pytest.fixture(scope="module")
def lib(bundled, amp) -> MotionLibrary:
    return MotionLibrary(bundled, amp, dtype=torch.float64)


def _walk_json() -> dict:
    return json.loads((default_data_dir() / WALK_FILE).read_text())


def _write_json(path: Path, doc: object) -> Path:
    path.write_text(json.dumps(doc))
    return path


# ------------------------------------------------------------------------------------ DeepMimic
def test_the_walker_clips_load_by_name_and_only_when_named(amp):
    """pybullet's five walker clips (issue 61): named in ``clips``, same format and skeleton; the
    default set stays the 15 bundled clips; a name that is neither is refused listing both."""
    from mocap.motion.deepmimic import LOCOMOTION_CLIPS, WALKER_CLIPS

    loco = DeepMimicSource(DeepMimicParams(clips=list(LOCOMOTION_CLIPS))).load(amp)
    assert loco.names == ["walk", "run", *WALKER_CLIPS] and loco.skipped == []
    for clip in loco.clips[2:]:
        assert clip.fps == 30.0 and clip.loop and clip.num_frames == 38
        assert 0.8 < float(clip.root_pos[:, 2].mean()) < 0.9  # upright, like the bundled walk
    turns = {c.name: float(c.root_pos[-1, 1] - c.root_pos[0, 1]) for c in loco.clips if "turn" in c.name}
    assert all(v > 0.2 for k, v in turns.items() if "left" in k) and all(v < -0.2 for k, v in turns.items() if "right" in k)
    assert DeepMimicSource(DeepMimicParams()).load(amp).names == list(CLIP_NAMES)
    with pytest.raises(ValueError, match="walker_turn_left0"):
        DeepMimicParams(clips=["walker_sideways"])


def test_all_bundled_clips_load(bundled):
    assert bundled.names == list(CLIP_NAMES)
    assert bundled.skipped == []
    by = {c.name: c for c in bundled.clips}
    for name in ("walk", "run", "kick", "punch"):  # frame duration 0.033332-0.033333 s
        assert by[name].fps == 30.0
    for name in ("jump", "spinkick", "cartwheel", "crawl", "dance_a", "dance_b", "getup_faceup", "getup_facedown"):
        assert by[name].fps == 60.0  # 0.016666 s
    assert by["spin"].fps == 24.0 and by["backflip"].fps == 16.0
    assert by["walk"].num_frames == 39 and by["walk"].duration == pytest.approx(38 / 30)
    assert by["run"].num_frames == 25 and by["kick"].num_frames == 47
    # roll has one double-length frame: resampled at 60 fps over the same span (2.0159 s -> 121 intervals)
    assert by["roll"].fps == 60.0 and by["roll"].num_frames == 122
    assert {n for n, c in by.items() if not c.loop} == {"kick", "punch", "getup_faceup", "getup_facedown"}
    for clip in bundled.clips:
        assert clip.skeleton == "amp" and clip.joint_rot.shape == (clip.num_frames, 14, 4)
        assert clip.duration > 0.5
        np.testing.assert_allclose(np.linalg.norm(clip.root_rot, axis=-1), 1.0, atol=1e-9)
        hands = [amp_skeleton().body_index(h) - 1 for h in ("right_hand", "left_hand")]
        np.testing.assert_array_equal(clip.joint_rot[:, hands], np.broadcast_to([1.0, 0, 0, 0], (clip.num_frames, 2, 4)))


def test_deepmimic_conversion_is_z_up(bundled):
    raw = np.asarray(_walk_json()["Frames"])
    walk = bundled.clips[0]
    np.testing.assert_allclose(walk.root_pos, np.stack([raw[:, 1], -raw[:, 3], raw[:, 2]], -1), atol=1e-12)
    q = raw[:, 4:8] / np.linalg.norm(raw[:, 4:8], axis=-1, keepdims=True)
    np.testing.assert_allclose(walk.root_rot, np.stack([q[:, 0], q[:, 1], -q[:, 3], q[:, 2]], -1), atol=1e-12)
    # right knee (column 20) is a rotation about (0, -1, 0); the walk's knees bend with negative angles
    knee = walk.joint_rot[:, amp_skeleton().body_index("right_shin") - 1]
    np.testing.assert_allclose(knee[:, [1, 3]], 0.0, atol=1e-12)
    np.testing.assert_allclose(2 * np.arctan2(-knee[:, 2], knee[:, 0]), raw[:, 20], atol=1e-9)
    assert raw[:, 20].max() <= 1e-6


def test_walk_heights_and_cycle(lib, amp):
    w = lib.clip_index("walk")
    rows = slice(lib.frame_index(w, 0), lib.frame_index(w, 38) + 1)
    pelvis_z = lib.body_pos[rows, 0, 2]
    assert 0.84 <= float(pelvis_z.min()) and float(pelvis_z.max()) <= 0.88
    # lowest corner of the foot boxes (the standing design: lowest foot point -5..+14 mm)
    lows = []
    for foot in ("left_foot", "right_foot"):
        b = amp.body_index(foot)
        (geom,) = amp.bodies[b].geoms
        assert geom.type == "box"
        signs = torch.tensor([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=torch.float64)
        corners = torch.tensor(geom.pos, dtype=torch.float64) + signs * torch.tensor(geom.size[:3], dtype=torch.float64)
        world = lib.body_pos[rows, b, None] + quat_apply(lib.body_rot[rows, b, None], corners)
        lows.append(world[..., 2].min(-1).values)
        # the foot body origin (ankle) stays above the sole: at least 3 cm off the ground every frame
        assert float(lib.body_pos[rows, b, 2].min()) > 0.03
    lowest = torch.minimum(*lows)  # per frame, over both feet: -5.3 .. +13.7 mm
    assert -0.007 <= float(lowest.min()) <= 0.0 and 0.005 <= float(lowest.max()) <= 0.015
    neck = lib.body_pos[rows, amp.body_index("head"), 2]  # the head body's origin is the neck joint
    assert 1.30 <= float(neck.min()) and float(neck.max()) <= 1.335
    offset = lib.cycle_offsets[w]
    assert float(offset[0]) == pytest.approx(1.239, abs=0.005) and abs(float(offset[1])) < 0.01
    f = lib.frames(torch.tensor([w, w]), torch.tensor([0.0, 3 * 38 / 30]))
    assert float(f.root_pos[1, 0] - f.root_pos[0, 0]) == pytest.approx(3 * 1.239, abs=0.02)


def test_deepmimic_unknown_clip_lists_names(tmp_path):
    with pytest.raises(ValueError, match="available: walk, run"):
        DeepMimicParams(clips=["wlak"])
    _write_json(tmp_path / "humanoid3d_mine.txt", _walk_json())
    src = DeepMimicSource(DeepMimicParams(clips=["walk"], data_dir=tmp_path))
    with pytest.raises(MotionDataError, match="unknown DeepMimic clip 'walk'.*available: mine"):
        src.load(amp_skeleton())


def test_deepmimic_wrong_skeleton(smpl):
    with pytest.raises(MotionDataError, match="skeleton 'smpl' lacks pelvis, torso.*use humanoid 'amp'"):
        DeepMimicSource(DeepMimicParams(clips=["walk"])).load(smpl)


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "no such file"),
        ('{"Loop": "wrap", "Frames": [[0.03, 1, 2', "not valid JSON"),
        ('{"Loop": "wrap"}', "missing the 'Frames' key"),
        ('{"Loop": "wrap", "Frames": []}', "clip has no frames"),
        ('{"Loop": "wrap", "Frames": [[0.03, 1.0]]}', "frame 0 has 2 values, expected 44"),
        ("NAN", "frame data contains NaN"),
        ("ONE", "at least 2 are needed"),
        ("ZEROQ", "quaternion at frame 3 has norm 0"),
    ],
)
def test_deepmimic_bad_files(tmp_path, amp, content, message):
    path = tmp_path / "humanoid3d_bad.txt"
    doc = _walk_json()
    if content == "NAN":
        doc["Frames"][5][9] = float("nan")
        path.write_text(json.dumps(doc))  # json writes NaN, which Python's json reads back
    elif content == "ONE":
        doc["Frames"] = doc["Frames"][:1]
        _write_json(path, doc)
    elif content == "ZEROQ":
        doc["Frames"][3][8:12] = [0, 0, 0, 0]
        _write_json(path, doc)
    elif content is not None:
        path.write_text(content)
    with pytest.raises(MotionDataError, match=message) as exc:
        load_deepmimic_file(path, amp)
    assert str(path) in str(exc.value)


def test_deepmimic_skip_bad(tmp_path, amp):
    _write_json(tmp_path / "humanoid3d_good.txt", _walk_json())
    (tmp_path / "humanoid3d_broken.txt").write_text("{")
    strict = DeepMimicSource(DeepMimicParams(data_dir=tmp_path))
    with pytest.raises(MotionDataError, match="humanoid3d_broken.txt: not valid JSON"):
        strict.load(amp)
    mset = DeepMimicSource(DeepMimicParams(data_dir=tmp_path, skip_bad=True)).load(amp)
    assert mset.names == ["good"]
    assert [Path(p).name for p, _ in mset.skipped] == ["humanoid3d_broken.txt"]


# ---------------------------------------------------------------------------------------- AMASS
def _amass_file(path: Path, T: int = 61, width: int = 156, rate: float = 60.0, seed: int = 0, **override) -> dict:
    rng = np.random.default_rng(seed)
    data = {
        "poses": rng.normal(0.0, 0.3, size=(T, width)),
        "trans": np.stack([np.linspace(0, 2, T), np.linspace(0, -1, T), 0.9 + 0.05 * np.sin(np.arange(T) / 5)], -1),
        "mocap_framerate": np.array(rate),
        "betas": np.zeros(16),
    }
    data.update(override)
    np.savez(path, **data)
    return data


def test_amass_resample_and_root(tmp_path, smpl):
    data = _amass_file(tmp_path / "a.npz", T=61)
    clip = load_amass_file(tmp_path / "a.npz", smpl, fps=30)
    assert clip.num_frames == 31 and clip.fps == 30.0 and clip.duration == pytest.approx(1.0)
    np.testing.assert_allclose(clip.root_pos, data["trans"][::2], atol=1e-12)  # same instants: translation kept
    native = load_amass_file(tmp_path / "a.npz", smpl, fps=None)
    assert native.num_frames == 61 and native.fps == 60.0
    np.testing.assert_allclose(clip.joint_rot, native.joint_rot[::2], atol=1e-9)
    np.testing.assert_allclose(clip.root_rot, native.root_rot[::2], atol=1e-9)
    # SMPL+H: joints 22-23 of the 156 numbers are fingers, so the SMPL hands are the identity
    for hand in ("L_Hand", "R_Hand"):
        np.testing.assert_allclose(clip.joint_rot[:, smpl.body_index(hand) - 1], [[1, 0, 0, 0]] * 31, atol=1e-12)
    smpl72 = load_amass_file(_amass_path(tmp_path, "b.npz", width=72), smpl, fps=30)
    assert not np.allclose(smpl72.joint_rot[:, smpl.body_index("L_Hand") - 1, 0], 1.0)


def _amass_path(tmp_path: Path, name: str, **kw) -> Path:
    _amass_file(tmp_path / name, **kw)
    return tmp_path / name


def test_amass_axes(tmp_path, smpl):
    """A standing AMASS root (+90 deg about x: SMPL y up -> world z up) is upright; SMPL's body y
    axis (up) becomes our z axis for local joint rotations."""
    T = 4
    poses = np.zeros((T, 72))
    poses[:, 0] = math.pi / 2
    poses[:, 3 * SMPL_JOINT_NAMES.index("L_Elbow") + 1] = 0.7  # about SMPL's y axis
    _amass_file(tmp_path / "stand.npz", T=T, width=72, poses=poses)
    clip = load_amass_file(tmp_path / "stand.npz", smpl, fps=None)
    root = torch.from_numpy(clip.root_rot[0])
    up = quat_apply(root, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    forward = quat_apply(root, torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    np.testing.assert_allclose(up.numpy(), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(forward.numpy(), [0, -1, 0], atol=1e-12)  # SMPL faces +z, +z -> -y in this world
    elbow = clip.joint_rot[0, smpl.body_index("L_Elbow") - 1]
    expect = quat_from_axis_angle(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), torch.tensor(0.7, dtype=torch.float64))
    np.testing.assert_allclose(elbow, expect.numpy(), atol=1e-12)
    # y-up data: an identity SMPL root is upright after the +90 deg turn about x; p' = (x, -z, y)
    trans = np.tile([1.0, 2.0, 3.0], (T, 1))
    _amass_file(tmp_path / "yup.npz", T=T, width=72, poses=np.zeros((T, 72)), trans=trans)
    clip = load_amass_file(tmp_path / "yup.npz", smpl, fps=None, up_axis="y")
    np.testing.assert_allclose(clip.root_pos, np.tile([1.0, -3.0, 2.0], (T, 1)), atol=1e-12)
    up = quat_apply(torch.from_numpy(clip.root_rot[0]), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    np.testing.assert_allclose(up.numpy(), [0, 0, 1], atol=1e-12)


def test_amass_bad_files_and_skip(tmp_path, smpl, amp):
    d = tmp_path / "amass"
    d.mkdir()
    _amass_file(d / "good.npz")
    (d / "truncated.npz").write_bytes((d / "good.npz").read_bytes()[:200])
    _amass_file(d / "nan.npz", trans=np.full((61, 3), np.nan))
    _amass_file(d / "empty.npz", T=0)
    np.savez(d / "nokeys.npz", poses=np.zeros((5, 72)))
    np.savez(d / "shape.npz", betas=np.zeros(16))  # AMASS per-subject shape file: ignored
    cases = {
        "truncated.npz": "unreadable or truncated",
        "nan.npz": "trans contains NaN",
        "empty.npz": "clip has no frames",
        "nokeys.npz": "missing trans, mocap_framerate",
        "missing.npz": "no such file",
    }
    for name, message in cases.items():
        with pytest.raises(MotionDataError, match=message) as exc:
            load_amass_file(d / name, smpl)
        assert str(d / name) in str(exc.value)
    with pytest.raises(MotionDataError, match="skeleton 'amp' lacks L_Hip, R_Hip.*use humanoid 'smpl'"):
        load_amass_file(d / "good.npz", amp)
    mset = AmassSource(AmassParams(paths=[d, tmp_path / "missing.npz"])).load(smpl)
    assert mset.names == ["good"]
    assert sorted(Path(p).name for p, _ in mset.skipped) == ["empty.npz", "missing.npz", "nan.npz", "nokeys.npz", "truncated.npz"]
    with pytest.raises(MotionDataError, match="empty.npz: clip has no frames"):
        AmassSource(AmassParams(paths=[d], skip_bad=False)).load(smpl)
    with pytest.raises(MotionDataError, match="no AMASS clip could be loaded"):
        AmassSource(AmassParams(paths=[d / "nan.npz"])).load(smpl)


# ----------------------------------------------------------------------------------- native npz
def test_native_npz_round_trip(tmp_path, bundled, amp, smpl):
    for clip in bundled.clips[:3]:
        clip.save(tmp_path / f"{clip.name}.npz")
    mset = NpzSource(NpzParams(paths=[tmp_path])).load(amp)
    assert mset.names == sorted(c.name for c in bundled.clips[:3])
    for got in mset.clips:
        want = next(c for c in bundled.clips if c.name == got.name)
        assert (got.skeleton, got.fps, got.loop) == (want.skeleton, want.fps, want.loop)
        for key in ("root_pos", "root_rot", "joint_rot"):
            np.testing.assert_array_equal(getattr(got, key), getattr(want, key))
    with pytest.raises(MotionDataError, match="walk.npz: clip 'walk' is for skeleton 'amp', not 'smpl'"):
        NpzSource(NpzParams(paths=[tmp_path / "walk.npz"], skip_bad=False)).load(smpl)
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 truncated")
    mset = NpzSource(NpzParams(paths=[tmp_path])).load(amp)
    assert [Path(p).name for p, _ in mset.skipped] == ["bad.npz"] and len(mset) == 3


# -------------------------------------------------------------------------------------- library
def test_library_metadata(lib, bundled):
    assert lib.num_clips == 15 and lib.clip_names == list(CLIP_NAMES)
    assert lib.num_frames.tolist() == [c.num_frames for c in bundled.clips]
    torch.testing.assert_close(lib.durations, torch.tensor([c.duration for c in bundled.clips], dtype=torch.float64))
    assert lib.loops.tolist() == [c.loop for c in bundled.clips]
    assert lib.fps[lib.clip_index("walk")] == 30.0
    with pytest.raises(KeyError, match="did you mean walk"):
        lib.clip_index("wakl")
    assert lib.dof_pos.shape == (lib.total_frames, 28) and lib.body_pos.shape == (lib.total_frames, 15, 3)


def test_library_frames_at_frame_times(lib):
    ids, times, rows = [], [], []
    for c in range(lib.num_clips):
        for i in range(0, int(lib.num_frames[c]) - 1, 7):
            ids.append(c)
            times.append(i / float(lib.fps[c]))
            rows.append(lib.frame_index(c, i))
    f = lib.frames(torch.tensor(ids), torch.tensor(times, dtype=torch.float64))
    rows_t = torch.tensor(rows)
    for key in ("dof_pos", "dof_vel", "body_pos", "body_lin_vel", "body_ang_vel"):
        torch.testing.assert_close(getattr(f, key), getattr(lib, key)[rows_t], atol=1e-9, rtol=0)
    torch.testing.assert_close(f.root_pos, lib.root_pos[rows_t], atol=1e-9, rtol=0)
    dots = (f.body_rot * lib.body_rot[rows_t]).sum(-1).abs()
    torch.testing.assert_close(dots, torch.ones_like(dots), atol=1e-9, rtol=0)
    torch.testing.assert_close(f.root_pos, f.body_pos[:, 0])


def test_library_midpoints_and_velocities(lib):
    c = torch.arange(lib.num_clips).repeat_interleave(5)
    i = torch.arange(5).repeat(lib.num_clips)
    f = lib.frames(c, (i + 0.5) / lib.fps[c])
    torch.testing.assert_close(f.root_rot.norm(dim=-1), torch.ones(len(c), dtype=torch.float64))
    torch.testing.assert_close(f.body_rot.norm(dim=-1), torch.ones(len(c), 15, dtype=torch.float64))
    # forward differences; the last frame repeats the previous (non-looping) or frame 0's (looping) velocity
    walk, kick = lib.clip_index("walk"), lib.clip_index("kick")
    r = lib.frame_index(walk, 10)
    torch.testing.assert_close(lib.body_lin_vel[r, 0], (lib.root_pos[r + 1] - lib.root_pos[r]) * 30.0)
    torch.testing.assert_close(lib.dof_vel[r], (lib.dof_pos[r + 1] - lib.dof_pos[r]) * 30.0)
    torch.testing.assert_close(lib.body_lin_vel[lib.frame_index(walk, 38)], lib.body_lin_vel[lib.frame_index(walk, 0)])
    torch.testing.assert_close(lib.dof_vel[lib.frame_index(kick, 46)], lib.dof_vel[lib.frame_index(kick, 45)])
    # DoFs are unwrapped: no jump near 2 pi between consecutive frames of a clip
    for c_id in range(lib.num_clips):
        a, b = lib.frame_index(c_id, 0), lib.frame_index(c_id, int(lib.num_frames[c_id]) - 1)
        assert float(lib.dof_pos[a : b + 1].diff(dim=0).abs().max()) < math.pi


def test_library_body_interpolation(bundled, amp):
    """Bodies between frames follow the slerped joint rotations, also where the punch's right
    shoulder passes near gimbal lock (its y and z angles swing by ~2.7 rad in one frame)."""
    punch = [c for c in bundled.clips if c.name == "punch"]
    fk = MotionLibrary(punch, amp, dtype=torch.float64)
    chord = MotionLibrary(punch, amp, dtype=torch.float64, body_interp="lerp")
    y = amp.dof_names.index("right_shoulder_y")
    assert float((fk.dof_pos[25, y] - fk.dof_pos[24, y]).abs()) > 2.0
    t = torch.tensor([24.0, 24.5, 10.0, 10.5], dtype=torch.float64) / 30.0
    a, b = fk.frames(torch.zeros(4, dtype=torch.long), t), chord.frames(torch.zeros(4, dtype=torch.long), t)
    torch.testing.assert_close(a.body_pos[[0, 2]], b.body_pos[[0, 2]])
    assert float((a.body_pos - b.body_pos).norm(dim=-1).max()) < 0.02
    with pytest.raises(ValueError, match="body_interp"):
        MotionLibrary(punch, amp, body_interp="spline")  # type: ignore[arg-type]


def test_library_unwraps_dofs(amp):
    """A chest twist crossing +pi stays continuous and the clip's mean angle lies in (-pi, pi]."""
    T = 9
    joint_rot = np.tile([1.0, 0.0, 0.0, 0.0], (T, 14, 1))
    angles = np.linspace(2.8, 3.6, T)
    joint_rot[:, amp.body_index("torso") - 1] = np.stack([np.cos(angles / 2), 0 * angles, 0 * angles, np.sin(angles / 2)], -1)
    clip = Clip("twist", "amp", 30.0, np.tile([0.0, 0.0, 0.9], (T, 1)), np.tile([1.0, 0, 0, 0], (T, 1)), joint_rot)
    lib = MotionLibrary([clip, clip], amp, dtype=torch.float64)
    chest_z = lib.dof_pos[:, amp.dof_names.index("chest_z")]
    torch.testing.assert_close(chest_z.diff()[: T - 1], torch.full((T - 1,), 0.1, dtype=torch.float64))
    torch.testing.assert_close(chest_z[:T], torch.from_numpy(angles) - 2 * math.pi)
    torch.testing.assert_close(chest_z[T:], chest_z[:T])
    torch.testing.assert_close(lib.dof_vel[: T - 1, amp.dof_names.index("chest_z")], torch.full((T - 1,), 3.0, dtype=torch.float64))
    assert lib.clip_names == ["twist", "twist#2"]


def test_library_loop_wrap(lib):
    looping = [c for c in range(lib.num_clips) if lib.loops[c]]
    c = torch.tensor(looping)
    period = lib.durations[c]
    f0 = lib.frames(c, torch.zeros(len(c), dtype=torch.float64))
    for k in (1, 2, -1):
        fk = lib.frames(c, k * period)
        shift = torch.cat((k * lib.cycle_offsets[c], torch.zeros(len(c), 1, dtype=torch.float64)), -1)
        torch.testing.assert_close(fk.root_pos, f0.root_pos + shift)
        torch.testing.assert_close(fk.body_pos, f0.body_pos + shift[:, None])
        torch.testing.assert_close(fk.dof_pos, f0.dof_pos)
        torch.testing.assert_close(fk.times, torch.zeros_like(fk.times))
    # positions are continuous across the wrap (the last frame is the next cycle's first)
    before, after = lib.frames(c, period - 1e-6), lib.frames(c, period + 1e-6)
    assert float((before.root_pos[:, :2] - after.root_pos[:, :2]).abs().max()) < 1e-3
    # a time inside cycle 2 is cycle 0's frame moved by twice the cycle offset
    f = lib.frames(c, 2 * period + 0.1)
    g = lib.frames(c, torch.full((len(c),), 0.1, dtype=torch.float64))
    torch.testing.assert_close(f.root_pos[:, :2], g.root_pos[:, :2] + 2 * lib.cycle_offsets[c])
    # non-looping clips clamp
    kick = lib.clip_index("kick")
    f = lib.frames(torch.tensor([kick, kick]), torch.tensor([-1.0, 100.0], dtype=torch.float64))
    torch.testing.assert_close(f.root_pos[0], lib.root_pos[lib.frame_index(kick, 0)])
    torch.testing.assert_close(f.root_pos[1], lib.root_pos[lib.frame_index(kick, 46)])
    torch.testing.assert_close(f.times, torch.tensor([0.0, 46 / 30], dtype=torch.float64))


def test_library_loop_heading(bundled, amp):
    spin = next(c for c in bundled.clips if c.name == "walk")
    lib = MotionLibrary([spin], amp, dtype=torch.float64, loop_heading=True)
    last = lib.frame_index(0, 38)
    f = lib.frames(torch.tensor([0, 0]), torch.stack([lib.durations[0], 3 * lib.durations[0]]))
    # one cycle later the root is where the last frame is (xy and heading)
    torch.testing.assert_close(f.root_pos[0, :2], lib.root_pos[last, :2])
    torch.testing.assert_close(heading_angle(f.root_rot[0]), heading_angle(lib.root_rot[last]))
    h = float(heading_angle(lib.root_rot[last]) - heading_angle(lib.root_rot[0]))
    turned = heading_angle(f.root_rot[1]) - heading_angle(lib.root_rot[0])
    assert float(torch.remainder(turned - 3 * h + math.pi, 2 * math.pi) - math.pi) == pytest.approx(0.0, abs=1e-9)


def test_library_sampling_respects_weights(lib):
    w = torch.zeros(lib.num_clips, dtype=torch.float64)
    w[0], w[3], w[7] = 1.0, 2.0, 5.0
    lib.set_weights(w)
    try:
        g = torch.Generator().manual_seed(0)
        ids, times = lib.sample(40000, generator=g)
        freq = torch.bincount(ids, minlength=lib.num_clips).double() / len(ids)
        torch.testing.assert_close(freq, w / w.sum(), atol=0.01, rtol=0)
        assert set(ids.tolist()) == {0, 3, 7}
        assert bool(torch.all(times >= 0)) and bool(torch.all(times <= lib.durations[ids]))
        ids2, times2 = lib.sample(100, generator=torch.Generator().manual_seed(0))
        assert torch.equal(ids2, ids[:100])
    finally:
        lib.set_weights(None)
    torch.testing.assert_close(lib.weights, torch.full((lib.num_clips,), 1 / lib.num_clips, dtype=torch.float64))
    with pytest.raises(ValueError, match="expected 15 clip weights"):
        lib.set_weights([1.0, 2.0])


def test_library_rejects_wrong_skeleton(bundled, smpl):
    with pytest.raises(MotionDataError, match="is for skeleton 'amp', not 'smpl'"):
        MotionLibrary(bundled.clips[:1], smpl)


def test_library_float32_amass(tmp_path, smpl):
    _amass_file(tmp_path / "a.npz", T=31, width=72)
    lib = MotionLibrary(AmassSource(AmassParams(paths=[tmp_path])).load(smpl), smpl)
    f = lib.frames(torch.tensor([0, 0]), torch.tensor([0.25, 5.0]))
    assert f.body_pos.dtype == torch.float32 and f.body_pos.shape == (2, 24, 3) and f.dof_pos.shape == (2, 69)
    assert torch.isfinite(f.body_ang_vel).all()


# ------------------------------------------------------------------------------------------ CLI
@pytest.fixture(scope="module")
def cli():
    app = typer.Typer()
    plugin.register_commands(app)
    return app


def test_cli_list_and_show(cli):
    runner = CliRunner()
    res = runner.invoke(cli, ["motions", "list", "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    walk = next(c for c in data["clips"] if c["name"] == "walk")
    assert len(data["clips"]) == 15 and data["humanoid"] == "amp"
    assert (walk["num_frames"], walk["fps"], walk["loop"]) == (39, 30.0, True)
    res = runner.invoke(cli, ["motions", "list"])
    assert res.exit_code == 0 and "spinkick" in res.stdout and "looping" in res.stdout
    res = runner.invoke(cli, ["motions", "show", "walk"])
    assert res.exit_code == 0, res.output
    assert "39" in res.stdout and "distance travelled" in res.stdout and WALK_FILE in res.stdout
    res = runner.invoke(cli, ["motions", "show", "walk", "--json"])
    info = json.loads(res.stdout)
    assert 0.84 < info["root_height_min"] < info["root_height_max"] < 0.88
    assert info["displacement"] == pytest.approx(1.239, abs=0.005)


def test_cli_errors(cli, tmp_path):
    runner = CliRunner()
    res = runner.invoke(cli, ["motions", "show", "wakl"])
    assert res.exit_code == 2 and "no clip 'wakl'" in res.output and "did you mean walk" in res.output
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)
    res = runner.invoke(cli, ["motions", "list", "--clip", "nope"])
    assert res.exit_code == 2 and "available: walk" in res.output
    res = runner.invoke(cli, ["motions", "list", "--source", "nosuch"])
    assert res.exit_code == 2 and "deepmimic" in res.output
    res = runner.invoke(cli, ["motions", "list", "--source", "npz", "--path", str(tmp_path / "missing.npz")])
    assert res.exit_code == 2 and "missing.npz: no such file" in res.output
