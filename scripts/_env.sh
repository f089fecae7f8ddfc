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
    # A virtual environment with edgedsm installed (editable) and exactly the versions that
    # requirements/<name>.lock pins (name: demo or test): every file checked against its sha256 and
    # no resolver choosing anything, so each machine gets the versions the suite ran (docs/install.md,
    # "Versions and locks"; scripts/upgrade-locks.sh moves them on purpose).
    local name="$1"
    local req="$ROOT/requirements"
    local lock="$req/$name.lock"
    if [ ! -f "$lock" ]; then
        echo "edgedsm: no lock file $lock" >&2
        return 1
    fi
    if ! "$PYTHON" -c "import venv, ensurepip" >/dev/null 2>&1; then
        apt_install python3-venv
    fi
    if [ ! -x "$VENV/bin/python" ]; then
        "$PYTHON" -m venv "$VENV"
    fi
    # Re-install only when pyproject.toml or a lock changed (the install of edgedsm is editable).
    local stamp="$VENV/.edgedsm-$name"
    local digest
    digest="$(cat "$ROOT/pyproject.toml" "$ROOT/lab/pyproject.toml" "$req/pip.lock" "$req/build.lock" "$lock" |
              sha256sum | cut -d' ' -f1)"
    if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$digest" ]; then
        return 0
    fi
    local python_version
    python_version="$("$VENV/bin/python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
    if [ "$python_version" != 3.11 ]; then
        echo "edgedsm: warning: the locks are resolved for Python 3.11 and $VENV has $python_version;" \
             "a pinned version may have no wheel for it (scripts/upgrade-locks.sh, docs/install.md)" >&2
    fi
    local pip=("$VENV/bin/python" -m pip --quiet --disable-pip-version-check)
    # (this machine's pip configuration may name local package folders that lack a package: noise)
    local quiet=(grep -v "is ignored: it is neither a file nor a directory")
    # pip first, at its locked version (--build-constraint needs pip >= 25.3; Debian 12's venv has 23.0).
    # Then the lock's wheels and sdists, --no-deps: the lock is the whole set. Each sdist (pycairo,
    # PyGObject) builds in an isolated environment that build.lock pins, hash-checked as well. Then
    # edgedsm itself, editable (which has no hash to check), built with build.lock's setuptools; for
    # the tests also the lab (lab/: the benchmarks and the paper's reproduction, which the product's
    # wheel leaves out), editable the same way; its dependencies are in test.lock.
    local projects=(-e "$ROOT")
    [ "$name" != test ] || projects+=(-e "$ROOT/lab")
    if ! "${pip[@]}" install --require-hashes --no-deps -r "$req/pip.lock" 2> >("${quiet[@]}" >&2) ||
       ! "${pip[@]}" install --require-hashes --no-deps --build-constraint "$req/build.lock" -r "$lock" \
            2> >("${quiet[@]}" >&2) ||
       ! "${pip[@]}" install --quiet --no-deps --build-constraint "$req/build.lock" "${projects[@]}" \
            2> >("${quiet[@]}" >&2); then  # (--quiet twice: errors only, not setuptools' editable notice)
        echo "edgedsm: pip could not install requirements/$name.lock and edgedsm${projects[2]:+ and its lab} into $VENV" >&2
        return 1
    fi
    local broken
    if ! broken="$("${pip[@]}" check 2>&1)"; then
        echo "edgedsm: requirements/$name.lock misses what an installed package needs:" >&2
        echo "$broken" >&2
        return 1
    fi
    echo "$digest" > "$stamp"
}
