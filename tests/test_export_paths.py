"""`mocap export` from one checkout into another (a run made in a git worktree, exported into the main
checkout): committed files are named at their place in the destination's checkout."""

from __future__ import annotations

from pathlib import Path

import yaml

from mocap.export import relative_spec_text, same_file_in_checkout


def _checkouts(tmp_path: Path) -> tuple[Path, Path]:
    main, worktree = tmp_path / "main", tmp_path / "train"
    (main / ".git").mkdir(parents=True)  # a clone: .git is a folder
    worktree.mkdir()
    (worktree / ".git").write_text("gitdir: ../main/.git/worktrees/train\n")  # a worktree: .git is a file
    for root in (main, worktree):
        (root / "checkpoints" / "teacher").mkdir(parents=True)
        (root / "checkpoints" / "teacher" / "policy.pt").write_bytes(b"the same teacher")
    return main, worktree


def test_the_identical_file_of_the_destination_checkout_is_named(tmp_path: Path):
    main, worktree = _checkouts(tmp_path)
    src = worktree / "checkpoints" / "teacher" / "policy.pt"
    dest = main / "checkpoints" / "student"
    assert same_file_in_checkout(src, dest) == main / "checkpoints" / "teacher" / "policy.pt"
    spec = yaml.safe_dump({"imitator": {"checkpoint": str(src)}, "latent": {"name": "pulse"}})
    assert yaml.safe_load(relative_spec_text(spec, dest))["imitator"]["checkpoint"] == "../teacher/policy.pt"


def test_other_files_keep_their_place(tmp_path: Path):
    main, worktree = _checkouts(tmp_path)
    src = worktree / "checkpoints" / "teacher" / "policy.pt"
    dest = main / "checkpoints" / "student"
    (main / "checkpoints" / "teacher" / "policy.pt").write_bytes(b"another teacher")  # differs: not the same file
    assert same_file_in_checkout(src, dest) == src
    (main / "checkpoints" / "teacher" / "policy.pt").unlink()  # absent from the destination's checkout
    assert same_file_in_checkout(src, dest) == src
    spec = yaml.safe_dump({"imitator": {"checkpoint": str(src)}})
    assert yaml.safe_load(relative_spec_text(spec, dest))["imitator"]["checkpoint"] == "../../../train/checkpoints/teacher/policy.pt"
    inside = main / "checkpoints" / "teacher" / "x.pt"  # the same checkout: unchanged
    inside.write_bytes(b"x")
    assert same_file_in_checkout(inside, dest) == inside
    outside = tmp_path / "loose.pt"  # in no checkout
    outside.write_bytes(b"y")
    assert same_file_in_checkout(outside, dest) == outside
