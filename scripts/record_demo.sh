#!/usr/bin/env bash
# Record one demonstration: simulator + recorder + a synthetic subject teleoperating one throw.
#
#   scripts/record_demo.sh [--subject S01] [--pair synth1] [--seed 0] [--cohort-seed 0]
#                          [--out DIR] [--rtf FACTOR] [--no-simulator]
#                          [--phantom NAME|MESH|PHANTOM.yaml] [--scene SCENE.yaml]
#
# The subject presses the recorder's toggle pedal (/footpedals/camera) before the throw and
# again after it, so the bag holds exactly one demonstration. Prints the bag directory on
# stdout and the subject's result (JSON) on stderr; exit code 0 when the throw scored 1.0.
# --no-simulator uses a simulator already running on ROS_DOMAIN_ID. --phantom defaults to the
# phantom the pair's name starts with (scan* scanned, synth* synthetic).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
subject=S01 pair=synth1 seed=0 cohort_seed=0 out=demonstrations rtf=1.0 simulator=1 phantom='' scene=''
while [ $# -gt 0 ]; do
  case "$1" in
    --subject) subject=$2; shift 2 ;;
    --pair) pair=$2; shift 2 ;;
    --seed) seed=$2; shift 2 ;;
    --cohort-seed) cohort_seed=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --rtf) rtf=$2; shift 2 ;;
    --phantom) phantom=$2; shift 2 ;;
    --scene) scene=$2; shift 2 ;;
    --no-simulator) simulator=0; shift ;;
    -h|--help) usage; exit 0 ;;
    *) say "unknown option $1"; exit 2 ;;
  esac
done
mkdir -p "$out"
out=$(cd "$out" && pwd)
if [ "$simulator" = 1 ]; then
  phantom_params "$phantom" "$scene" "$pair"
  start simulator --ros-args "${phantom_args[@]}" -p real_time_factor:="$rtf" \
    -p target_pair:="$pair"
fi
start recorder --ros-args -p output_dir:="$out" -p use_sim_time:=true
run demonstrator --ros-args -p subject:="$subject" -p pair:="$pair" -p seed:="$seed" \
  -p cohort_seed:="$cohort_seed"
status=$run_status
# the demonstrator's result: its one JSON line on standard output
result=$(grep '^{' "$LOG_DIR/demonstrator.log" | tail -1 || true)
[ -n "$result" ] && say "throw on $pair by $subject: $result"
bag=$(printf '%s\n' "$result" | sed -n 's/.*"bag": "\([^"]*\)".*/\1/p')
if [ -z "$bag" ]; then
  say "no bag recorded (demonstrator exit code $status)"
  exit $(( status ? status : 1 ))
fi
printf '%s\n' "$bag"
exit "$status"
