#!/usr/bin/env bash
# Moves the locked versions on purpose. The README's commands install exactly what requirements/*.lock
# pins (scripts/_env.sh: pip --require-hashes --no-deps, no resolver); this script re-resolves those
# files from pyproject.toml and then tests them in a venv of their own (docs/install.md, "Versions
# and locks"):
#
#   scripts/upgrade-locks.sh                 the newest versions pyproject.toml allows, then the whole
#                                            suite in .venv-newest, installed from the new locks
#   scripts/upgrade-locks.sh --keep          keep every pin pyproject.toml still allows and resolve only
#                                            what changed (a dependency added, a range moved), then test
#   scripts/upgrade-locks.sh --no-test ...   write the locks only
#   scripts/upgrade-locks.sh ... -- ARGS     test with `scripts/test.sh ARGS` (e.g. -- tests/unit -k lock)
#
# EDGEDSM_VENV names the test venv (default .venv-newest; .venv stays as it is until its next
# `./scripts/test.sh`, which brings it to the committed locks). Review `git diff requirements/`,
# and commit the locks with the change that needed them.
#
# The resolver is uv (`uv pip compile`), itself pinned by hash in requirements/tools.lock: it resolves
# for the target named below (CPython 3.11 on glibc 2.36 x86_64, i.e. Debian 12) whichever Python
# runs it, records the sha256 of every file of each pinned release, and is one wheel with no
# dependencies. (pip-compile resolves for the interpreter that runs it, and its releases trail
# pip's.)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
REQ="$ROOT/requirements"
PYTHON="${PYTHON:-python3}"
TARGET=(--python-version 3.11 --python-platform x86_64-manylinux_2_36)

upgrade=(--upgrade)
run_tests=1
test_args=()
while [ $# -gt 0 ]; do
    case "$1" in
        --keep) upgrade=(); shift ;;
        --no-test) run_tests=0; shift ;;
        --) shift; test_args=("$@"); break ;;
        -h|--help) sed -n '2,21p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "upgrade-locks.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done

# uv in a venv of its own, outside the work tree, from requirements/tools.lock.
tools="${XDG_CACHE_HOME:-$HOME/.cache}/edgedsm/locktools"
tools_digest="$(sha256sum "$REQ/tools.lock" | cut -d' ' -f1)"
if [ "$(cat "$tools/.stamp" 2>/dev/null)" != "$tools_digest" ]; then
    rm -rf "$tools"
    "$PYTHON" -m venv "$tools"
    "$tools/bin/python" -m pip install --quiet --disable-pip-version-check --require-hashes --no-deps \
        -r "$REQ/tools.lock" 2> >(grep -v "is ignored: it is neither a file nor a directory" >&2)
    echo "$tools_digest" > "$tools/.stamp"
fi
UV="$tools/bin/uv"

# compile OUT DESCRIPTION INPUT... [uv options]: resolves into requirements/OUT (exact versions, every
# file's sha256) behind a header that says what it is and how it was made. uv reads its pins from
# the existing file (--keep) unless --upgrade; no uv configuration file or index setting of this
# machine takes part (the default package index).
compile() {
    local out="$1" what="$2"
    shift 2
    (cd "$ROOT" && env -u UV_INDEX_URL -u UV_DEFAULT_INDEX -u UV_EXTRA_INDEX_URL -u UV_INDEX -u UV_FIND_LINKS \
        -u UV_CONSTRAINT -u UV_OVERRIDE "$UV" pip compile --quiet --no-config --no-header --generate-hashes \
        "${TARGET[@]}" "${upgrade[@]}" -o "requirements/$out" "$@")
    local body
    body="$(cat "$REQ/$out")"
    {
        echo "# requirements/$out: $what"
        echo "# Exact versions and sha256 hashes for CPython 3.11 on Linux x86_64 (Debian 12), made by"
        echo "# scripts/upgrade-locks.sh (docs/install.md, \"Versions and locks\"; do not edit by hand) with"
        echo "#   $("$UV" --version | cut -d' ' -f1-2) pip compile --no-config --generate-hashes ${TARGET[*]} $*"
        echo "$body"
    } > "$REQ/$out"
}

# test.lock first: every other lock takes its versions where they share a package (-c), so demo's
# and the builds' numpy, setuptools, pycairo ... are the ones the suite ran. The lab (lab/pyproject.toml,
# installed into the test venv too) is not an input: its one requirement beyond edgedsm, matplotlib,
# is in the test extra (tests/unit/test_locks.py checks), and edgedsm itself is no index's to resolve.
compile test.lock "everything \`pip install -e .[test]\` installs (scripts/test.sh)." \
    pyproject.toml --extra test
compile demo.lock "everything \`pip install -e .[fast]\` installs (scripts/demo.sh)." \
    pyproject.toml --extra fast -c requirements/test.lock
compile build.lock "what pip builds the sdists and edgedsm's editable install with (--build-constraint)." \
    requirements/build.in -c requirements/test.lock
compile pip.lock "the pip that installs the other locks (scripts/_env.sh brings the venv's to it first)." \
    requirements/pip.in
compile tools.lock "the resolver this script runs." requirements/tools.in

if git -C "$ROOT" diff --quiet -- requirements/; then
    echo "upgrade-locks.sh: the locks in requirements/ are unchanged" >&2
else
    echo "upgrade-locks.sh: what moved in requirements/ (- committed, + now):" >&2
    git -C "$ROOT" diff -U0 -- requirements/ | grep -E '^([-+][a-z0-9]|\+\+\+ )' | sed 's/ \\$//' >&2 || true
fi

[ "$run_tests" -eq 1 ] || exit 0
export EDGEDSM_VENV="${EDGEDSM_VENV:-$ROOT/.venv-newest}"
# The demo's install from demo.lock (in a venv of its own), then the suite from test.lock.
(VENV_BASE="$EDGEDSM_VENV"; export EDGEDSM_VENV="$VENV_BASE-demo"
 source "$ROOT/scripts/_env.sh"; ensure_venv demo; "$VENV/bin/edgedsm" --help >/dev/null)
echo "upgrade-locks.sh: demo.lock installs; now the suite on test.lock in $EDGEDSM_VENV" >&2
exec "$ROOT/scripts/test.sh" "${test_args[@]}"
