#!/usr/bin/env bash
# Idempotent set-up for a fresh Debian machine: system packages, .venv/, torch first, then the project.
# A second run finds everything in place and returns in about a second.
set -euo pipefail
cd "$(dirname "$0")/.."

apt_packages=(libusb-1.0-0 libgl1 libgomp1 prusa-slicer liburdfdom-tools)
missing=()
for p in "${apt_packages[@]}"; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if (( ${#missing[@]} )); then
  echo "setup: installing system packages: ${missing[*]}" >&2
  sudo_cmd=""; [[ $(id -u) == 0 ]] || sudo_cmd="sudo"
  $sudo_cmd apt-get update -q >/dev/null
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null
fi

if [[ ! -x .venv/bin/python ]]; then
  echo "setup: creating .venv" >&2
  python3 -m venv .venv
  .venv/bin/python -m pip install -q --upgrade pip wheel
fi

# torch first: with no torch present, a plain dependency on it would pull several GB of CUDA wheels.
if ! .venv/bin/python -c "import torch" >/dev/null 2>&1; then
  echo "setup: installing torch==2.13.0" >&2
  .venv/bin/python -m pip install -q torch==2.13.0
fi

stamp=.venv/.spare-twin-setup
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [[ ! -f $stamp || $(cat "$stamp") != "$want" ]]; then
  echo "setup: installing spare-twin and its dependencies into .venv" >&2
  .venv/bin/python -m pip install -q -e ".[test]"
  echo "$want" > "$stamp"
fi

# The project's own bytecode, compiled once here (a no-op while it is current): where
# PYTHONDONTWRITEBYTECODE is set, as on the development machines, Python would otherwise compile every
# spare_twin module again in each new process, about 1 s of every command and test subprocess.
.venv/bin/python -m compileall -q spare_twin >/dev/null
