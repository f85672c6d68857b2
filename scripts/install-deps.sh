#!/usr/bin/env bash
# Installs what a fresh Debian 12 machine lacks to build and run lpmsplat: the Vulkan loader,
# Mesa's lavapipe (a CPU Vulkan driver, so a machine without a GPU runs everything), the
# Khronos validation layer (the tests turn it on) and shaderc with the static glslang /
# SPIRV-Tools archives the build links (see .cargo/config.toml), and g++ (shaderc-sys's build
# needs a C++ compiler; a minimal Debian 12 has none), and Slurm with munge (the partition
# tests start a single-node cluster of their own, scripts/slurm-node.sh; nothing is started
# here). Both README commands call this script first, so they work in either order.
# Idempotent: installs only missing packages.
set -euo pipefail

PACKAGES=(g++ libvulkan1 libvulkan-dev mesa-vulkan-drivers vulkan-validationlayers libshaderc-dev glslang-dev spirv-tools
  slurmctld slurmd slurm-client munge)

need=()
if command -v dpkg >/dev/null 2>&1; then
  for pkg in "${PACKAGES[@]}"; do
    dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
  done
else
  echo "install-deps: no dpkg here (not Debian/Ubuntu). Install your distribution's equivalents of:" >&2
  echo "  ${PACKAGES[*]}" >&2
  echo "  (the Vulkan loader, a Vulkan driver such as Mesa's lavapipe, the validation layer, and" >&2
  echo "   shaderc with glslang and SPIRV-Tools; set SHADERC_LIB_DIR if shaderc lives elsewhere)" >&2
fi

if [ ${#need[@]} -gt 0 ]; then
  echo "install-deps: installing ${need[*]}"
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then
      SUDO="sudo"
    else
      echo "install-deps: not root and no sudo. Ask an administrator to run:" >&2
      echo "  apt-get install ${need[*]}" >&2
      exit 1
    fi
  fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" </dev/null
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "install-deps: cargo is missing. Install the Rust toolchain first:" >&2
  echo "  curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs | sh" >&2
  exit 1
fi
