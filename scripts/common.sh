# Shared by the scripts: environment (DDS on this machine only), node start-up, clean stop.
# Source it; it defines `start [--as LOG] NAME ARGS...` (a node executable in the background,
# log in $LOG_DIR/LOG.log, LOG defaulting to NAME), `run NAME ARGS...` (a node in the
# foreground while the started ones are watched: a node that dies ends the script at once with
# its error line), `wait_ready NAME TEXT` (until the node's log says TEXT), `watch_nodes`
# (until a started node dies, then ends the script with its error line), and stops every
# started node on exit (SIGTERM, then SIGKILL after $STOP_TIMEOUT seconds). Every node dies
# with the script even when the script is killed outright (SIGKILL): the kernel sends it
# SIGTERM then (prctl PR_SET_PDEATHSIG, set by `guard` before the node's program starts). Logs
# go to one folder per run under $SUTURE_LFD_LOGS (default: suture-lfd-logs in the temporary
# directory), printed at the start and removed when the script succeeds; LOG_DIR names another
# folder, always kept.
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv=${SUTURE_LFD_VENV:-$repo/.venv}
[ -x "$venv/bin/simulator" ] || "$repo/tools/setup.sh"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-$(( $$ % 90 + 10 ))}
export AMENT_PREFIX_PATH=$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}
export PYTHONUNBUFFERED=1
STOP_TIMEOUT=${STOP_TIMEOUT:-10}
# guard PROGRAM ARGS...: PROGRAM, with SIGTERM on this script's death (a script killed before
# that took effect is seen at once: the program does not start)
guard=("$venv/bin/python" -I -S -c 'import ctypes, os, sys
ctypes.CDLL(None).prctl(1, 15)
if os.getppid() != int(sys.argv[1]):
    sys.exit(143)
os.execv(sys.argv[2], sys.argv[2:])' "$$")
children=()
names=()
declare -A ready_text=([simulator]='simulating')  # the log line that says a node is ready
declare -A announced=()
logs_announced=0
keep_logs=1
if [ -z "${LOG_DIR:-}" ]; then
  logs_root=${SUTURE_LFD_LOGS:-${TMPDIR:-/tmp}/suture-lfd-logs}
  mkdir -p "$logs_root"
  LOG_DIR=$(mktemp -d "$logs_root/$(basename "$0" .sh)-$(date +%Y%m%d-%H%M%S)-XXXX")
  keep_logs=0
fi

say() { printf '%s: %s\n' "$(basename "$0")" "$*" >&2; }

# last_error LOG: the line of a node's log that says why it stopped (its last error, or else
# its last line).
last_error() {
  local line
  line=$(grep -E 'error|Error|ERROR|FATAL|refused|unknown' "$1" 2>/dev/null | tail -1 || true)
  [ -n "$line" ] || line=$(grep -v '^[[:space:]]*$' "$1" 2>/dev/null | tail -1 || true)
  printf '%s\n' "${line:-(its log is empty)}"
}

# check_children: exit at once, with the node's error line, if a started node has exited.
check_children() {
  local i pid status
  for i in "${!children[@]}"; do
    pid=${children[$i]}
    kill -0 "$pid" 2>/dev/null && continue
    status=0
    wait "$pid" 2>/dev/null || status=$?
    say "${names[$i]:-process $pid} exited (code $status):" \
      "$(last_error "$LOG_DIR/${names[$i]:-}.log")"
    exit $(( status ? status : 1 ))
  done
}

# wait_ready NAME TEXT [TIMEOUT]: wait until the started node NAME logs TEXT; say it is ready.
wait_ready() {
  local name=$1 text=$2 deadline=$(( SECONDS + ${3:-300} ))
  until grep -q -- "$text" "$LOG_DIR/$name.log" 2>/dev/null; do
    check_children
    if [ "$SECONDS" -ge "$deadline" ]; then
      say "$name not ready after ${3:-300} s: $(last_error "$LOG_DIR/$name.log")"
      exit 1
    fi
    sleep 0.2
  done
  announced[$name]=1
  say "$name ready"
}

# run NAME ARGS...: run a node to its end (log in $LOG_DIR/NAME.log) while watching the started
# ones; set run_status to its exit code; on failure say its error line.
run() {
  local name=$1 pid
  shift
  "${guard[@]}" "$venv/bin/$name" "$@" >"$LOG_DIR/$name.log" 2>&1 &
  pid=$!
  local began=$SECONDS
  while kill -0 "$pid" 2>/dev/null; do
    if ! check_running; then
      kill -TERM "$pid" 2>/dev/null || true
      wait "$pid" 2>/dev/null || true
      progress_done
      check_children
    fi
    announce_ready
    progress "$name" $(( SECONDS - began )) "$LOG_DIR/$name.log"
    sleep 0.2
  done
  progress_done
  run_status=0
  wait "$pid" || run_status=$?
  if [ "$run_status" -ne 0 ]; then
    say "$name exited (code $run_status): $(last_error "$LOG_DIR/$name.log")"
  fi
}

# progress NAME SECONDS LOG: on a terminal, one updating line: the node, its time, its last
# log message (nothing when standard error is not a terminal: the log has it all).
progress() {
  [ -t 2 ] || return 0
  local message
  message=$(grep -v '^{' "$3" 2>/dev/null | tail -1 | sed 's/^\[[A-Z]*\] \[[0-9.]*\] \[[^]]*\]: //')
  printf '\r\033[K%s: %s (%d s)' "$1" "${message:0:$(( ${COLUMNS:-100} - ${#1} - 12 ))}" "$2" >&2
  progress_shown=1
}

progress_done() {
  if [ "${progress_shown:-0}" = 1 ]; then
    printf '\r\033[K' >&2
    progress_shown=0
  fi
}

# announce_ready: say once that a started node is ready, when its log says so.
announce_ready() {
  local name
  for name in "${names[@]}"; do
    [ -n "${ready_text[$name]:-}" ] && [ -z "${announced[$name]:-}" ] || continue
    if grep -q -- "${ready_text[$name]}" "$LOG_DIR/$name.log" 2>/dev/null; then
      announced[$name]=1
      progress_done
      say "$name ready"
    fi
  done
}

# check_running: true while every started node runs.
check_running() {
  local pid
  for pid in "${children[@]}"; do
    kill -0 "$pid" 2>/dev/null || return 1
  done
  return 0
}

# The script's help: its leading comment block, without the comment marks.
usage() { awk 'NR == 1 { next } /^#/ { sub(/^# ?/, ""); print; next } { exit }' "$0"; }

# phantom_params PHANTOM SCENE PAIR: set phantom_args to the simulator's phantom parameters
# and phantom to the phantom resolved. PHANTOM is a phantom of the scene, a mesh (STL/OBJ/PLY)
# or a phantom file (.yaml); empty: the phantom the pair's name starts with (scan* scanned,
# synth* synthetic). SCENE ('' none) replaces the installed scene.yaml. Files are passed with
# absolute paths.
phantom_params() {
  local scene=$2 pair=$3
  phantom=$1
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
  local log=''
  if [ "$1" = --as ]; then
    log=$2
    shift 2
  fi
  local name=$1
  shift
  log=${log:-$name}
  if [ "$logs_announced" = 0 ]; then
    say "logs in $LOG_DIR"
    logs_announced=1
  fi
  "${guard[@]}" "$venv/bin/$name" "$@" >"$LOG_DIR/$log.log" 2>&1 &
  children+=("$!")
  names+=("$log")
  say "started $log (pid $!)"
}

# watch_nodes: never return; when a started node dies, end the script with its error line.
watch_nodes() {
  while true; do
    check_children
    sleep 0.2
  done
}

stop_children() {
  local status=$? pid deadline
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
  if [ "$keep_logs" = 0 ] && [ "$status" = 0 ]; then
    rm -rf "$LOG_DIR"
    rmdir "$(dirname "$LOG_DIR")" 2>/dev/null || true
  elif [ "$logs_announced" = 1 ] && [ "$status" != 0 ]; then
    say "logs kept in $LOG_DIR"
  fi
  exit "$status"
}
trap stop_children EXIT
trap 'exit 130' INT
trap 'exit 143' TERM
