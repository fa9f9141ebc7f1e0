"""Issue 63, fuzz items 2 and 5 (motion files): an AMASS ``.npz`` that would unpack to gigabytes or
hold more frames than a clip may is refused from its zip directory and ``.npy`` headers, before
numpy loads it; values no capture holds (a frame rate as text or a bool, complex or bool poses,
positions and shapes of 1e300, frame durations of 1e308 or 1e-12, numbers written as text) are one
:class:`MotionDataError` naming the file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_bad_input import assert_one_line_error

from mocap.motion.clip import MotionDataError
from mocap.testing import invoke


def _amass(path: Path, frames: int = 8, compressed: bool = False, **fields: object) -> Path:
    data: dict[str, object] = {"poses": np.zeros((frames, 156)), "trans": np.zeros((frames, 3)), "mocap_framerate": 120.0, "betas": np.zeros(16)}
    (np.savez_compressed if compressed else np.savez)(path, **{**data, **fields})
    return path


def test_an_amass_member_that_unpacks_beyond_the_cap_is_refused_before_numpy_loads_it(tmp_path, smpl, monkeypatch):
    import mocap.motion.clip
    from mocap.motion.amass import load_amass_file

    path = _amass(tmp_path / "bomb.npz", frames=20_000, compressed=True)  # 25 MB of poses in a file of about 30 kB
    assert path.stat().st_size < 100_000
    monkeypatch.setattr(mocap.motion.clip, "MAX_MEMBER_BYTES", 2**20)  # the real cap is 512 MiB: the same refusal at a test's size
    monkeypatch.setattr(np, "load", None)
    with pytest.raises(MotionDataError, match=r"poses.npy unpacks to 24,960,128 bytes; .* at most 1,048,576"):
        load_amass_file(path, smpl)


def test_an_amass_file_of_more_frames_than_a_clip_may_have_is_refused_from_its_header(tmp_path, smpl, monkeypatch):
    import mocap.motion.clip
    from mocap.motion.amass import load_amass_file

    path = _amass(tmp_path / "long.npz", frames=101)
    monkeypatch.setattr(mocap.motion.clip, "MAX_FRAMES", 100)
    monkeypatch.setattr(np, "load", None)
    with pytest.raises(MotionDataError, match=r"poses has 101 frames; a clip has at most 100"):
        load_amass_file(path, smpl)


def test_resampling_to_more_frames_than_a_clip_may_have_is_refused(tmp_path, smpl):
    from mocap.motion.amass import load_amass_file

    path = _amass(tmp_path / "ok.npz", frames=200)
    with pytest.raises(MotionDataError, match=r"clip resampled to 1e\+09 fps has"):
        load_amass_file(path, smpl, fps=1e9)


@pytest.mark.parametrize(
    "fields, fragment",
    [
        ({"mocap_framerate": np.array("120")}, "mocap_framerate holds <U3 values; expected real numbers"),
        ({"mocap_framerate": np.array(True)}, "mocap_framerate holds bool values"),
        ({"poses": np.zeros((8, 156), dtype=np.complex128)}, "poses holds complex128 values"),
        ({"poses": np.zeros((8, 156), dtype=bool)}, "poses holds bool values"),
        ({"trans": np.full((8, 3), 1e300)}, "trans holds 1e+300 m at frame 0"),
        ({"betas": np.full(16, 1e300)}, "betas holds 1e+300 at frame 0"),
        ({"betas": np.full(16, np.nan)}, "betas contains NaN"),
        ({"poses": np.full((8, 156), 1e300)}, "poses holds 1e+300 rad"),
    ],
)
def test_amass_values_no_capture_holds_are_refused(tmp_path, smpl, fields, fragment):
    from mocap.motion.amass import load_amass_file

    with pytest.raises(MotionDataError, match=fragment.replace("+", r"\+")):
        load_amass_file(_amass(tmp_path / "odd.npz", **fields), smpl)


def test_an_ordinary_amass_file_still_loads(tmp_path, smpl):
    from mocap.motion.amass import load_amass_file

    clip = load_amass_file(_amass(tmp_path / "ok.npz", frames=240, mocap_framerate=np.array(120)), smpl)
    assert clip.fps == 30.0 and clip.num_frames == 60


# ------------------------------------------------------------------ DeepMimic
def _deepmimic(tmp_path: Path, edit: str) -> Path:
    from mocap.motion.deepmimic import default_data_dir

    doc = json.loads((default_data_dir() / "humanoid3d_walk.txt").read_text())
    frames = doc["Frames"]
    if edit == "durations_1e308":
        for row in frames:
            row[0] = 1e308
    elif edit == "one_duration_1e308":
        frames[3][0] = 1e308
    elif edit in ("rate_1e12", "rate_1e-12"):
        for row in frames:
            row[0] = 1e-12 if edit == "rate_1e12" else 1e12
    elif edit == "root_1e300":
        frames[2][1] = 1e300
    elif edit == "duration_text":
        frames[0][0] = str(frames[0][0])
    elif edit == "true":
        frames[1][9] = True
    path = tmp_path / "humanoid3d_odd.txt"
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    "edit, fragment",
    [
        ("durations_1e308", "frame 0 lasts 1e+308 s; a frame lasts 0.0001 to 1 s"),
        ("one_duration_1e308", "frame 3 lasts 1e+308 s"),
        ("rate_1e12", "frame 0 lasts 1e-12 s"),
        ("rate_1e-12", "frame 0 lasts 1e+12 s"),
        ("root_1e300", "the root position holds 1e+300 m at frame 2"),
        ("duration_text", "frame 0 value 0 is '0.0333"),
        ("true", "frame 1 value 9 is True; frames hold numbers"),
    ],
)
def test_deepmimic_values_no_capture_holds_are_one_error(tmp_path, amp, edit, fragment):
    from mocap.motion.deepmimic import load_deepmimic_file

    path = _deepmimic(tmp_path, edit)
    with pytest.raises(MotionDataError, match=fragment.replace("+", r"\+")):
        load_deepmimic_file(path, amp)
    if edit == "durations_1e308":  # the fuzz campaign's ZeroDivisionError came from `motions list`
        assert_one_line_error(invoke(["motions", "list", "--clip", str(path)]), str(path), "lasts 1e+308 s")
