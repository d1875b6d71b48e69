#!/usr/bin/env bash
# Start the simulated dVRK (PSM1, PSM2, ECM, scene ground truth, foot pedals, /clock).
#
#   scripts/simulator.sh [--phantom synthetic|scanned|MESH|PHANTOM.yaml] [--scene SCENE.yaml]
#                        [--rtf FACTOR] [--ros-args ...]
#
# MESH: an STL/OBJ/PLY file in metres, z up; its markers mesh1.. are laid on its top surface
# (the log says where). PHANTOM.yaml: mesh, scale, pose, wound line or markers (README).
# Runs until Ctrl-C. ROS_DOMAIN_ID picks the domain (default: derived from the process id);
# discovery stays on this machine.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
phantom=synthetic scene='' rtf=1.0
while [ $# -gt 0 ]; do
  case "$1" in
    --phantom) phantom=$2; shift 2 ;;
    --scene) scene=$2; shift 2 ;;
    --rtf) rtf=$2; shift 2 ;;
    --ros-args) break ;;
    -h|--help) usage; exit 0 ;;
    *) say "unknown option $1"; exit 2 ;;
  esac
done
extra=("$@")
[ ${#extra[@]} -gt 0 ] && extra=("${extra[@]:1}")
phantom_params "$phantom" "$scene" ''
say "ROS_DOMAIN_ID=$ROS_DOMAIN_ID"
start simulator --ros-args "${phantom_args[@]}" -p real_time_factor:="$rtf" "${extra[@]}"
wait_ready simulator 'simulating'
watch_nodes
