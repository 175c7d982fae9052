#!/usr/bin/env bash
# Set up gendr in ./.venv (idempotent: a second run skips whatever is already in place).
#
#   bash install.sh          # gendr, both backends (torch, drjit), validation references, experiments
#   bash install.sh --dev    # ... plus the test dependencies (pytest, scipy, ...)
#
# Steps: system packages (apt, only when APT_PACKAGES lists something missing) -> .venv with the
# machine's python3 (>= 3.10) -> torch==2.13.0 (exact pin, installed first and alone) ->
# `pip install -e ".[torch,drjit,images,validation,experiments,meshes]"` (+ `dev` with --dev) -> pyrender
# with --no-deps -> sanity check and a short summary.
#
# Environment: GENDR_PYTHON (default python3) picks the interpreter for a new .venv.
# pip's own configuration (PIP_FIND_LINKS, pip.conf, ...) is respected as it is.
set -euo pipefail

# ---------------------------------------------------------------------------------------------
# What gets installed
# ---------------------------------------------------------------------------------------------
# torch is pinned EXACTLY: on this machine class a CPU wheel of this version lies on disk and pip
# takes it. An unpinned `torch` (or a range admitting a newer release) would download the newest
# CUDA build, several GB. Once 2.13.0 is installed, gendr's own `torch>=2.1` is already satisfied.
TORCH_VERSION="2.13.0"

# Debian packages the project needs at run time (installed with apt-get, as root, only when one of
# them is missing), per shared/STACK.md. The torch backend alone needs none of them.
APT_PACKAGES=(
    libllvm19                               # Dr.Jit's / Mitsuba's LLVM (CPU) back end (LLVM 14-16 fail)
    libosmesa6                              # pyrender offscreen (PYOPENGL_PLATFORM=osmesa)
    libegl1 libegl-mesa0 libgl1-mesa-dri    # pyrender with PYOPENGL_PLATFORM=egl
    libgl1 libopengl0                       # `import pyrender` loads libGL even headless
    chromium                                # headless check that validation reports render
)

# pyrender 0.1.45 pins PyOpenGL==3.1.0, which fails on osmesa; the `validation` extra brings
# PyOpenGL 3.1.10 and pyrender's other dependencies, and pyrender itself goes in with --no-deps.
PYRENDER_VERSION="0.1.45"

MIN_PYTHON="3.10"

# ---------------------------------------------------------------------------------------------
usage() {
    sed -n '2,12p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
}

DEV=0
for arg in "$@"; do
    case "$arg" in
        --dev) DEV=1 ;;
        -h|--help) usage; exit 0 ;;
        *) echo "install.sh: unknown argument '$arg' (usage: bash install.sh [--dev])" >&2; exit 2 ;;
    esac
done

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
cd "$ROOT"
VENV="$ROOT/.venv"
VPY="$VENV/bin/python"
PYTHON="${GENDR_PYTHON:-python3}"
EXTRAS="torch,drjit,images,validation,experiments,meshes"
[[ $DEV == 1 ]] && EXTRAS="$EXTRAS,dev"
START=$SECONDS
LOG="$(mktemp "${TMPDIR:-/tmp}/gendr-install.XXXXXX")"
trap 'rm -f "$LOG"' EXIT

say() { printf '[install.sh] %s\n' "$*"; }
warn() { printf '[install.sh] WARNING: %s\n' "$*" >&2; }
die() { printf '[install.sh] ERROR: %s\n' "$*" >&2; exit 1; }
is_root() { [[ $(id -u) == 0 ]]; }

