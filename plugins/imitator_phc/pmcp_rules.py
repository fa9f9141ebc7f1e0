"""PMCP's bookkeeping rules (:mod:`mocap_phc.pmcp`): when to freeze a primitive
(:class:`PlateauTracker`), the next hard clip set (:func:`next_hard_set`), the motion library's clip
names (:func:`unique_clip_names`) and the per-clip markdown report (:func:`pmcp_report`)."""

from __future__ import annotations

from typing import Any, Sequence

from mocap_phc.pmcp_params import PMCPParams


# ------------------------------------------------------------------------------- the logic
class PlateauTracker:
    """When to freeze a primitive, from its evaluations (per-clip success vectors).

    Evaluation ``j`` with success set ``S_j`` **improves** when ``|S_j| > max_{i<j} |S_i|`` (more
    clips succeed than at any earlier evaluation; the first evaluation always improves) or when
    ``S_j`` holds a clip that no earlier evaluation succeeded on. ``stale`` counts the consecutive
    non-improving evaluations since the last improvement; the plateau is reached when
    ``patience > 0`` and ``stale >= patience``. ``all_success`` is true when the last evaluation
    succeeded on every clip.
    """

    def __init__(self, patience: int, num_clips: int):
        self.patience = int(patience)
        self.num_clips = int(num_clips)
        self.best_count = -1
        self.ever = [False] * self.num_clips
        self.stale = 0
        self.last_all = False
        self.history: list[dict[str, Any]] = []  # per evaluation: iteration, number of clips succeeded, improved

    def update(self, iteration: int, success: Sequence[bool]) -> bool:
        s = [bool(x) for x in success]
        if len(s) != self.num_clips:
            raise ValueError(f"expected {self.num_clips} clip results, got {len(s)}")
        count = sum(s)
        improved = count > self.best_count or any(x and not e for x, e in zip(s, self.ever))
        self.best_count = max(self.best_count, count)
        self.ever = [x or e for x, e in zip(s, self.ever)]
        self.stale = 0 if improved else self.stale + 1
        self.last_all = all(s)
        self.history.append({"iteration": int(iteration), "succeeded": count, "improved": improved})
        return improved

    @property
    def plateaued(self) -> bool:
        return self.patience > 0 and self.stale >= self.patience

    @property
    def all_success(self) -> bool:
        return self.last_all

    def state_dict(self) -> dict[str, Any]:
        return {
            "patience": self.patience,
            "num_clips": self.num_clips,
            "best_count": self.best_count,
            "ever": list(self.ever),
            "stale": self.stale,
            "last_all": self.last_all,
            "history": [dict(h) for h in self.history],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if int(state["num_clips"]) != self.num_clips:
            raise ValueError(f"plateau state for {state['num_clips']} clips, this tracker has {self.num_clips}")
        self.best_count = int(state["best_count"])
        self.ever = [bool(x) for x in state["ever"]]
        self.stale = int(state["stale"])
        self.last_all = bool(state["last_all"])
        self.history = [dict(h) for h in state["history"]]


def unique_clip_names(names: Sequence[str]) -> list[str]:
    """Clip names as :class:`~mocap.motion.library.MotionLibrary` spells them (``#2``, ``#3``... on repeats)."""
    seen: dict[str, int] = {}
    out = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}#{seen[n]}")
    return out


def next_hard_set(clip_ids: Sequence[int], success: Sequence[bool]) -> list[int]:
    """The next primitive's clips: those of ``clip_ids`` (full-library indices) whose freeze
    evaluation failed (``success[i]`` is the result of ``clip_ids[i]``). A subset by construction."""
    if len(clip_ids) != len(success):
        raise ValueError("one success flag per clip")
    return [int(c) for c, ok in zip(clip_ids, success) if not ok]


def pmcp_report(state: dict[str, Any], params: PMCPParams) -> str:
    """The per-clip markdown report: each primitive's clip set and freeze evaluation, the composite's."""
    names: list[str] = state["clip_names"]
    prims = state["primitives"]
    lines = [
        "# PMCP",
        "",
        (f"{len(prims)} primitive(s) (init {params.init!r}), composer {params.composer_form!r}; primitive phase ended: {state.get('stop_reason')}."),
        "",
        "| primitive | clips | end | iterations | env steps | success on its clips |",
        "|---|---|---|---|---|---|",
    ]
    for pr in prims:
        ev = pr.get("evaluation") or {}
        rate = ev.get("success_rate")
        getup = pr.get("getup")
        tag = " (recovery)" if pr.get("recovery") else ""
        if getup is not None:
            tag = f" (recovery, after a get-up phase of {getup.get('env_steps', '-')} env steps)"
        lines.append(
            f"| {pr['index']}{tag} | {len(pr['clip_ids'])} | {pr.get('end', '-')} | {pr.get('iterations', '-')} | "
            f"{pr.get('env_steps', '-')} | {'-' if rate is None else f'{rate:.3f}'} |"
        )
    final = state.get("final_evaluation") or {}
    if final:
        lines += ["", f"Composite (composer + {len(prims)} primitives) on all clips: success {final['success_rate']:.3f}."]
    header = "| clip | " + " | ".join(f"prim {pr['index']}" for pr in prims) + " | composite |"
    lines += ["", "Per clip: `ok` / `fail` at the primitive's freeze evaluation (blank: not in its set), and the composite.", ""]
    lines += [header, "|---|" + "---|" * (len(prims) + 1)]
    for name in names:
        cells = []
        for pr in prims:
            r = ((pr.get("evaluation") or {}).get("clips") or {}).get(name)
            cells.append("" if r is None else ("ok" if r["success"] else "fail"))
        r = (final.get("clips") or {}).get(name)
        cells.append("" if r is None else ("ok" if r["success"] else "fail"))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
