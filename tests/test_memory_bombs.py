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


# ------------------------------------------------------------------ checkpoints (zip records, allocating globals)
def _crafted_checkpoint(path: Path, obj: object, records: dict[str, bytes], *, deflate: bool = False) -> Path:
    """A torch zip checkpoint whose pickle is ``obj`` written with :class:`_Storage` placeholders as
    storages (persistent ids), and whose records are ``records`` (key -> bytes)."""
    import io
    import pickle
    import zipfile

    import torch

    class Pickler(pickle.Pickler):
        def persistent_id(self, obj):
            return ("storage", torch.FloatStorage, obj.key, "cpu", obj.numel) if isinstance(obj, _Storage) else None

    buffer = io.BytesIO()
    Pickler(buffer, protocol=2).dump(obj)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED) as archive:
        archive.writestr("archive/data.pkl", buffer.getvalue())
        archive.writestr("archive/byteorder", "little")
        for key, raw in records.items():
            archive.writestr(f"archive/data/{key}", raw)
        archive.writestr("archive/version", "3\n")
    return path


class _Storage:
    def __init__(self, numel: int, key: str = "0"):
        self.numel, self.key = numel, key


class _Tensor:
    def __init__(self, storage: _Storage, size: tuple[int, ...]):
        self.storage, self.size = storage, size

    def __reduce__(self):
        import collections

        import torch

        return (torch._utils._rebuild_tensor_v2, (self.storage, 0, self.size, (1,) * len(self.size), False, collections.OrderedDict()))


class _Call:
    def __init__(self, fn: object, args: tuple):
        self.fn, self.args = fn, args

    def __reduce__(self):
        return (self.fn, self.args)


def test_a_checkpoint_calling_bytearray_with_a_huge_size_is_refused_before_loading(tmp_path):
    import torch

    size = 300_000_000  # the fuzz campaign's was 4.5e9; smaller here, so that a regression costs a test run little
    direct = _crafted_checkpoint(tmp_path / "direct.pt", {"x": _Call(bytearray, (size,))}, {})
    through = _crafted_checkpoint(tmp_path / "through.pt", {"x": _Call(torch._tensor._rebuild_from_type_v2, (bytearray, torch.Tensor, (size,), {}))}, {})
    for path in (direct, through):
        assert path.stat().st_size < 1000
        assert_one_line_error(invoke(["eval", path]), str(path), "refused", "builtins.bytearray")


def test_a_checkpoint_whose_records_unpack_far_beyond_its_size_is_refused_before_torch_reads_it(tmp_path, monkeypatch):
    import mocap.checkpoint
    import mocap.pickle_scan

    n = 4_000_000  # 16 MB of zeros, deflated to about 16 kB
    path = _crafted_checkpoint(tmp_path / "bomb.pt", {"w": _Tensor(_Storage(n), (n,))}, {"0": bytes(4 * n)}, deflate=True)
    monkeypatch.setattr(mocap.checkpoint, "UNPACK_SLACK", 2**20)  # the real slack is 256 MiB: the same refusal at a test's size
    monkeypatch.setattr(mocap.checkpoint.torch, "load", None)  # torch must not read it
    assert path.stat().st_size < 100_000
    assert_one_line_error(invoke(["eval", path]), str(path), "refused: its records unpack to 16,000,", "archive/data/0 alone")
    monkeypatch.setattr(mocap.pickle_scan, "MAX_PICKLE_BYTES", 100)
    monkeypatch.setattr(mocap.checkpoint, "UNPACK_SLACK", 2**30)
    assert_one_line_error(invoke(["eval", path]), str(path), "refused: its pickle archive/data.pkl is")


@pytest.mark.parametrize("case", ["storage_beyond_record", "tensor_beyond_storage"])
def test_a_checkpoint_that_rebuilds_a_tensor_beyond_its_record_is_one_error_line(tmp_path, case):
    n = 1_200_000_000  # 4.8 GB of float32
    storage = _Storage(n if case == "storage_beyond_record" else 1)
    path = _crafted_checkpoint(tmp_path / "big.pt", {"w": _Tensor(storage, (n,))}, {"0": bytes(4)})
    assert_one_line_error(invoke(["eval", path]), str(path))


def test_committed_checkpoints_pass_the_archive_check():
    from committed import committed_files

    from mocap.checkpoint import _check_archive

    paths = committed_files("checkpoints", "**/*.pt")
    assert len(paths) > 20
    for path in paths:
        _check_archive(path)
