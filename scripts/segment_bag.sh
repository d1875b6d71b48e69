#!/usr/bin/env bash
# Segment a demonstration bag into the five subtasks and write the executor's segment file.
#
#   scripts/segment_bag.sh BAG [OUTPUT] [--pair PAIR] [--subject NAME]
#
# OUTPUT defaults to BAG.segments.npz beside the bag; it is printed on stdout.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
args=() positional=()
while [ $# -gt 0 ]; do
  case "$1" in
    --pair) args+=(-p pair:="$2"); shift 2 ;;
    --subject) args+=(-p subject:="$2"); shift 2 ;;
    -h|--help) usage; exit 0 ;;
    *) positional+=("$1"); shift ;;
  esac
done
[ ${#positional[@]} -ge 1 ] || { say "usage: $0 BAG [OUTPUT]"; exit 2; }
bag=$(cd "$(dirname "${positional[0]}")" && pwd)/$(basename "${positional[0]}")
output=${positional[1]:-$bag.segments.npz}
run segmenter --ros-args -p bag:="$bag" -p output:="$output" "${args[@]}"
[ "$run_status" = 0 ] || exit "$run_status"
grep -v '^[[:space:]]*$' "$LOG_DIR/segmenter.log" | tail -1 >&2
printf '%s\n' "$output"
