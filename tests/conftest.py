import os
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
os.environ.setdefault("MUJOCO_GL", "egl")
torch.set_num_threads(1)


@pytest.fixture
def toy_plugins():
    """The installed plugins plus the throw-away ``toy`` plugin, as the process-wide set."""
    from toy_plugins import CountTrainer, toy

    from mocap.testing import use_plugins

    CountTrainer.calls.clear()
    with use_plugins(("toy", toy)) as pset:
        yield pset


@pytest.fixture(scope="session")
def amp():
    """The default ``amp`` skeleton (shared: skeletons are immutable)."""
    from mocap.humanoids.amp import amp_skeleton

    return amp_skeleton()


@pytest.fixture(scope="session")
def smpl():
    from mocap.humanoids.smpl import smpl_skeleton

    return smpl_skeleton()


def load_bench(name: str):
    """The script ``bench/<name>.py`` imported as a module (bench/ is not a package)."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "bench" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
