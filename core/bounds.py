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
#: most passes over one batch (PPO's ``epochs``)
MAX_EPOCHS = 1000
#: most steps per env per iteration (PPO's ``horizon``)
MAX_HORIZON = 100_000
#: most samples in one batch (``num_envs`` x ``horizon``; PHC's GPU recipe: 49,152): the rollout
#: buffers are allocated whole
MAX_BATCH = 10_000_000
#: the largest training budget, env steps (a trillion: years on any machine)
MAX_ENV_STEPS = 10**12
#: the hidden activations of :data:`mocap.rl.networks.ACTIVATIONS` (its keys), for params that name one
ACTIVATION_NAMES: tuple[str, ...] = ("elu", "relu", "tanh", "silu", "gelu")

ThreadCount = Annotated[int, Field(ge=1, le=MAX_THREADS)]
EnvCount = Annotated[int, Field(ge=1, le=MAX_ENVS)]
LayerWidth = Annotated[int, Field(ge=1, le=MAX_WIDTH)]
LearningRate = Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)]
LogStd = Annotated[float, Field(ge=-20.0, le=5.0, allow_inf_nan=False)]
EpochCount = Annotated[int, Field(ge=1, le=MAX_EPOCHS)]
EnvSteps = Annotated[int, Field(ge=1, le=MAX_ENV_STEPS)]

__all__ = [
    "ACTIVATION_NAMES",
    "MAX_BATCH",
    "MAX_ENVS",
    "MAX_ENV_STEPS",
    "MAX_EPOCHS",
    "MAX_HORIZON",
    "MAX_THREADS",
    "MAX_WIDTH",
    "EnvCount",
    "EnvSteps",
    "EpochCount",
    "LayerWidth",
    "LearningRate",
    "LogStd",
    "ThreadCount",
]
