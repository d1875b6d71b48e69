#!/usr/bin/env bash
# Learn the throw from a segment file and execute it on a marker pair in the simulator.
#
#   scripts/learn_and_execute.sh SEGMENTS PAIR [--phantom NAME|MESH|PHANTOM.yaml]
#                                [--scene SCENE.yaml] [--rtf FACTOR] [--no-simulator]
#                                [--ros-args ...]
#
# Starts the simulator (--phantom, by default the phantom the pair's name starts with: scan*
# scanned, synth* synthetic) unless --no-simulator, runs the executor
# node on SEGMENTS and PAIR until it reports the throw, and prints its result on stdout (one
# JSON object: pair, outcome, score, subtasks, entry and exit errors, time); exit code 0 when
# the throw scored 1.0. Extra --ros-args go to the executor.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
rtf=1.0 simulator=1 positional=() phantom='' scene=''
while [ $# -gt 0 ]; do
  case "$1" in
    --rtf) rtf=$2; shift 2 ;;
    --phantom) phantom=$2; shift 2 ;;
    --scene) scene=$2; shift 2 ;;
    --no-simulator) simulator=0; shift ;;
    --ros-args) shift; break ;;
    -h|--help) usage; exit 0 ;;
    *) positional+=("$1"); shift ;;
  esac
done
[ ${#positional[@]} -eq 2 ] || { say "usage: $0 SEGMENTS PAIR"; exit 2; }
segments=$(cd "$(dirname "${positional[0]}")" && pwd)/$(basename "${positional[0]}")
pair=${positional[1]}
if [ "$simulator" = 1 ]; then
  phantom_params "$phantom" "$scene" "$pair"
  start simulator --ros-args "${phantom_args[@]}" -p real_time_factor:="$rtf" \
    -p target_pair:="$pair"
fi
run executor --ros-args -p segments:="$segments" -p pair:="$pair" -p use_sim_time:=true "$@"
# the executor's result: its one JSON line on standard output
grep '^{' "$LOG_DIR/executor.log" | tail -1 || true
exit "$run_status"
