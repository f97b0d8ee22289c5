# Sourced by tools/run and tools/test: make a virtual environment with hwbridge installed.
#   HWBRIDGE_VENV  where the environment lives (default: .venv in the checkout)
#   PYTHON         interpreter that creates it (default: python3)
#   HWBRIDGE_EXTRA pip extra to install with it (tools/test sets "test")
#   HWBRIDGE_NO_COMPILE  set: pip leaves the installed packages' bytecode to be written on first
#                  import (tools/test, whose bytecode goes to PYTHONPYCACHEPREFIX)
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${HWBRIDGE_VENV:-$ROOT/.venv}"

hwbridge_setup() {
    local spec="$ROOT"
    [ -n "${HWBRIDGE_EXTRA:-}" ] && spec="$ROOT[$HWBRIDGE_EXTRA]"
    if [ ! -x "$VENV/bin/python" ]; then
        printf '==> [%ss] creating virtual environment %s\n' "$SECONDS" "$VENV" >&2
        "${PYTHON:-python3}" -m venv "$VENV"
        "$VENV/bin/python" -m pip install -q --disable-pip-version-check --upgrade pip >&2
    fi
    printf '==> [%ss] pip install -e .%s\n' "$SECONDS" "${spec#"$ROOT"}" >&2
    "$VENV/bin/python" -m pip install -q --disable-pip-version-check \
        ${HWBRIDGE_NO_COMPILE:+--no-compile} -e "$spec" >&2
}
