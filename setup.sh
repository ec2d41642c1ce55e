#!/usr/bin/env bash
# The one command that sets sim2real up on a fresh Debian machine and runs the main job.
#
#   ./setup.sh                      install everything, then run the main job, `sim2real study` on its
#                                   embedded default; extra arguments go to it (e.g. --budget quick)
#   SIM2REAL_SKIP_RUN=1 ./setup.sh  install only (CI does this)
#
# Environment:
#   PYTHON                    interpreter for the venv (default: python3.11, else python3; >= 3.10)
#   SIM2REAL_TORCH_INDEX_URL  take torch 2.13.0 from this package index instead of the default sources, e.g.
#                             https://download.pytorch.org/whl/cpu for PyTorch's CPU build (used only when set)
#   MUJOCO_GL                 headless rendering backend for the main job (default egl)
#
# Python packages come from requirements.lock (every transitive dependency pinned with its sha256; refresh it
# with scripts/refresh-lock.sh). The lock is for CPython 3.11; with another Python, setup.sh warns and installs
# from pyproject.toml's ranges instead (not reproducible).
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
    for candidate in "${PYTHON:-}" python3.11 python3 python3.13 python3.12 python3.10; do
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
# pip byte-compiles what it installs on one core (half of the install's CPU time): it installs without, and
# compileall writes the same .pyc files afterwards on every core (compile_venv). The .pyc files must be there: where
# PYTHONDONTWRITEBYTECODE=1 is set (as on this workplace's machines), a venv without them recompiles every import in
# every process (torch + torchrl + dm_control: 10.5 s vs 4.5 s per process; the test suite 878 s vs 542 s).
PIP=(.venv/bin/python -m pip install --progress-bar off --disable-pip-version-check --no-compile)

compile_venv() {
    log "byte-compiling the installed packages (compileall, one process per core)"
    local site
    site="$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
    # As pip's own compile step: a file that does not compile (a template, another Python's syntax) is skipped.
    .venv/bin/python -m compileall -q -j 0 "$site" >/dev/null 2>&1 || true
}
TORCH=torch==2.13.0   # keep equal to constraints.txt and requirements.lock

installed_torch() {
    .venv/bin/python -c 'import importlib.metadata as m; print(m.version("torch"))' 2>/dev/null || true
}


venv_py="$(.venv/bin/python -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')"
if [ "$venv_py" = "3.11" ]; then
    # torch alone first, without its dependencies (the lock brings them, hashed). pip would take PyPI's CUDA build over
    # a local CPU wheel in hash-checking mode, so the wheel is fetched here, checked against the lock's hashes, installed.
    case "$(installed_torch)" in
        2.13.0|2.13.0+*) log "torch $(installed_torch) already installed" ;;
        *)
            torch_dir="$(mktemp -d)"
            torch_source=()
            if [ -n "${SIM2REAL_TORCH_INDEX_URL:-}" ]; then
                torch_source=(--index-url "$SIM2REAL_TORCH_INDEX_URL")
                log "fetching $TORCH from SIM2REAL_TORCH_INDEX_URL=$SIM2REAL_TORCH_INDEX_URL"
            else
                log "fetching $TORCH (the CPU build where this machine has its wheel, else PyPI's build)"
            fi
            .venv/bin/python -m pip download --progress-bar off --disable-pip-version-check --no-deps \
                "${torch_source[@]}" -d "$torch_dir" "$TORCH"
            torch_wheel="$(ls "$torch_dir"/torch-*.whl)"
            torch_sum="$(sha256sum "$torch_wheel" | cut -d' ' -f1)"
            if grep -q "sha256:$torch_sum" requirements.lock; then
                log "$(basename "$torch_wheel"): sha256 listed in requirements.lock"
            elif [ -n "${SIM2REAL_TORCH_INDEX_URL:-}" ]; then
                warn "$(basename "$torch_wheel") from SIM2REAL_TORCH_INDEX_URL is not in requirements.lock (sha256 $torch_sum);"
                warn "installing it anyway because you chose that index."
            else
                echo "setup.sh: error: $(basename "$torch_wheel") has sha256 $torch_sum, which requirements.lock does not list." >&2
                exit 2
            fi
            "${PIP[@]}" --no-deps "$torch_wheel"
            rm -rf "$torch_dir"
            ;;
    esac
    log "installing the locked dependencies (requirements.lock, hashes checked)"
    "${PIP[@]}" --require-hashes --no-deps -r requirements.lock
    # The lock holds torch's CPU dependencies only. Where PyPI's CUDA build of torch was taken (no CPU wheel on this
    # machine and no SIM2REAL_TORCH_INDEX_URL), this adds its nvidia-* libraries; with the CPU build it is a no-op.
    "${PIP[@]}" -c constraints.txt "$TORCH"
    log "installing sim2real itself (editable)"
    "${PIP[@]}" --no-deps --no-build-isolation -e .
    compile_venv
    .venv/bin/python -m pip check
else
    warn "requirements.lock is for CPython 3.11 and .venv has Python $venv_py:"
    warn "installing from pyproject.toml's version ranges instead (newer releases may change results)."
    warn "for the locked install: rm -rf .venv && PYTHON=python3.11 ./setup.sh"
    # torch first and pinned: anything later that depends on torch then finds it satisfied.
    "${PIP[@]}" -c constraints.txt "$TORCH"
    "${PIP[@]}" -c constraints.txt -e ".[dev,ray]"
    compile_venv
fi

# The optional C extensions of the single-env hot step (setup.py): built where a C compiler and Python's headers are.
if .venv/bin/python -c 'import sys; from noise_models import compiled; sys.exit(0 if compiled.available() else 1)'; then
    log "compiled hot step built (noise_models._hot, sim2real.wrappers._hotstep)"
else
    warn "the optional C extensions were not built (no C compiler or Python headers?): single envs step in Python,"
    warn "with the same results, slower. To build them: sudo apt-get install gcc python3-dev, then ./setup.sh again."
fi

export MUJOCO_GL="${MUJOCO_GL:-egl}"

if [ "${SIM2REAL_SKIP_RUN:-0}" = "1" ]; then
    log "installed; SIM2REAL_SKIP_RUN=1, so not running the main job"
    exit 0
fi

# --------------------------------------------------------------------------- the main job
# The main job: the whole sim-to-real loop on the embedded default (writes ./sim2real-study/report.html).
log "running: sim2real study $*"
exec .venv/bin/sim2real study "$@"
