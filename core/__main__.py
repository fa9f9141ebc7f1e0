"""``python -m mocap`` = the ``mocap`` command; also what ``torchrun ... -m mocap run SPEC`` starts on
every rank (see :mod:`mocap.distributed`). Ranks other than 0 of such a launch print nothing on
stdout (errors still go to stderr)."""

import os
import sys

if os.environ.get("WORLD_SIZE", "1") not in ("", "0", "1") and os.environ.get("RANK", "0") not in ("", "0"):
    sys.stdout = open(os.devnull, "w", encoding="utf-8")  # noqa: SIM115 - for the life of the process

from mocap.cli import main

sys.exit(main())
