#!/usr/bin/env bash
# The one dependency step of `make demo`, `make test` and `.ci/run`: what a machine needs
# beyond Python and PyPI, checked, and installed where it can be (Debian/Ubuntu, apt-get, as
# root or with password-less sudo). Where it cannot, one clear message says what is missing
# and the command that installs it, and the step fails (exit 1).
#
#   tools/deps.sh demo    a C compiler, the Python headers and venv (the ortho's C loops are
#                         built at install; `python -m venv` needs ensurepip)
#   tools/deps.sh test    demo's, and gpsd + gpspipe, node + npm (the independent MCAP reader
#                         and Foxglove WebSocket client, whose packages `npm ci` installs from
#                         the committed locks) and gdalwarp
#                         (the reference `gdalwarp -geoloc` in the tests), chromium (headless:
#                         the processing report rendered as a reader sees it)
#   tools/deps.sh make    make itself (for .ci/run, before it can call make)
#
# Several groups may be given. PYTHON names the interpreter (default python3).
set -euo pipefail
case $0 in  # the repository (no dirname: the step may run with little on the PATH)
  */*) cd "${0%/*}/.." ;;
  *) cd .. ;;
esac
PYTHON=${PYTHON:-python3}

need=()  # Debian packages
why=()   # what each is for, for the message

want() {  # want PACKAGE WHAT: one missing thing
  need+=("$1")
  why+=("$2")
}

have() { command -v "$1" >/dev/null 2>&1; }

check_make() {
  have make || want make "make (the README's commands)"
}

check_demo() {
  have cc || want gcc "a C compiler (the ortho's C loops, built at install)"
  if ! have "$PYTHON"; then
    echo "deps: $PYTHON: not found: Python 3.11 or newer is needed (PYTHON=... names another)" >&2
    exit 1
  fi
  "$PYTHON" -c 'import os, sys, sysconfig
sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' \
    || want python3-dev "the Python headers (Python.h)"
  "$PYTHON" -c 'import ensurepip' 2>/dev/null || want python3-venv "python -m venv (ensurepip)"
}

check_test() {
  check_demo
  have gpsd || [ -x /usr/sbin/gpsd ] || want gpsd "gpsd (a real client of the emulated receiver)"
  have gpspipe || want gpsd-clients "gpspipe"
  have node || want nodejs "node (the independent MCAP reader)"
  have npm || want npm "npm (installs the MCAP reader's packages)"
  have gdalwarp || want gdal-bin "gdalwarp (the reference ortho)"
  have chromium || want chromium "chromium (renders the processing report in a test)"
}

if (($# == 0)); then
  set -- demo
fi
for group in "$@"; do
  case "$group" in
    demo) check_demo ;;
    test) check_test ;;
    make) check_make ;;
    *) echo "deps: unknown group '$group' (demo, test or make)" >&2; exit 2 ;;
  esac
done

# each package once, in the order first wanted
declare -A seen=()
packages=()
for p in "${need[@]+"${need[@]}"}"; do
  [[ -n ${seen[$p]:-} ]] && continue
  seen[$p]=1
  packages+=("$p")
done

if ((${#packages[@]})); then
  as_root=()
  if [ "$(id -u)" != 0 ]; then
    if have sudo && sudo -n true 2>/dev/null; then
      as_root=(sudo -n)
    else
      as_root=(none)
    fi
  fi
  if ! have apt-get || [ "${as_root[*]-}" = none ]; then
    {
      echo "deps: missing on this machine:"
      for i in "${!need[@]}"; do
        echo "  - ${why[$i]} (Debian package ${need[$i]})"
      done
      if have apt-get; then
        echo "deps: not root and no password-less sudo, so not installed here: run"
        echo "  sudo apt-get install -y ${packages[*]}"
        echo "then this command again (or run it as root: it installs them itself)"
      else
        echo "deps: no apt-get here: install them with this system's package manager, then run"
        echo "this command again"
      fi
    } >&2
    exit 1
  fi
  echo "deps: installing ${packages[*]} (apt-get)" >&2
  export DEBIAN_FRONTEND=noninteractive
  "${as_root[@]+"${as_root[@]}"}" apt-get update -qq
  "${as_root[@]+"${as_root[@]}"}" apt-get install -y -qq "${packages[@]}" >/dev/null
fi

for group in "$@"; do
  if [ "$group" = test ] && [ ! -d tests/recorder/js/node_modules/@mcap/core ]; then
    echo "deps: npm ci in tests/recorder/js (the independent MCAP reader)" >&2
    (cd tests/recorder/js && npm ci --no-audit --no-fund --silent)
  fi
  if [ "$group" = test ] && [ ! -d tests/live/js/node_modules/@foxglove/ws-protocol ]; then
    echo "deps: npm ci in tests/live/js (the independent Foxglove WebSocket client)" >&2
    (cd tests/live/js && npm ci --no-audit --no-fund --silent)
  fi
done
