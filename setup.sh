#!/usr/bin/env bash
# The one command that sets sim2real up on a fresh Debian machine and runs the main job.
#
#   ./setup.sh                      install everything, then run the main job, `sim2real study` on its
#                                   embedded default; extra arguments go to it (e.g. --budget quick)
#   SIM2REAL_SKIP_RUN=1 ./setup.sh  install only (CI does this)
#
# Environment: PYTHON (interpreter for the venv, default python3, >= 3.10), MUJOCO_GL (default egl).
# Safe to run again: every step checks what is already there.
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")"
export DEBIAN_FRONTEND=noninteractive

log() { printf '==> %s\n' "$*"; }
warn() { printf 'setup.sh: warning: %s\n' "$*" >&2; }

# --------------------------------------------------------------------------- Debian packages
GL_PACKAGES=(libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6)

missing_debs() {
    local pkg
    for pkg in "$@"; do
        # dpkg -s succeeds for removed-but-configured packages too, so read the status itself.
        if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q 'install ok installed'; then
            printf '%s\n' "$pkg"
        fi
    done
}

# Installs Debian packages as root, through sudo when we are not root (never prompting without a
# terminal). Returns non-zero instead of exiting, so callers decide what a failure means.
apt_install() {
    local -a sudo=()
    if [ "$(id -u)" -ne 0 ]; then
        if ! command -v sudo >/dev/null 2>&1; then
            return 1
        fi
        if [ -t 0 ]; then sudo=(sudo); else sudo=(sudo -n); fi
    fi
    command -v apt-get >/dev/null 2>&1 || return 1
    "${sudo[@]}" apt-get update -qq || return 1
    "${sudo[@]}" apt-get install -y -q --no-install-recommends "$@"
}

if command -v dpkg-query >/dev/null 2>&1; then
    mapfile -t missing < <(missing_debs "${GL_PACKAGES[@]}")
    if [ "${#missing[@]}" -gt 0 ]; then
        log "installing headless OpenGL packages: ${missing[*]}"
        if ! apt_install "${missing[@]}"; then
            warn "could not install ${missing[*]} (need root or sudo, and apt-get)."
            warn "install them yourself: sudo apt-get install -y --no-install-recommends ${missing[*]}"
            warn "continuing: everything but rendering works; the rendering tests will be skipped."
        fi
    else
        log "headless OpenGL packages present (${GL_PACKAGES[*]})"
    fi
else
    warn "not a Debian system (no dpkg-query): make sure EGL or OSMesa is installed for headless rendering."
fi

# --------------------------------------------------------------------------- Python venv
python_ok() {
    "$1" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 10) else 1)' >/dev/null 2>&1
}

find_python() {
    local candidate
    for candidate in "${PYTHON:-}" python3 python3.13 python3.12 python3.11 python3.10; do
        if [ -n "$candidate" ] && command -v "$candidate" >/dev/null 2>&1 && python_ok "$candidate"; then
            printf '%s\n' "$candidate"
            return 0
        fi
    done
    return 1
}

if [ ! -x .venv/bin/python ] || ! python_ok .venv/bin/python; then
    if ! PY="$(find_python)"; then
        log "no Python >= 3.10 found; installing Debian's python3"
        apt_install python3 python3-venv python3-pip || true
        PY="$(find_python)" || {
            echo "setup.sh: error: sim2real needs Python >= 3.10 (set PYTHON=/path/to/python3.x)." >&2
            exit 2
        }
    fi
    log "creating .venv with $PY ($("$PY" --version 2>&1))"
    rm -rf .venv
    if ! "$PY" -m venv .venv; then
        # Debian's own python3 ships venv without ensurepip until python3-venv is installed.
        log "python3 -m venv failed; installing python3-venv"
        rm -rf .venv
        ver="$("$PY" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')"
        apt_install python3-venv "python${ver}-venv" || true
        "$PY" -m venv .venv
    fi
fi

# --------------------------------------------------------------------------- Python packages
PIP=(.venv/bin/python -m pip install --progress-bar off -c constraints.txt)
# torch first and pinned: anything later that depends on torch then finds it satisfied instead of
# pulling a multi-GB CUDA build.
log "installing torch (CPU build, pinned in constraints.txt)"
"${PIP[@]}" torch==2.13.0
log "installing sim2real with the dev and ray extras"
"${PIP[@]}" -e ".[dev,ray]"

export MUJOCO_GL="${MUJOCO_GL:-egl}"

if [ "${SIM2REAL_SKIP_RUN:-0}" = "1" ]; then
    log "installed; SIM2REAL_SKIP_RUN=1, so not running the main job"
    exit 0
fi

# --------------------------------------------------------------------------- the main job
# The main job: the whole sim-to-real loop on the embedded default (writes ./sim2real-study/report.html).
log "running: sim2real study $*"
exec .venv/bin/sim2real study "$@"
