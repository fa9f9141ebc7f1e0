"""The globals a checkpoint's pickle names, read without unpickling anything.

When PyTorch's restricted (``weights_only``) load refuses a file, its message does not always say
why: a pickle of protocol 4 or 5 fails on an opcode the restricted unpickler does not read before
it reaches the global (``Unsupported operand 149``), which reads like a corrupt file. This module
walks the pickle's opcodes (:func:`pickletools.genops`, which executes nothing) and lists the
globals it names, so that :func:`mocap.checkpoint.load_checkpoint` can say "refused: the checkpoint
names the global builtins.print" instead of "corrupt or truncated".
"""

from __future__ import annotations

import pickletools
import zipfile
from pathlib import Path
from typing import Any

#: the most bytes of a ``data.pkl`` read (a checkpoint's pickle holds metadata, not tensor data)
MAX_PICKLE_BYTES = 64 * 2**20
#: globals a restricted load accepts in a mocap checkpoint (besides ``torch.*``)
PLAIN_GLOBALS = frozenset({"collections.OrderedDict", "builtins.set", "builtins.frozenset"})
#: modules of the objects :func:`mocap.checkpoint.convert_checkpoint` makes safe (an older mocap checkpoint)
CONVERTIBLE_MODULES = ("numpy", "collections")

_STRINGS = {"SHORT_BINUNICODE", "BINUNICODE", "BINUNICODE8", "UNICODE", "SHORT_BINSTRING", "BINSTRING", "STRING"}


def _globals_in(raw: bytes) -> list[str]:
    """``module.name`` of every GLOBAL / STACK_GLOBAL in one pickle, in order (as far as it parses)."""
    found: list[str] = []
    stack: list[Any] = []  # the recent strings (None: another object), enough for STACK_GLOBAL's two operands
    memo: dict[int, Any] = {}
    try:
        for op, arg, _ in pickletools.genops(raw):
            name = op.name
            if name in _STRINGS:
                stack.append(arg if isinstance(arg, str) else None)
            elif name == "GLOBAL" and isinstance(arg, str):
                found.append(arg.replace(" ", "."))
                stack.append(None)
            elif name == "STACK_GLOBAL":
                module, attr = (stack[-2], stack[-1]) if len(stack) >= 2 else (None, None)
                found.append(f"{module}.{attr}" if isinstance(module, str) and isinstance(attr, str) else "an unnamed global")
                stack.append(None)
            elif name == "MEMOIZE":
                memo[len(memo)] = stack[-1] if stack else None
            elif name in ("BINPUT", "LONG_BINPUT", "PUT") and isinstance(arg, int):
                memo[arg] = stack[-1] if stack else None
            elif name in ("BINGET", "LONG_BINGET", "GET") and isinstance(arg, int):
                stack.append(memo.get(arg))
            elif name not in ("FRAME", "PROTO"):
                stack.append(None)
            del stack[:-8]
    except Exception:  # noqa: BLE001 - a damaged pickle: what was read so far
        pass
    return found


def pickled_globals(path: Path) -> list[str]:
    """The globals named by the pickles (``*/data.pkl``) of a zip checkpoint at ``path``, in order
    ([] for a file that is no zip, or that cannot be read)."""
    names: list[str] = []
    try:
        with zipfile.ZipFile(path) as archive:
            for info in [i for i in archive.infolist() if i.filename.endswith("data.pkl")][:4]:
                with archive.open(info) as fh:
                    names += _globals_in(fh.read(MAX_PICKLE_BYTES))
    except Exception:  # noqa: BLE001 - no zip, a damaged one: nothing to name
        return []
    return names


def refused_global(path: Path) -> str | None:
    """The first global in the checkpoint at ``path`` that a restricted load does not build (not
    ``torch.*`` nor a plain container), or None when it names none."""
    for name in pickled_globals(path):
        if not (name.startswith("torch.") or name in PLAIN_GLOBALS):
            return name
    return None


#: globals torch's restricted load accepts that allocate whatever size their arguments name (a
#: pickle of 400 bytes calling ``bytearray(4_500_000_000)``; a quantized, nested, sparse or wrapper
#: tensor built at a size of its own): a mocap checkpoint holds none of them
ALLOCATING_GLOBALS = frozenset(
    {
        "builtins.bytearray",
        "torch._utils._rebuild_qtensor",
        "torch._utils._rebuild_nested_tensor",
        "torch._utils._rebuild_sparse_tensor",
        "torch._utils._rebuild_wrapper_subclass",
    }
)


def allocating_global(path: Path) -> str | None:
    """The first global of :data:`ALLOCATING_GLOBALS` the checkpoint at ``path`` names, or None."""
    for name in pickled_globals(path):
        if name.startswith("__builtin__."):  # the Python 2 name a protocol-2 pickle writes (torch reads it as builtins)
            name = "builtins." + name[len("__builtin__.") :]
        if name in ALLOCATING_GLOBALS:
            return name
    return None


def convertible(name: str) -> bool:
    """Whether a refused global is one an older mocap checkpoint held (a NumPy array or scalar,
    a deque): :func:`mocap.checkpoint.convert_checkpoint` makes such a file safe."""
    return name.split(".")[0] in CONVERTIBLE_MODULES


__all__ = ["ALLOCATING_GLOBALS", "MAX_PICKLE_BYTES", "allocating_global", "convertible", "pickled_globals", "refused_global"]