# ---------------------------------------------------------------------------------------------
# apt
# ---------------------------------------------------------------------------------------------
APT_UPDATED=0
apt_install() {  # apt_install PKG... : install the ones that are missing (root only)
    local missing=() p
    if ! command -v dpkg-query >/dev/null 2>&1; then
        warn "no dpkg-query (not Debian?): make sure these are installed: $*"
        return 0
    fi
    for p in "$@"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
    done
    [[ ${#missing[@]} == 0 ]] && return 0
    if ! is_root; then
        die "missing system packages: ${missing[*]} — run this script as root, or: sudo apt-get install ${missing[*]}"
    fi
    say "apt-get install ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    if [[ $APT_UPDATED == 0 ]]; then
        apt-get update -qq >"$LOG" 2>&1 || { tail -n 20 "$LOG" >&2; die "apt-get update failed"; }
        APT_UPDATED=1
    fi
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >"$LOG" 2>&1 \
        || { tail -n 30 "$LOG" >&2; die "apt-get install ${missing[*]} failed"; }
}

if [[ ${#APT_PACKAGES[@]} -gt 0 ]]; then
    apt_install "${APT_PACKAGES[@]}"
fi

# ---------------------------------------------------------------------------------------------
# the virtual environment
# ---------------------------------------------------------------------------------------------
python_ok() {  # python_ok PYTHON : runs, and is >= MIN_PYTHON
    "$1" -c "import sys; sys.exit(0 if sys.version_info >= tuple(map(int, '$MIN_PYTHON'.split('.'))) else 1)" \
        >/dev/null 2>&1
}

venv_ok() { [[ -x $VPY ]] && python_ok "$VPY" && "$VPY" -m pip --version >/dev/null 2>&1; }

if venv_ok; then
    say ".venv exists ($("$VPY" -c 'import sys; print(sys.version.split()[0])')), reusing it"
else
    command -v "$PYTHON" >/dev/null 2>&1 || die "no '$PYTHON' on PATH: install Python >= $MIN_PYTHON (apt-get install python3) or set GENDR_PYTHON"
    python_ok "$PYTHON" || die "$PYTHON is $("$PYTHON" -V 2>&1); gendr needs Python >= $MIN_PYTHON (set GENDR_PYTHON to another interpreter)"
    if [[ -e $VENV ]]; then
        warn ".venv exists but is broken (no working python/pip inside): recreating it"
        rm -rf "$VENV"
    fi
    say "creating .venv with $(command -v "$PYTHON") ($("$PYTHON" -V 2>&1))"
    if ! "$PYTHON" -m venv "$VENV" >"$LOG" 2>&1; then
        # Debian's python3 ships venv/ensurepip separately (python3-venv).
        rm -rf "$VENV"
        pyver="$("$PYTHON" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
        if command -v apt-get >/dev/null 2>&1 && is_root; then
            say "'$PYTHON -m venv' failed ($(tail -n 1 "$LOG")); installing Debian's venv support"
            apt_install python3-venv "python${pyver}-venv"
            "$PYTHON" -m venv "$VENV" >"$LOG" 2>&1 || { cat "$LOG" >&2; die "could not create .venv"; }
        else
            cat "$LOG" >&2
            die "could not create .venv; on Debian/Ubuntu: sudo apt-get install python3-venv python${pyver}-venv"
        fi
    fi
    venv_ok || die ".venv was created but has no working pip"
fi

# ---------------------------------------------------------------------------------------------
# pip, with its output kept: a failure shows the end of the log; ERROR/WARNING lines that pip
# prints while exiting 0 (e.g. dependency conflicts) are shown too, never swallowed.
# ---------------------------------------------------------------------------------------------
pip_install() {  # pip_install ARGS...
    say "pip install $*"
    local rc=0
    "$VPY" -m pip install --disable-pip-version-check --no-input "$@" >"$LOG" 2>&1 || rc=$?
    cat "$LOG" >>"$VENV/install.log"
    if [[ $rc != 0 ]]; then
        echo "----- last lines of pip's output (all of it: .venv/install.log) -----" >&2
        tail -n 40 "$LOG" >&2
        die "pip install $* failed (exit $rc)"
    fi
    grep -E '^(ERROR|WARNING)' "$LOG" | grep -v -e 'pip version' -e 'is ignored: it is neither a file nor a directory' | sed 's/^/[install.sh] pip said: /' >&2 || true
    grep -E '^Successfully installed' "$LOG" | sed 's/^/[install.sh]   /' || true
}

# The distribution version of an installed package ('' if absent), local label (+cpu) dropped.
installed_version() {
    "$VPY" - "$1" <<'EOF' 2>/dev/null || true
import sys
from importlib import metadata
try:
    print(metadata.version(sys.argv[1]).split("+")[0])
except metadata.PackageNotFoundError:
    pass
EOF
}

# --- 1. torch, exact pin, alone and first ---------------------------------------------------
have_torch="$(installed_version torch)"
if [[ $have_torch == "$TORCH_VERSION" ]]; then
    say "torch $TORCH_VERSION already installed"
else
    [[ -n $have_torch ]] && warn "torch $have_torch installed; replacing it with $TORCH_VERSION"
    pip_install "torch==$TORCH_VERSION"
    have_torch="$(installed_version torch)"
    [[ $have_torch == "$TORCH_VERSION" ]] || die "after installing, torch is '${have_torch:-missing}', expected $TORCH_VERSION"
fi

# --- 2. gendr itself, editable, with its extras ---------------------------------------------
# Skipped when the editable install is of this checkout, was made from the current pyproject.toml
# (the stamp) and every requirement of the requested extras is installed and satisfied.
STAMP_FILE="$VENV/.gendr-install-stamp"
stamp="$( { cat pyproject.toml; echo "$ROOT"; "$VPY" -V; } 2>&1 | sha256sum | cut -d' ' -f1)"
gendr_up_to_date() {
    [[ -f $STAMP_FILE && $(cat "$STAMP_FILE") == "$stamp" ]] || return 1
    "$VPY" -I - "$ROOT" "$EXTRAS" <<'EOF' >/dev/null 2>&1
import os, sys
from importlib import metadata
from pip._vendor.packaging.requirements import Requirement
root, extras = sys.argv[1], sys.argv[2].split(",")
dist = metadata.distribution("gendr")
# the editable install must point at this checkout
import importlib.util
spec = importlib.util.find_spec("gendr")
assert spec and spec.origin and os.path.realpath(spec.origin).startswith(os.path.realpath(root) + os.sep)
for line in dist.requires or ():
    req = Requirement(line)
    if req.marker and not any(req.marker.evaluate({"extra": e}) for e in [""] + extras):
        continue
    have = metadata.version(req.name)  # raises when missing
    assert req.specifier.contains(have.split("+")[0], prereleases=True), (req, have)
EOF
}

if gendr_up_to_date; then
    say "gendr (editable, extras [$EXTRAS]) already installed"
else
    rm -f "$STAMP_FILE"
    pip_install -e ".[$EXTRAS]"
    have_torch="$(installed_version torch)"
    [[ $have_torch == "$TORCH_VERSION" ]] || die "installing gendr changed torch to '${have_torch:-missing}' (expected $TORCH_VERSION)"
    if ! "$VPY" -m pip check >"$LOG" 2>&1; then
        sed 's/^/[install.sh] pip check: /' "$LOG" >&2
    fi
    echo "$stamp" >"$STAMP_FILE"
fi

# --- 3. pyrender without its PyOpenGL pin ----------------------------------------------------
if [[ $(installed_version pyrender) == "$PYRENDER_VERSION" ]]; then
    say "pyrender $PYRENDER_VERSION already installed"
else
    pip_install --no-deps "pyrender==$PYRENDER_VERSION"
fi

# ---------------------------------------------------------------------------------------------
# sanity check + summary
# ---------------------------------------------------------------------------------------------
"$VPY" -I - "$DEV" <<'EOF' || die "the installed environment does not work (see the traceback above)"
import sys, platform
from importlib import metadata
import numpy, torch, gendr
backends = sorted(ep.name for ep in metadata.entry_points(group="gendr.backends"))
if "torch" not in backends:
    sys.exit(f"the torch backend is not registered (gendr.backends entry points: {backends})")
for ep in metadata.entry_points(group="gendr.backends"):
    ep.load()  # every registered backend imports
import drjit, mitsuba, pyrender  # noqa: F401  (drjit finds libLLVM when its LLVM back end starts)
print("[install.sh] ready:")
print(f"  python  {platform.python_version()}  ({sys.executable})")
print(f"  torch   {torch.__version__}  (cuda available: {torch.cuda.is_available()})")
print(f"  numpy   {numpy.__version__}")
print(f"  drjit   {drjit.__version__}   mitsuba {mitsuba.__version__}   pyrender {pyrender.__version__}")
print(f"  gendr   {getattr(gendr, '__version__', '?')}  backends: {', '.join(backends)}")
if sys.argv[1] == "1":
    import pytest
    print(f"  pytest  {pytest.__version__}")
EOF
say "done in $((SECONDS - START)) s. Try: .venv/bin/gendr demo -o out/demo"
