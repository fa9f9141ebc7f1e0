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
