"""One table of latent spaces next to their teacher: imitation (PULSE / Hybrid Table 1 layout) and
random generation, from the JSON files of ``mocap eval --json`` and ``mocap generate --json``.

    python bench/latent_table.py --out bench/results/latent_table \
        --entry hybrid=checkpoints/hybrid_rvq_amp/eval.json,checkpoints/hybrid_rvq_amp/generation.json \
        --entry pulse=checkpoints/pulse_amp/eval.json,checkpoints/pulse_amp/generation.json

Each ``--entry NAME=EVAL_JSON[,GENERATION_JSON]``; the teacher row comes from the first eval file
(``mocap eval`` of a latent embeds its teacher's table); entries distilled from different teachers
get one teacher row each, before the first entry of that teacher. ``--teacher EVAL_JSON`` supplies the
teacher for entries whose eval file does not embed one (the ``imitation_eval.json`` of a run's eval stage,
e.g. the cells of a comparison spec): their kept clips and MPJPE-g ratio are computed against it with
``mocap.imitation_eval.compare_tables``. Writes ``<out>.json`` and ``<out>.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mocap.imitation_eval import compare_tables

IMITATION = ("success_rate", "succeeded", "mpjpe_g", "mpjpe_g_succ", "mpjpe_l", "acc_err", "vel_err", "rot_err")
GENERATION = ("fall_rate", "time_to_fall_s", "diversity_m", "match_distance", "filtered", "coverage")


def row(eval_table: dict, gen: dict | None) -> dict:
    agg = eval_table["aggregate"]
    out = {k: agg.get(k) for k in IMITATION}
    comp = eval_table.get("comparison")
    if comp:
        out["kept_teacher_clips"] = f"{len(comp['both_succeeded'])}/{len(comp['teacher_succeeded'])}"
        out["mpjpe_g_ratio_on_shared"] = comp["mpjpe_g_ratio_on_both"]
    if gen:
        out.update({k: gen.get(k) for k in GENERATION})
    return out


def fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--entry", action="append", required=True, help="NAME=EVAL_JSON[,GENERATION_JSON]")
    ap.add_argument("--out", type=Path, default=Path("bench/results/latent_table"))
    ap.add_argument("--teacher", type=Path, help="the teacher's eval JSON, for entries whose eval file embeds none")
    ap.add_argument("--title", default="Latent spaces vs their teacher (bundled clips)", help="the Markdown heading")
    args = ap.parse_args(argv)
    given = json.loads(args.teacher.read_text()) if args.teacher else None
    rows: dict[str, dict] = {}
    teacher = None
    teachers: dict[str, dict] = {}  # a row per distinct teacher, named after the first entry distilled from it
    for item in args.entry:
        name, files = item.split("=", 1)
        paths = files.split(",")
        ev = json.loads(Path(paths[0]).read_text())
        gen = json.loads(Path(paths[1]).read_text()) if len(paths) > 1 else None
        if "imitator" not in ev and given is not None:
            ev = {**ev, "imitator": given, "comparison": compare_tables(given, ev)}
        if "imitator" in ev:
            own = row(ev["imitator"], None)
            teacher = own if teacher is None else teacher
            if json.dumps(own, sort_keys=True) not in {json.dumps(t, sort_keys=True) for t in teachers.values()}:
                teachers[name] = own
        rows[name] = row(ev, gen)
    table = {"teacher": teacher, "teachers": teachers, "latents": rows, "sources": args.entry}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(table, indent=2) + "\n")
    cols = ["succeeded", "kept_teacher_clips", "mpjpe_g", "mpjpe_g_succ", "mpjpe_g_ratio_on_shared", "mpjpe_l", "rot_err", *GENERATION]
    lines = ["| policy | " + " | ".join(cols) + " |", "|" + "---|" * (len(cols) + 1)]
    for name, r in rows.items():
        if name in teachers:  # the teacher's row before the first latent distilled from it
            label = "imitator (teacher)" if len(teachers) == 1 else f"imitator (teacher of {name})"
            lines.append(f"| {label} | " + " | ".join(fmt(teachers[name].get(c)) for c in cols) + " |")
        lines.append(f"| {name} | " + " | ".join(fmt(r.get(c)) for c in cols) + " |")
    args.out.with_suffix(".md").write_text(
        f"# {args.title}\n\nImitation: mocap-imitation-v1 (15 clips, mm, "
        "success out of 15). Generation: mocap-generation-v1 (64 rollouts x 10 s from the prior).\n\n" + "\n".join(lines) + "\n"
    )
    print(args.out.with_suffix(".md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
