#!/usr/bin/env bash
# Installs what mscloth needs and is missing: Debian's libllvm19 (for Dr.Jit's LLVM backend)
# and the pinned Python packages in .venv/. Quick and silent when everything is there.
set -euo pipefail
cd "$(dirname "$0")/.."

have_llvm19() {
    local f
    for f in /usr/lib/*/libLLVM.so.19* /usr/lib/*/libLLVM-19.so* /usr/lib/llvm-19/lib/libLLVM*.so*; do
        [ -e "$f" ] && return 0
    done
    return 1
}

apt_install() {
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "setup: installing Debian packages: $*"
        apt-get update -qq >/dev/null
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
    else
        echo "setup: error: missing Debian packages: $*" >&2
        echo "setup: install them as root, e.g.  sudo apt-get install $*" >&2
        exit 1
    fi
}

have_llvm19 || apt_install libllvm19
have_llvm19 || { echo "setup: error: libLLVM.so.19 still not found after installing libllvm19" >&2; exit 1; }

# `setup.sh test`: the test suite also checks the HTML report in headless Chromium.
if [ "${1:-}" = "test" ] && ! command -v chromium >/dev/null 2>&1; then
    apt_install chromium
fi

PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    if ! "$PYTHON" -c 'import venv, ensurepip' >/dev/null 2>&1; then
        apt_install python3-venv
    fi
    echo "setup: creating .venv/"
    "$PYTHON" -m venv .venv
fi

# Reinstall only when the pins changed (hash of the files that define them).
want=$(cat requirements.lock pyproject.toml | sha256sum | cut -d' ' -f1)
stamp=.venv/.mscloth-installed
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    echo "setup: installing pinned Python packages into .venv/"
    .venv/bin/python -m pip install -q --disable-pip-version-check -r requirements.lock
    .venv/bin/python -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
    echo "$want" > "$stamp"
fi
