#!/usr/bin/env bash
# A person demonstrates a throw: simulator (real time), viewer, virtual MTMs, two teleop nodes
# (MTMR -> PSM2, the right arm; MTML -> PSM1, the left arm) and the recorder, on this machine.
#
#   scripts/demonstrate.sh --device browser|gamepad|spacemouse|console [--pair synth1]
#                          [--out DIR] [--record-pedal camera|coag] [--no-align]
#                          [--phantom NAME|MESH|PHANTOM.yaml] [--scene SCENE.yaml]
#
# Prints the viewer's URL and where the bags go. Press coag (operator present) and pinch the
# gripper once to start following; hold the clutch to recentre the hands. The camera pedal (the
# gamepad's Y, a SpaceMouse's third button, the page's record control) starts and stops a
# recording; --record-pedal coag makes the coag pedal do it, as the paper's users did. Segment
# and learn the bags with scripts/segment_bag.sh and scripts/learn_and_execute.sh. Ctrl-C stops.
# --device console: a physical dVRK console's MTMs and pedals on this ROS_DOMAIN_ID (DDS then
# discovers beyond this machine); no virtual MTMs. --phantom defaults to the phantom the pair's
# name starts with (scan* scanned, synth* synthetic).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
device='' pair=synth1 out=demonstrations record_pedal=camera align=true phantom='' scene=''
while [ $# -gt 0 ]; do
  case "$1" in
    --device) device=$2; shift 2 ;;
    --pair) pair=$2; shift 2 ;;
    --phantom) phantom=$2; shift 2 ;;
    --scene) scene=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --record-pedal) record_pedal=$2; shift 2 ;;
    --no-align) align=false; shift ;;
    -h|--help) usage; exit 0 ;;
    *) say "unknown option $1"; exit 2 ;;
  esac
done
case "$device" in
  browser|gamepad|spacemouse) ;;
  console) export ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET ;;
  *) say "--device must be browser, gamepad, spacemouse or console"; exit 2 ;;
esac
case "$record_pedal" in
  camera|coag) ;;
  *) say "--record-pedal must be camera or coag"; exit 2 ;;
esac
phantom_params "$phantom" "$scene" "$pair"
mkdir -p "$out"
out=$(cd "$out" && pwd)
say "ROS_DOMAIN_ID=$ROS_DOMAIN_ID"
start simulator --ros-args "${phantom_args[@]}" -p target_pair:="$pair" \
  -p real_time_factor:=1.0 -p footpedals:=false
if [ -x "$venv/bin/viewer" ]; then
  start viewer --ros-args -p phantom:="$phantom" -p view:=endoscope
  url=''
  for _ in $(seq 1 300); do
    check_children
    url=$(grep -o 'http://[^ ]*' "$LOG_DIR/viewer.log" | head -1 || true)
    [ -n "$url" ] && break
    sleep 0.2
  done
  say "viewer: ${url:-see $LOG_DIR/viewer.log} (over SSH: ssh -L 8080:localhost:8080 <host>)"
elif [ "$device" = browser ]; then
  say "the viewer executable is not installed in this checkout: the browser device needs its"
  say "page; use --device gamepad or --device spacemouse, or update and re-run tools/setup.sh"
  exit 1
else
  say "no viewer in this checkout: you will not see the scene (the bag is recorded anyway)"
fi
if [ "$device" != console ]; then
  start mtms --ros-args -p device:="$device"
fi
start --as teleop_MTMR_PSM2 teleop --ros-args -r __node:=MTMR_PSM2 -p mtm:=MTMR -p psm:=PSM2 \
  -p align_mtm:="$align"
start --as teleop_MTML_PSM1 teleop --ros-args -r __node:=MTML_PSM1 -p mtm:=MTML -p psm:=PSM1 \
  -p align_mtm:="$align"
start recorder --ros-args -p output_dir:="$out" -p use_sim_time:=true \
  -p toggle_pedal:=/footpedals/"$record_pedal"
say "pair $pair; press the $record_pedal pedal to start and stop a recording"
say "bags go to $out/"
printf '%s\n' "$out"
watch_nodes
