# Shared set-up for the README commands: system packages (Debian 12, as root) and a venv.
# Sourced by scripts/demo.sh and scripts/test.sh; idempotent and quick when all is in place.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${EDGEDSM_VENV:-$ROOT/.venv}"
PYTHON="${PYTHON:-python3}"

apt_install() {
    # Installs the Debian packages that are missing; apt-get update only when needed.
    local missing=()
    for pkg in "$@"; do
        dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
    done
    [ ${#missing[@]} -eq 0 ] && return 0
    if ! command -v apt-get >/dev/null; then
        echo "edgedsm: need the Debian packages ${missing[*]} but apt-get is not available" >&2
        return 1
    fi
    local sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    echo "edgedsm: installing Debian packages: ${missing[*]}" >&2
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

ensure_venv() {
    # A virtual environment with edgedsm installed (editable) plus the given extras.
    local extras="$1"
    if ! "$PYTHON" -c "import venv, ensurepip" >/dev/null 2>&1; then
        apt_install python3-venv
    fi
    if [ ! -x "$VENV/bin/python" ]; then
        "$PYTHON" -m venv "$VENV"
    fi
    # Re-install only when pyproject.toml or the extras changed (the install is editable).
    local stamp="$VENV/.edgedsm-$extras"
    local digest
    digest="$(sha256sum "$ROOT/pyproject.toml" | cut -d' ' -f1)"
    if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$digest" ]; then
        return 0
    fi
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --upgrade pip 2>/dev/null
    if ! "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -e "$ROOT[$extras]" \
            2> >(grep -v "is ignored: it is neither a file nor a directory" >&2); then
        echo "edgedsm: pip could not install edgedsm[$extras]" >&2
        return 1
    fi
    echo "$digest" > "$stamp"
}
