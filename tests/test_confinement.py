"""Names from user data never steer a write outside its folder (issue 25): clip names from motion
files become safe file names, published outputs stay inside the stage folder, spec names are slugs."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mocap.paths import MAX_STEM, confined, safe_filename
from mocap.spec import SpecError, validate_document

REPO = Path(__file__).resolve().parents[1]


@given(st.text(max_size=400))
def test_safe_filename_is_one_harmless_component(name):
    out = safe_filename(name)
    assert out and len(out) <= MAX_STEM
    assert re.fullmatch(r"[A-Za-z0-9._+-]+", out)
    assert not out.startswith(".") and "/" not in out and "\n" not in out and "|" not in out


def test_safe_filename_keeps_ordinary_clip_names():
    for name in ("walk", "getup_faceup", "dance_a", "jump-2.v1"):
        assert safe_filename(name) == name
    assert safe_filename("../../../etc/passwd") == "etc_passwd"
    assert safe_filename("a\n|b") == "a_b"


def test_confined_refuses_escapes(tmp_path):
    assert confined(tmp_path, "x.mp4") == tmp_path / "x.mp4"
    for bad in ("../x", "a/../../x", "/etc/passwd"):
        with pytest.raises(ValueError, match="outside"):
            confined(tmp_path, bad)
    (tmp_path / "link").symlink_to("/")
    with pytest.raises(ValueError, match="outside"):
        confined(tmp_path, "link/tmp/x")


@pytest.mark.parametrize("name", ["../../X", "", "a/b", ".hidden", "x" * 101, "new\nline"])
def test_spec_name_must_be_a_slug(name):
    from mocap.plugins import get_plugins

    doc = {"spec_version": 1, "name": name}
    with pytest.raises(SpecError, match="name"):
        validate_document(doc, get_plugins(), source="t.yaml")


def test_every_shipped_spec_name_is_a_slug():
    for path in REPO.glob("specs/**/*.yaml"):
        for line in path.read_text().splitlines():
            if line.startswith("name:"):
                assert re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}", line.split(":", 1)[1].strip()), path


@pytest.mark.parametrize(
    "override, field",
    [
        ("imitator.trainer.params.actor_hidden=[-1]", "actor_hidden"),
        ("imitator.trainer.params.lr=1e300", "lr"),
        ("imitator.trainer.params.lr=nan", "lr"),
        ("imitator.trainer.params.log_std_init=1e308", "log_std_init"),
        ("imitator.trainer.params.torch_threads=100000", "torch_threads"),
        ("torch_threads=100000", "torch_threads"),
        ("imitator.trainer.params.num_envs=100000", "num_envs"),
        ("simulator.params.threads=100000", "threads"),
        ("simulator.params.markers=100000", "markers"),
    ],
)
def test_values_that_would_crash_at_run_start_fail_validation(override, field):
    """Specs that validated and then crashed (or segfaulted) at run start: now a validation error."""
    from mocap.plugins import get_plugins
    from mocap.spec import load_spec

    with pytest.raises(SpecError, match=field):
        load_spec(REPO / "specs/imitator/amp_bundled.yaml", get_plugins(), [override])


@pytest.mark.parametrize(
    "text, message",
    [
        ("spec_version: 1\nname: a\nname: b\n", "duplicate key 'name'"),
        ("spec_version: 1\nname: a\nx: " + "[" * 1000 + "]" * 1000 + "\n", "nested more than"),
        ("spec_version: 1\nname: a\nmatrix:\n" + "".join(f"  seed{k}: [0,1,2,3,4,5,6,7,8,9]\n" for k in range(6)), "1,000,000 cells"),
    ],
    ids=["duplicate-key", "deep", "huge-matrix"],
)
def test_spec_documents_that_hung_or_crashed_are_one_error(tmp_path, capsys, text, message):
    from mocap.cli import main

    path = tmp_path / "s.yaml"
    path.write_text(text)
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and str(path) in err


def test_a_full_disk_while_logging_metrics_is_one_storage_error(tmp_path, monkeypatch):
    """A metrics / TensorBoard write on a full disk gave two tracebacks: now one StorageError naming the file."""
    import errno

    from mocap.checkpoint import StorageError
    from mocap.runlog import MetricsLogger

    log = MetricsLogger(tmp_path / "metrics.jsonl", "imitator", tensorboard_dir=None, enabled=True)
    log.log(1, x=1.0)
    real_open = Path.open

    def full(self, *a, **k):
        if self.name == "metrics.jsonl":
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_open(self, *a, **k)

    monkeypatch.setattr(Path, "open", full)
    with pytest.raises(StorageError, match="metrics.jsonl: the disk is full"):
        log.log(2, x=2.0)
    log.close()  # never raises


# ------------------------------------------------------------------------- motion files (fuzz finds)
def _deepmimic(tmp_path: Path, text: str, name: str = "clip.txt") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(
    "text, message",
    [
        ('{"Frames": ' + "[" * 100_000 + "]" * 100_000 + "}", "nested too deeply|not valid JSON"),
        ('{"Loop": "none", "Frames": [[' + ", ".join(["1" + "0" * 400] * 44) + "]]}", "non-numeric|frame"),
    ],
    ids=["deep", "huge-int"],
)
def test_deepmimic_files_that_crashed_the_loader_are_one_error(tmp_path, amp, text, message):
    from mocap.motion.clip import MotionDataError
    from mocap.motion.deepmimic import load_deepmimic_file

    with pytest.raises(MotionDataError, match=message):
        load_deepmimic_file(_deepmimic(tmp_path, text), amp)


def test_a_utf8_bom_deepmimic_file_loads_and_a_directory_is_named_as_such(tmp_path, amp):
    from mocap.motion.clip import MotionDataError
    from mocap.motion.deepmimic import default_data_dir, load_deepmimic_file

    original = Path(default_data_dir()) / "humanoid3d_walk.txt"
    bom = tmp_path / "walk_bom.txt"
    bom.write_bytes(b"\xef\xbb\xbf" + original.read_bytes())
    assert load_deepmimic_file(bom, amp).num_frames == load_deepmimic_file(original, amp).num_frames
    with pytest.raises(MotionDataError, match="a directory"):
        load_deepmimic_file(tmp_path, amp)


def test_amass_rate_out_of_range_and_empty_folder_are_named(tmp_path, smpl):
    import numpy as np

    from mocap.motion.amass import AmassParams, AmassSource, load_amass_file
    from mocap.motion.clip import MotionDataError

    path = tmp_path / "a.npz"
    np.savez(path, poses=np.zeros((4, 156)), trans=np.zeros((4, 3)), mocap_framerate=1e-9, betas=np.zeros(16))
    with pytest.raises(MotionDataError, match="mocap_framerate must be between"):
        load_amass_file(path, smpl)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(MotionDataError, match=f"no AMASS files found in {empty}"):
        AmassSource(AmassParams(paths=[empty])).load(smpl)


def test_path_components_over_255_bytes_are_one_error(tmp_path, capsys):
    from mocap.cli import main

    long = "x" * 300
    spec = REPO / "specs/imitator/amp_bundled.yaml"
    assert main(["run", str(spec), "--out", str(tmp_path / long)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and ("not a usable path" in err or "not writable" in err)
    assert main(["validate", str(spec), "--set", f"imitator.checkpoint={tmp_path / long / 'p.pt'}", "--set", "imitator.trainer=null"]) in (0, 2)
    assert "Traceback" not in capsys.readouterr().err


@pytest.mark.parametrize(
    "spec_text, stages_text, message",
    [
        ("spec_version: 1\nname: [unclosed\n", "[]", "not a valid spec"),
        ("- a list\n", "[]", "not a mapping"),
        (None, "{not json", "corrupt run record"),
        (None, '[{"no_stage": 1}]', "corrupt run record"),
    ],
    ids=["bad-yaml", "not-mapping", "stages-not-json", "stages-missing-keys"],
)
def test_corrupt_run_metadata_is_one_error(tmp_path, capsys, spec_text, stages_text, message):
    from mocap.cli import main

    run = tmp_path / "run"
    run.mkdir()
    (run / "spec.yaml").write_text(spec_text if spec_text is not None else (REPO / "specs/imitator/amp_bundled.yaml").read_text())
    (run / "stages.json").write_text(stages_text)
    for argv in (["eval", str(run)], ["export", str(run), str(tmp_path / "out")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err, (argv, err)
