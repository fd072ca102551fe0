#!/usr/bin/env bash
# Idempotent set-up of drs-torchrl on a fresh Debian 12 machine (or any machine with Python 3.10+).
#   1. a usable Vulkan driver (SAPIEN needs one even for state observations): if no GPU Vulkan
#      driver is present, install Mesa's software driver (lavapipe) from bookworm-backports;
#      Debian 12's own Mesa 22.3 is too old (no descriptorBindingPartiallyBound).
#   2. .venv at the repository root (python3-venv installed if missing, as root) with torch 2.13.0 first (the
#      CPU build where there is no NVIDIA GPU), then the project.
# Usage: bin/setup.sh            (as root for step 1 on a machine without Vulkan)
# Env:   DRS_SKIP_VULKAN=1 skips step 1; PYTHON=python3.11 picks the interpreter; TORCH_CPU_INDEX another CPU index.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
PYTHON=${PYTHON:-python3}
TORCH_VERSION=${TORCH_VERSION:-2.13.0}
TORCH_CPU_INDEX=${TORCH_CPU_INDEX:-https://download.pytorch.org/whl/cpu}

log() { printf '[setup] %s\n' "$*"; }

have_gpu_vulkan() {
  # NVIDIA's driver registers its own ICD; Mesa's radv/anv need a real GPU render node.
  # (Mesa's package ships intel/radeon ICD files even without such a GPU: they do not count.)
  local d
  for d in /usr/share/vulkan/icd.d /etc/vulkan/icd.d; do
    ls "$d" 2>/dev/null | grep -iq 'nvidia' && return 0
  done
  # a real GPU with Mesa >= 24 (older Mesa can leave only a too-old lavapipe usable, e.g. on virtio-gpu)
  local v
  v=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
  if ls /dev/dri/renderD* >/dev/null 2>&1 && [ -n "$v" ] && dpkg --compare-versions "$v" ge 24; then
    return 0
  fi
  return 1
}

have_recent_lavapipe() {
  local v
  v=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
  [ -n "$v" ] || return 1
  dpkg --compare-versions "$v" ge 24 && ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 \
    && dpkg-query -W libvulkan1 >/dev/null 2>&1
}

install_lavapipe() {
  if [ "$(id -u)" != 0 ]; then
    log "no usable Vulkan driver and not root. Run as root, or install it yourself:"
    log "  echo 'deb http://deb.debian.org/debian bookworm-backports main' > /etc/apt/sources.list.d/backports.list"
    log "  apt-get update && apt-get install -y -t bookworm-backports mesa-vulkan-drivers libvulkan1"
    exit 1
  fi
  if ! command -v apt-get >/dev/null; then
    log "no apt-get: install a Vulkan driver (Mesa >= 24 lavapipe, or your GPU's) by hand"; exit 1
  fi
  . /etc/os-release
  if [ "${VERSION_CODENAME:-}" = bookworm ]; then
    if ! grep -rqs 'bookworm-backports' /etc/apt/sources.list /etc/apt/sources.list.d/; then
      log "adding bookworm-backports"
      echo 'deb http://deb.debian.org/debian bookworm-backports main' > /etc/apt/sources.list.d/drs-backports.list
    fi
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null
  else
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
  fi
  log "installed $(dpkg-query -W -f='mesa-vulkan-drivers ${Version}' mesa-vulkan-drivers)"
}

if [ "${DRS_SKIP_VULKAN:-0}" = 1 ]; then
  log "skipping the Vulkan check (DRS_SKIP_VULKAN=1)"
elif have_gpu_vulkan; then
  log "GPU Vulkan driver found; system packages left alone"
elif have_recent_lavapipe; then
  log "software Vulkan (lavapipe) already installed"
else
  install_lavapipe
fi

if ! "$PYTHON" -c "import ensurepip" 2>/dev/null; then  # Debian ships venv's pip apart: python3-venv
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    pkg="python$("$PYTHON" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')-venv"
    log "installing $pkg (venv needs it)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$pkg" >/dev/null
  else
    log "$PYTHON cannot make a virtual environment with pip: install python3-venv (as root: apt-get install python3-venv)"
    exit 1
  fi
fi
if ! command -v g++ >/dev/null && ! command -v c++ >/dev/null; then  # torch.compile's CPU backend builds C++
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    log "installing g++ (algo.compile on a CPU, and its test, compile C++)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq g++ >/dev/null
  else
    log "no C++ compiler: algo.compile on a CPU (and its test) needs one (as root: apt-get install g++)"
  fi
fi
if [ -x .venv/bin/python ] && ! .venv/bin/python -m pip --version >/dev/null 2>&1; then
  log ".venv has no pip (an earlier venv creation failed half-way): making it again"
  rm -rf .venv
fi
if [ ! -x .venv/bin/python ]; then
  log "creating .venv with $($PYTHON --version)"
  "$PYTHON" -m venv .venv
fi
py=.venv/bin/python
if ! $py -c "import torch,sys; sys.exit(0 if torch.__version__.startswith('$TORCH_VERSION') else 1)" 2>/dev/null; then
  # PyPI's Linux torch is the CUDA build (several GB of nvidia-* packages): without an NVIDIA GPU take the CPU build,
  # from a wheel on disk (pip's find-links) or PyTorch's CPU index where that is reachable; else PyPI's
  spec="torch==$TORCH_VERSION" extra=()
  if ! command -v nvidia-smi >/dev/null; then
    if timeout 20 $py -c "import urllib.request; urllib.request.urlopen('$TORCH_CPU_INDEX/', timeout=10)" 2>/dev/null; then
      extra=(--extra-index-url "$TORCH_CPU_INDEX")
    fi
    if $py -m pip install -q "${extra[@]}" "torch==$TORCH_VERSION+cpu" 2>/dev/null; then
      spec=""
      log "installed torch==$TORCH_VERSION+cpu (the CPU build)"
    fi
  fi
  if [ -n "$spec" ]; then
    log "installing $spec"
    $py -m pip install -q "$spec"
  fi
fi
log "installing drs-torchrl with its test, locomotion (MuJoCo) and docs (mkdocs) extras"
$py -m pip install -q -e ".[test,locomotion,docs]"
log "checking the simulator"
.venv/bin/drs-doctor
log "done. Activate with: source .venv/bin/activate"
