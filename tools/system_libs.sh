#!/usr/bin/env bash
# Debian packages that the bpy module loads at import or render time. Installs what is missing when it can
# (root + apt-get), otherwise names the command to run.
set -euo pipefail
packages=(libvulkan1 libx11-6 libxrender1 libxfixes3 libxi6 libxkbcommon0 libsm6 libgl1 libegl1 libgl1-mesa-dri)
command -v dpkg-query >/dev/null || { echo "system-libs: not a Debian system; make sure these are installed: ${packages[*]}"; exit 0; }
missing=()
for package in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed" || missing+=("$package")
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "system-libs: missing ${missing[*]}"
if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null; then
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then
  sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
else
  echo "system-libs: run as root: apt-get update && apt-get install -y ${missing[*]}" >&2
  exit 1
fi
