#!/usr/bin/env bash
# The GPU checks of the `mujoco_warp` simulator (docs/simulators.md), for a machine with an NVIDIA GPU,
# `pip install -e '.[warp]'` and a CUDA build of torch. Usage: bash tools/gpu_check.sh [OUT_DIR]
# Writes into OUT_DIR (default gpu_check/): env.txt (devices, versions), tests.log (the slow
# tests/test_sim_mujoco_warp.py on cuda for the amp model: parity with `mujoco`, resets, instability,
# a PPO run through `mocap run`; smpl, props and terrain compile kernels of their own and are left to
# a longer run), sim_throughput_warp_gpu.json (amp: env steps/s of `mujoco_warp` on the GPU against
# `mujoco` on this machine's CPU cores, and large N on the GPU alone) and ppo_gpu.log
# (the learning loop: the PHC imitator's PPO with 4096 worlds on the GPU, state copied to the CPU).
# Each step writes its file as it goes, so a run stopped by a time limit still leaves what it did.
set -u
OUT=${1:-gpu_check}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
step() { echo "== $(date +%T) $*"; }

step environment
{
  nvidia-smi -L
  nproc
  python -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), torch.cuda.get_device_name(0))"
  python -c "import mujoco, mujoco_warp, warp as wp; wp.init(); print('mujoco', mujoco.__version__, 'mujoco_warp', mujoco_warp.__version__, 'warp', wp.__version__, [str(d) for d in wp.get_devices()])"
} 2>&1 | tee "$OUT/env.txt"

step "slow tests on cuda (the first compiles Warp's kernels)"
# the amp humanoid only (MuJoCo Warp specializes kernels per model: smpl and terrain compile their own)
MOCAP_WARP_TEST_DEVICE=cuda timeout 240 python -m pytest -m slow tests/test_sim_mujoco_warp.py -k "(parity and amp) or unstable or reset_subset or ppo_imitator" \
  -s -q -p no:cacheprovider 2>&1 | grep -v "^Module .* took" | tee "$OUT/tests.log"

step "throughput: mujoco_warp on the GPU vs mujoco on all CPU cores"
timeout 150 python bench/sim_throughput.py --warp --warp-device cuda --humanoids amp --sizes 1024 4096 --repeats 2 --env-steps 400000 \
  --out "$OUT/sim_throughput_warp_gpu.json" 2>&1 | grep -v "^Module .* took" | tee "$OUT/throughput.log"
timeout 90 python bench/sim_throughput.py --warp --warp-only --warp-device cuda --humanoids amp --sizes 16384 65536 --repeats 2 --env-steps 4000000 \
  --out "$OUT/sim_throughput_warp_gpu_large.json" 2>&1 | grep -v "^Module .* took" | tee -a "$OUT/throughput.log"

step "learning loop: PPO imitator, 4096 worlds on the GPU"
cat > "$OUT/ppo_gpu.yaml" <<'SPEC'
spec_version: 1
name: ppo-gpu
seed: 0
humanoid: {name: amp}
motions: {name: deepmimic}
simulator: {name: mujoco_warp, params: {device: cuda, state_device: cpu}}
imitator:
  name: phc
  params: {obs: rot, action: residual, eval_every: 0}
  trainer:
    name: ppo
    params: {num_envs: 4096, horizon: 32, total_env_steps: 393216, epochs: 2, minibatch_size: 16384,
             actor_hidden: [1024, 512], critic_hidden: [1024, 512], checkpoint_every: 100}
SPEC
timeout 100 mocap run "$OUT/ppo_gpu.yaml" --out "$OUT/ppo_run" 2>&1 | grep -v "^Module .* took" | tee "$OUT/ppo_gpu.log"
step done
