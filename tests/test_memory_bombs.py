"""Issue 63, fuzz item 2: no input file or spec of a few kB may take gigabytes before it is refused.
YAML alias bombs, deep ``extends:`` chains and ``--set`` paths, oversized matrices; each is one
``error:`` line (exit 2), reached without expanding anything."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from test_bad_input import assert_one_line_error

from mocap.testing import invoke

REPO = Path(__file__).resolve().parents[1]
AMP_BUNDLED = REPO / "specs" / "imitator" / "amp_bundled.yaml"


def _anchors(levels: int, indent: str = "  ") -> str:
    """YAML lines defining ``&a0`` .. ``&a<levels>``, each a list of ten of the previous: ``*a<levels>``
    stands for 10**(levels + 1) values in about 60 bytes per level."""
    lines = [f"{indent}a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"{indent}a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, levels + 1)]
    return "\n".join(lines)


def _bomb(kind: str, tmp_path: Path) -> Path:
    spec = tmp_path / "bomb.yaml"
    head = f"spec_version: 1\nextends: {AMP_BUNDLED}\n"
    if kind == "key":
        spec.write_text(f"{head}defs:\n{_anchors(8)}\n? *a8\n: 1\n")
    elif kind == "actor_hidden":
        spec.write_text(f"{head}defs:\n{_anchors(8)}\nimitator:\n  trainer:\n    params:\n      actor_hidden: *a8\n")
    elif kind == "matrix":
        spec.write_text(f"{head}defs:\n{_anchors(7)}\nmatrix:\n  seed: [*a7, 1]\n")
    elif kind == "extends":
        parent = tmp_path / "parent.yaml"
        parent.write_text(f"{head}defs:\n{_anchors(8)}\nmore: *a8\n")
        spec.write_text(f"spec_version: 1\nextends: {parent.name}\n")
    elif kind == "recursive":
        spec.write_text(f"{head}description: &r [1, *r]\n")
    elif kind == "deep_through_aliases":  # 60 lines, each one level deeper than the last, through aliases
        lines = ["  d0: &d0 [1]"] + [f"  d{i}: &d{i} [*d{i - 1}]" for i in range(1, 60)]
        spec.write_text(f"{head}defs:\n" + "\n".join(lines) + "\ndescription: *d59\n")
    assert spec.stat().st_size < 2000
    return spec


@pytest.mark.parametrize("kind", ["key", "actor_hidden", "matrix", "extends", "recursive", "deep_through_aliases"])
def test_a_yaml_alias_bomb_is_refused_before_it_is_expanded(kind, tmp_path):
    spec = _bomb(kind, tmp_path)
    start = time.monotonic()
    for command in (["validate", spec], ["run", spec, "--out", tmp_path / "run"]):
        line = assert_one_line_error(invoke(command), ".yaml")
        assert any(f in line for f in ("stands for more than 100,000 values", "contains it", "levels deep")), line
    assert time.monotonic() - start < 20
    assert not (tmp_path / "run").exists()


def test_a_run_folder_whose_spec_is_an_alias_bomb_is_one_error_line(tmp_path):
    """``mocap eval RUN_DIR`` reads the run's own spec.yaml: through the same bounded loader."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "spec.yaml").write_text(f"spec_version: 1\nname: r\ndefs:\n{_anchors(8)}\n")
    (run / "stages.json").write_text('[{"stage": "imitator"}]')
    assert_one_line_error(invoke(["eval", run]), "spec.yaml", "stands for more than 100,000 values")


def test_bounded_loader_reads_what_plain_safe_load_reads():
    import yaml

    from mocap import safe_yaml

    for spec in sorted(REPO.glob("specs/**/*.yaml")):
        text = spec.read_text()
        assert safe_yaml.load(text) == yaml.safe_load(text), spec
    shared = "a: &x {b: [1, 2]}\nc: *x\nd: {<<: *x, e: 3}\n"  # aliases and merge keys within the limits
    assert safe_yaml.load(shared) == yaml.safe_load(shared)


def test_an_extends_chain_longer_than_64_files_is_one_error_line(tmp_path):
    (tmp_path / "s0.yaml").write_text("spec_version: 1\nname: chain\n")
    for i in range(1, 200):
        (tmp_path / f"s{i}.yaml").write_text(f"extends: s{i - 1}.yaml\n")
    assert_one_line_error(invoke(["validate", tmp_path / "s199.yaml"]), "s199.yaml", "extends", "more than 64 files")
    ok = invoke(["validate", tmp_path / "s30.yaml"])  # a chain of 31 files is fine as far as extends goes
    assert "more than 64 files" not in ok.output


def test_a_set_key_of_20000_parts_is_one_error_line():
    line = assert_one_line_error(invoke(["validate", AMP_BUNDLED, "--set", ".".join(["a"] * 20_000) + "=1"]), "--set", "20,000 parts", "at most 64")
    assert len(line) < 300


def test_a_matrix_of_many_cells_times_a_large_parameter_is_refused_before_the_cells_are_built(tmp_path, monkeypatch):
    import copy

    import mocap.matrix

    calls = {"n": 0}
    real = copy.deepcopy

    def counting(obj, memo=None):
        calls["n"] += 1
        return real(obj, memo)

    spec = tmp_path / "big.yaml"
    values = "{" + ", ".join(f"k{i}: {i}" for i in range(5_000)) + "}"
    spec.write_text(f"spec_version: 1\nextends: {AMP_BUNDLED}\ndescription: x\nbig: {values}\nmatrix:\n  seed: [{', '.join(map(str, range(1000)))}]\n")
    assert spec.stat().st_size < 100_000
    monkeypatch.setattr(mocap.matrix.copy, "deepcopy", counting)
    assert_one_line_error(invoke(["validate", spec]), "matrix", "1,000 cells", "exceed 2,000,000 values")
    assert calls["n"] < 100  # the merge of the spec files, not once per cell


def test_matrix_values_of_300_characters_give_short_distinct_cell_names(tmp_path):
    from mocap.matrix import MAX_CELL_NAME, expand

    doc = {"spec_version": 1, "name": "m", "description": "", "matrix": {"description": ["a" * 300, "a" * 299 + "b", "short"]}}
    cells = expand(doc, tmp_path)
    names = [c.name for c in cells]
    assert len(set(names)) == 3 and all(len(n) <= MAX_CELL_NAME for n in names), names
    assert names[2] == "description-short"
    for name in names:
        (tmp_path / name).mkdir()  # a valid folder name
