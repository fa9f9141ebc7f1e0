"""How far the committed numbers drift when the float path changes (issue 63 item 1).

Runs the model cards' commands (``mocap eval checkpoints/imitator/policy.pt``, ``mocap generate
checkpoints/pulse``, ...) under settings that change the last bits of the arithmetic the way another
CPU would: torch's kernels at another ISA level (``ATEN_CPU_CAPABILITY=default`` / ``avx2``) and
another thread count (``OMP_NUM_THREADS=1``), and compares each result with the committed file:
how many aggregates differ, the largest relative difference, and whether every aggregate stays
inside the committed 95% interval (``tests/test_cards_reproduce.py``'s rule).

    python bench/drift.py --out bench/results/drift.json

Not a timing benchmark: the load average is recorded but does not change the numbers.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = {
    "as committed (2 threads, the CPU's best ISA)": {"OMP_NUM_THREADS": "2"},
    "1 thread": {"OMP_NUM_THREADS": "1"},
    "ATEN_CPU_CAPABILITY=default (no AVX)": {"OMP_NUM_THREADS": "2", "ATEN_CPU_CAPABILITY": "default"},
    "ATEN_CPU_CAPABILITY=avx2": {"OMP_NUM_THREADS": "2", "ATEN_CPU_CAPABILITY": "avx2"},
}
CARDS = [
    ("eval", "checkpoints/imitator/policy.pt", "checkpoints/imitator/eval.json"),
    ("generate", "checkpoints/pulse", "checkpoints/pulse/generation.json"),
]


def aggregates(data: dict) -> dict[str, float]:
    values = data.get("aggregate", data)
    return {k: float(v) for k, v in values.items() if k in data.get("ci95", {}) and isinstance(v, (int, float))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "tests"))
    from test_cards_reproduce import outside

    rows = []
    for command, target, committed in CARDS:
        card = json.loads((ROOT / committed).read_text())
        for name, env in SETTINGS.items():
            with tempfile.TemporaryDirectory() as tmp:
                out = Path(tmp) / "fresh.json"
                proc = subprocess.run(
                    [sys.executable, "-m", "mocap", command, target, "--json", str(out)],
                    cwd=ROOT,
                    env={**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), **env},
                    capture_output=True,
                    text=True,
                )
                if proc.returncode:
                    rows.append({"command": f"mocap {command} {target}", "setting": name, "error": proc.stderr[-500:]})
                    continue
                fresh = json.loads(out.read_text())
            a, b = aggregates(fresh), aggregates(card)
            rel = {k: abs(a[k] - b[k]) / max(abs(b[k]), 1e-12) for k in b if k in a and math.isfinite(a[k]) and math.isfinite(b[k])}
            rows.append(
                {
                    "command": f"mocap {command} {target}",
                    "setting": name,
                    "aggregates_differing": sum(1 for v in rel.values() if v > 0),
                    "aggregates": len(b),
                    "max_relative_difference": max(rel.values(), default=0.0),
                    "outside_intervals": outside(fresh, card),
                }
            )
            print(json.dumps(rows[-1]), flush=True)
    record = {
        "command": "python bench/drift.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "cpu": _cpu(),
        "platform": platform.platform(),
        "load_average": os.getloadavg(),
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=2) + "\n")
    return 0


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


if __name__ == "__main__":
    raise SystemExit(main())
