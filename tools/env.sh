# Sourced by tools/run and tools/test: make a virtual environment with hwbridge installed.
#   HWBRIDGE_VENV  where the environment lives (default: .venv in the checkout)
#   PYTHON         interpreter that creates it (default: python3)
#   HWBRIDGE_EXTRA pip extra to install with it (tools/test sets "test")
#   HWBRIDGE_NO_COMPILE  set: pip leaves the installed packages' bytecode to be written on first
#                  import (tools/test, whose bytecode goes to PYTHONPYCACHEPREFIX)
#   HWBRIDGE_PIP=pip  install with pip only (by default uv installs, pip when uv cannot)
# The installer is uv (from PyPI, into the environment): it installs the ~150 packages of the test
# extra in about 8 s where pip takes 35 s. The environment is made without pip (venv's ensurepip
# takes 6 s); pip puts uv into it, and uv puts pip there with the rest (tests and users run
# `.venv/bin/python -m pip`). uv does not read pip's configuration files; the one setting it is
# given from there is pip's index-url (a mirror that stands in for PyPI). Should uv fail for any
# reason (no uv wheel for this machine, an index it cannot reach), the environment gets pip from
# ensurepip and pip installs, as it did before.
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${HWBRIDGE_VENV:-$ROOT/.venv}"

_hwbridge_uv() {
    [ "${HWBRIDGE_PIP:-}" = pip ] && return 1
    if [ ! -x "$VENV/bin/uv" ]; then
        if "$VENV/bin/python" -m pip --version >/dev/null 2>&1; then
            "$VENV/bin/python" -m pip install -q --disable-pip-version-check uv >&2 || return 1
        else  # pip 22.3 or later installs into another environment
            "${PYTHON:-python3}" -m pip --python "$VENV/bin/python" install -q \
                --disable-pip-version-check uv >&2 || return 1
        fi
    fi
    local index compile=(--compile-bytecode)
    [ -n "${HWBRIDGE_NO_COMPILE:-}" ] && compile=()
    index="$("${PYTHON:-python3}" -m pip config get global.index-url 2>/dev/null || true)"
    [ -n "${PIP_INDEX_URL:-}" ] && index="$PIP_INDEX_URL"
    ${index:+env UV_DEFAULT_INDEX="$index"} "$VENV/bin/uv" pip install -q \
        --python "$VENV/bin/python" "${compile[@]}" pip -e "$1" >&2
}

hwbridge_setup() {
    local spec="$ROOT"
    [ -n "${HWBRIDGE_EXTRA:-}" ] && spec="$ROOT[$HWBRIDGE_EXTRA]"
    if [ ! -x "$VENV/bin/python" ]; then
        printf '==> [%ss] creating virtual environment %s\n' "$SECONDS" "$VENV" >&2
        "${PYTHON:-python3}" -m venv --without-pip "$VENV"
    fi
    printf '==> [%ss] installing -e .%s\n' "$SECONDS" "${spec#"$ROOT"}" >&2
    if ! _hwbridge_uv "$spec"; then
        [ "${HWBRIDGE_PIP:-}" = pip ] || echo "note: uv could not install; pip installs instead" >&2
        "$VENV/bin/python" -m pip --version >/dev/null 2>&1 ||
            "$VENV/bin/python" -m ensurepip --upgrade >/dev/null
        "$VENV/bin/python" -m pip install -q --disable-pip-version-check \
            ${HWBRIDGE_NO_COMPILE:+--no-compile} -e "$spec" >&2
    fi
}
