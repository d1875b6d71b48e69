#!/usr/bin/env bash
# Run the test suite (lint included) with DDS confined to this machine. Called by
# `./suture-lfd test`, which has set up the environment first.
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv=${SUTURE_LFD_VENV:-$repo/.venv}
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-$(( $$ % 90 + 10 ))}
export PYTHONDONTWRITEBYTECODE=1
cd "$repo"
run=("$venv/bin/python" -m pytest -p no:cacheprovider "$@")
# Where we may, run the tests in a private network namespace holding only loopback, so that no
# DDS packet can leave the machine whatever a test does (SUTURE_LFD_NETNS=0 turns this off).
if [ "${SUTURE_LFD_NETNS:-1}" = 1 ] && command -v unshare >/dev/null && command -v ip >/dev/null \
   && unshare -n true 2>/dev/null; then
  exec unshare -n sh -c 'ip link set lo up && exec "$@"' sh "${run[@]}"
fi
exec "${run[@]}"
