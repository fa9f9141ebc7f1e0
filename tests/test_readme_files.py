"""Every result file the README, a model card or a doc names is committed: a video or table that exists only on the machine
that made it (git-ignored, like ``*.mp4`` outside the folders .gitignore lets through) is missing
from every clone. Directories are not checked (the README names removed checkpoints by their
folder and commit)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PREFIXES = ("bench/results/", "checkpoints/", "specs/")


def expand_braces(path: str) -> list[str]:
    """``a.{md,json}`` -> ``[a.md, a.json]`` (nested and repeated groups too)."""
    m = re.search(r"\{([^{}]*)\}", path)
    if m is None:
        return [path]
    return [q for alt in m.group(1).split(",") for q in expand_braces(path[: m.start()] + alt + path[m.end() :])]


def named_files(text: str) -> set[str]:
    """Files (a last component with a suffix) under PREFIXES named in backticks, braces expanded."""
    out = set()
    for token in re.findall(r"`([^`\s]+)`", text):
        if not token.startswith(PREFIXES) or any(c in token for c in "*<>"):
            continue
        out.update(p for p in expand_braces(token) if "." in p.rsplit("/", 1)[-1] and not p.endswith("/"))
    return out


def test_expand_braces_and_named_files():
    assert expand_braces("bench/results/x.{md,json}") == ["bench/results/x.md", "bench/results/x.json"]
    assert expand_braces("a/{b,c}/d.{e,f}") == ["a/b/d.e", "a/b/d.f", "a/c/d.e", "a/c/d.f"]
    text = "see `bench/results/t.{md,png}`, `checkpoints/old/` and `specs/x.yaml --set a=1`, `mocap run`, `specs/*.yaml`"
    assert named_files(text) == {"bench/results/t.md", "bench/results/t.png"}


@pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(), reason="not a git checkout")
def test_every_file_the_readme_the_model_cards_and_the_docs_name_is_committed():
    tracked = set(subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.splitlines())
    docs = [ROOT / "README.md", *sorted(ROOT.glob("checkpoints/*/MODEL_CARD.md")), *sorted(ROOT.glob("docs/*.md"))]
    missing = {d.relative_to(ROOT).as_posix(): sorted(named_files(d.read_text()) - tracked) for d in docs}
    missing = {k: v for k, v in missing.items() if v}
    assert not missing, f"named but not committed: {missing}"
