"""Bounded field types shared by the spec models: values that validate also run.

A spec that validates and then crashes at run start (a negative layer width, a learning rate of
1e300, ``torch_threads: 100000``, which segfaults) is a validation bug: these types reject such
values with the field's name, before anything is built.
"""

from __future__ import annotations

import os
from typing import Annotated

from pydantic import Field

#: most torch intra-op threads a stage may ask for: a generous multiple of this machine's cores
MAX_THREADS = max(8, 4 * (os.cpu_count() or 1))
#: most parallel environments of one process (GPU simulators run thousands; 10^5 on a CPU runs for minutes per step)
MAX_ENVS = 65536
#: widest hidden layer
MAX_WIDTH = 65536
#: the hidden activations of :data:`mocap.rl.networks.ACTIVATIONS` (its keys), for params that name one
ACTIVATION_NAMES: tuple[str, ...] = ("elu", "relu", "tanh", "silu", "gelu")

ThreadCount = Annotated[int, Field(ge=1, le=MAX_THREADS)]
EnvCount = Annotated[int, Field(ge=1, le=MAX_ENVS)]
LayerWidth = Annotated[int, Field(ge=1, le=MAX_WIDTH)]
LearningRate = Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)]
LogStd = Annotated[float, Field(ge=-20.0, le=5.0, allow_inf_nan=False)]

__all__ = ["ACTIVATION_NAMES", "MAX_ENVS", "MAX_THREADS", "MAX_WIDTH", "EnvCount", "LayerWidth", "LearningRate", "LogStd", "ThreadCount"]
