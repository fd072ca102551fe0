#!/bin/bash
# Builds .gpu/ (git-ignored through .git/info/exclude) for the device check: Python 3.12 wheels of what the device
# image lacks, SAPIEN and ManiSkill trimmed to fit the 64 MiB the device tool carries (about 59 MiB in all), the
# Vulkan/GL loaders, two committed pick_cube checkpoints, and this harness. Run from the repository root, then:
#   git rm -r -q --cached results && echo /results/ >> .git/info/exclude   # results/ (73 MiB) must not travel
#   device run: command "bash .gpu/run.sh", carry [".gpu"], timeout_s 470
#   git reset -q && sed -i '/^\/results\/$/d' .git/info/exclude           # afterwards: the index as it was
set -euo pipefail
G=.gpu; T=$(mktemp -d); mkdir -p $G/whl $G/gl
grep -qx "/.gpu/" .git/info/exclude || echo "/.gpu/" >> .git/info/exclude
PLAT="--only-binary=:all: --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform manylinux1_x86_64"
python3 -m pip download -q --no-deps $PLAT -d $T sapien==3.0.3 mani_skill==3.0.1
python3 -m pip download -q --no-deps $PLAT -d $G/whl torchrl==0.14.1 tensordict==0.14.3 hydra-core==1.3.8 omegaconf==2.3.1 \
  gymnasium==1.4.0 farama-notifications==0.0.6 transforms3d==0.4.2 trimesh==5.2.0 dacite==1.9.2 defusedxml==0.7.1 \
  pyvers==0.2.3 hoptorch==0.1.4 orjson==3.13.0 pytorch_kinematics==0.7.6 arm_pytorch_utilities==0.5.0 pytorch_seed==0.2.0 \
  GitPython==3.2.1 gitdb==4.0.12 smmap==5.0.3 tyro==1.0.17 docstring_parser==0.18.0 typeguard==4.6.1 pyperclip==1.11.0 \
  importlib_metadata==10.2.0 importlib_resources==7.1.0
python3 -m pip wheel -q --no-deps -w $G/whl antlr4-python3-runtime==4.9.3   # an sdist only: built here (pure Python)
# SAPIEN without its C++ headers, examples, depth-sensor patterns and OIDN's CUDA denoiser (not used for state)
(mkdir $T/sap && cd $T/sap && python3 -m zipfile -e ../sapien-3.0.3-*.whl . && rm -rf sapien/include sapien/example \
  sapien/sensor/assets/patterns sapien/oidn_library/*device_cuda* && python3 -m zipfile -c sapien.zip sapien sapien.libs sapien-3.0.3.dist-info)
mv $T/sap/sapien.zip $G/
# ManiSkill with the Panda robot only (pick_cube), no environment maps or large scene textures
(mkdir $T/ms && cd $T/ms && python3 -m zipfile -e ../mani_skill-3.0.1-*.whl . && cd mani_skill && rm -rf examples \
  assets/environment_maps assets/maniskill2-scene-2.glb assets/robots/panda/realsense2_description \
  assets/robots/panda/sciurus17_description utils/scene_builder/replicacad/autumn_field_puresky_4k.hdr \
  utils/scene_builder/kitchen_counter/assets/kitchen_counter.glb && find assets/robots -maxdepth 1 -mindepth 1 ! -name panda \
  -exec rm -rf {} + && cd .. && python3 -m zipfile -c mani_skill.zip mani_skill mani_skill-3.0.1.dist-info)
mv $T/ms/mani_skill.zip $G/
o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'; mkdir -p /tmp/amd64/partial
apt-get $o update -qq && (cd $G/gl && apt-get $o download -qq libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
cp results/reuse/pick_cube/run_files/learn-sacdemos_s0/reward.pt $G/ckpt_reward.pt
cp results/reuse/pick_cube/run_files/learn-sacdemos_s0/policy.pt $G/ckpt_policy.pt
cp -r results/gpu/harness/run.sh results/gpu/harness/app.py results/gpu/harness/shims $G/
rm -rf $T; du -sh $G
