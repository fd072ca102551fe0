#!/bin/bash
# Device check of the GPU path (README "GPU"): learner on CUDA fed by the CPU simulation, precisions, a CPU-trained
# reward and policy loaded onto CUDA, and the CPU learner on the same machine for comparison. Run by the device tool.
R=$PWD; PY=${PY:-python3}; L=$OUT/log.txt; W=/tmp/gpuruns; mkdir -p $W
exec > >(tee -a $L) 2>&1
t0=$(date +%s); stamp() { echo "=== [$(( $(date +%s) - t0 ))s] $*"; }
stamp install
for f in .gpu/gl/*.deb; do dpkg -x $f /; done; ldconfig
python3 -m pip install -q --upgrade --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .gpu/whl/*.whl || exit 1
python3 -m zipfile -e .gpu/sapien.zip /tmp/site && python3 -m zipfile -e .gpu/mani_skill.zip /tmp/site || exit 1; chmod -R u+x /tmp/site/sapien.libs /tmp/site/sapien/*.so 2>/dev/null
export PYTHONPATH=$R/.gpu/shims:/tmp/site:$R/src PYTHONUNBUFFERED=1 RL_WARNINGS=0
ICD=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json; [ -f $ICD ] && export VK_DRIVER_FILES=$ICD
EGLV=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json; [ -f $EGLV ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$EGLV
nvidia-smi -L; nproc; python3 --version
python3 -c "import torch, numpy, sapien, mani_skill, torchrl, tensordict; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), torch.cuda.get_device_name(0), 'numpy', numpy.__version__, 'sapien', sapien.__version__, 'torchrl', torchrl.__version__, 'tensordict', tensordict.__version__)"
stamp doctor; timeout 90 $PY -c 'from drs_torchrl.envs.doctor import main; main()' 2>&1 | tail -25
run() { name=$1; lim=$2; shift 2; stamp "$name: $*"; d="hydra.run.dir=$W/$name"; case "$*" in *resume=*) d=;; esac
  s=$(date +%s); timeout $lim $PY .gpu/app.py "$@" $d logger.progress_bar=false > $W/$name.log 2>&1; rc=$?; tail -12 $W/$name.log
  echo "$name exit $rc wall $(( $(date +%s) - s )) s"; }
P="algo=sac_paper total_frames=6000 algo.learning_starts=2000 eval.episodes=2 eval.interval=3000 checkpoint_interval=3000 seed=0"
run cuda_auto 150 learn_main device=cuda $P
run cpu_fp32 150 learn_main device=cpu algo.precision=fp32 $P
run reuse_finetune_cuda 120 reuse_main device=cuda algo=sac_cpu total_frames=3000 algo.learning_starts=1000 eval.episodes=2 eval.interval=1500 checkpoint_interval=1500 reward=drs reward.checkpoint=$R/.gpu/ckpt_reward.pt init_from=$R/.gpu/ckpt_policy.pt seed=0
run cuda_resume 90 learn_main resume=$W/cuda_auto total_frames=8000
run cuda_fp32 120 learn_main device=cuda algo.precision=fp32 $P
run cuda_fp16 120 learn_main device=cuda algo.precision=fp16 $P
run cuda_gpusim 90 learn_main device=cuda env.sim_backend=physx_cuda env.num_envs=16 algo=sac_paper total_frames=2048 algo.learning_starts=512 eval.episodes=0 seed=0
stamp pack
cd $W && tar czf $OUT/gpu_runs.tar.gz --exclude='state' --exclude='replay*' . ; ls -la $OUT
