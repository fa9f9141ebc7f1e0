"""bench/latent_table.py: latent spaces next to their teachers; entries distilled from different
teachers each get their own teacher row, placed before the first entry of that teacher."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _load():
    spec = importlib.util.spec_from_file_location("latent_table", ROOT / "bench" / "latent_table.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _eval(path: Path, succeeded: int, teacher_succeeded: int) -> str:
    table = lambda n: {"aggregate": {"succeeded": n, "mpjpe_g": 100.0 + n}}  # noqa: E731
    doc = table(succeeded) | {"imitator": table(teacher_succeeded)}
    doc["comparison"] = {"both_succeeded": ["walk"], "teacher_succeeded": ["walk", "run"], "mpjpe_g_ratio_on_both": 1.1}
    path.write_text(json.dumps(doc))
    return str(path)


def test_one_teacher_row_per_distinct_teacher(tmp_path):
    lt = _load()
    entries = [f"a7={_eval(tmp_path / 'a7.json', 10, 11)}", f"b7={_eval(tmp_path / 'b7.json', 9, 11)}", f"a11={_eval(tmp_path / 'a11.json', 9, 12)}"]
    out = tmp_path / "table"
    assert lt.main([arg for e in entries for arg in ("--entry", e)] + ["--out", str(out)]) == 0
    rows = [line.split(" | ")[0].lstrip("| ") for line in out.with_suffix(".md").read_text().splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert rows == ["imitator (teacher of a7)", "a7", "b7", "imitator (teacher of a11)", "a11"]
    table = json.loads(out.with_suffix(".json").read_text())
    assert [t["succeeded"] for t in table["teachers"].values()] == [11, 12] and table["teacher"]["succeeded"] == 11


def test_a_single_teacher_keeps_the_plain_label(tmp_path):
    lt = _load()
    out = tmp_path / "table"
    lt.main(["--entry", f"a={_eval(tmp_path / 'a.json', 10, 11)}", "--entry", f"b={_eval(tmp_path / 'b.json', 8, 11)}", "--out", str(out)])
    assert "| imitator (teacher) |" in out.with_suffix(".md").read_text()


def _clips(path: Path, ok: dict[str, tuple[bool, float]]) -> str:
    clips = {c: {"success": s, "mpjpe_g": m} for c, (s, m) in ok.items()}
    agg = {"succeeded": sum(s for s, _ in ok.values()), "mpjpe_g": sum(m for _, m in ok.values()) / len(ok)}
    path.write_text(json.dumps({"aggregate": agg, "clips": clips}))
    return str(path)


def test_a_given_teacher_scores_entries_that_embed_none(tmp_path):
    """A run's imitation_eval.json has no teacher: --teacher supplies it, kept clips and the ratio on the
    clips both track are computed against it; an entry that embeds its own teacher keeps that one."""
    lt = _load()
    teacher = _clips(tmp_path / "t.json", {"walk": (True, 40.0), "run": (True, 100.0), "spin": (False, 200.0)})
    cell = _clips(tmp_path / "c.json", {"walk": (True, 60.0), "run": (False, 300.0), "spin": (True, 150.0)})
    out = tmp_path / "table"
    args = ["--entry", f"cell={cell}", "--entry", f"own={_eval(tmp_path / 'o.json', 9, 11)}", "--teacher", teacher, "--out", str(out)]
    assert lt.main([*args, "--title", "Ablations"]) == 0
    table = json.loads(out.with_suffix(".json").read_text())
    assert table["latents"]["cell"]["kept_teacher_clips"] == "1/2"
    assert table["latents"]["cell"]["mpjpe_g_ratio_on_shared"] == 60.0 / 40.0
    assert table["latents"]["own"]["kept_teacher_clips"] == "1/2" and table["latents"]["own"]["mpjpe_g_ratio_on_shared"] == 1.1
    assert out.with_suffix(".md").read_text().startswith("# Ablations\n")
    lt.main(["--entry", f"cell={cell}", "--out", str(out)])  # without --teacher: no teacher, nothing kept
    assert "kept_teacher_clips" not in json.loads(out.with_suffix(".json").read_text())["latents"]["cell"]
