# Shared by the scripts: environment (DDS on this machine only), node start-up, clean stop.
# Source it; it defines `start NAME ARGS...` (a node executable in the background, log in
# $LOG_DIR/NAME.log) and stops every started node on exit (SIGTERM, then SIGKILL after
# $STOP_TIMEOUT seconds).
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv=${SUTURE_LFD_VENV:-$repo/.venv}
[ -x "$venv/bin/simulator" ] || "$repo/tools/setup.sh"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-$(( $$ % 90 + 10 ))}
export AMENT_PREFIX_PATH=$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}
export PYTHONUNBUFFERED=1
LOG_DIR=${LOG_DIR:-$(mktemp -d "${TMPDIR:-/tmp}/suture-lfd-logs.XXXXXX")}
STOP_TIMEOUT=${STOP_TIMEOUT:-10}
children=()

say() { printf '%s: %s\n' "$(basename "$0")" "$*" >&2; }

# The script's help: its leading comment block, without the comment marks.
usage() { awk 'NR == 1 { next } /^#/ { sub(/^# ?/, ""); print; next } { exit }' "$0"; }

# phantom_params PHANTOM SCENE PAIR: set phantom_args to the simulator's phantom parameters.
# PHANTOM is a phantom of the scene, a mesh (STL/OBJ/PLY) or a phantom file (.yaml); empty:
# the phantom the pair's name starts with (scan* scanned, synth* synthetic). SCENE ('' none)
# replaces the installed scene.yaml. Files are passed with absolute paths.
phantom_params() {
  local phantom=$1 scene=$2 pair=$3
  if [ -z "$phantom" ]; then
    case "$pair" in
      scan*) phantom=scanned ;;
      synth*|'') phantom=synthetic ;;
      *) say "pair $pair: give the phantom it is on with --phantom (a mesh or phantom file)"
         exit 2 ;;
    esac
  fi
  if [ -f "$phantom" ]; then
    phantom=$(cd "$(dirname "$phantom")" && pwd)/$(basename "$phantom")
  elif [[ "$phantom" == */* || "$phantom" == *.* ]]; then
    say "phantom file $phantom does not exist"
    exit 2
  fi
  phantom_args=(-p phantom:="$phantom")
  if [ -n "$scene" ]; then
    [ -f "$scene" ] || { say "scene file $scene does not exist"; exit 2; }
    phantom_args+=(-p scene:="$(cd "$(dirname "$scene")" && pwd)/$(basename "$scene")")
  fi
}

start() {
  local name=$1
  shift
  "$venv/bin/$name" "$@" >"$LOG_DIR/$name.log" 2>&1 &
  children+=("$!")
  say "started $name (pid $!, log $LOG_DIR/$name.log)"
}

stop_children() {
  local pid deadline
  trap - EXIT INT TERM
  for pid in "${children[@]}"; do
    kill -TERM "$pid" 2>/dev/null || true
  done
  deadline=$(( SECONDS + STOP_TIMEOUT ))
  for pid in "${children[@]}"; do
    while kill -0 "$pid" 2>/dev/null && [ "$SECONDS" -lt "$deadline" ]; do sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
  done
}
trap stop_children EXIT
trap 'exit 130' INT
trap 'exit 143' TERM
