#!/usr/bin/env bash
# The README's second command: install everything the tests need (Debian packages included),
# check the code with ruff, and run the whole test suite.
source "$(dirname "${BASH_SOURCE[0]}")/_env.sh"
# socat: PTY pairs for the emulated relay boards; systemd: systemd-analyze checks the unit
# (procps: the unit's ExecReload=/bin/kill, which `verify` checks).
# chromium + chromium-driver: the dashboard's browser tests (Selenium drives the system browser).
# octave + octave-bsltl: the field's reference toolbox BSLTL, which the descriptors are checked against
# (tests/integration/test_bsltl_conformance.py).
apt_install socat systemd procps mosquitto openssl chromium chromium-driver gir1.2-aravis-0.8 aravis-tools libgirepository1.0-dev libcairo2-dev pkg-config gcc python3-dev octave octave-bsltl
ensure_venv test
cd "$ROOT"
"$VENV/bin/ruff" check edgedsm edgedsm_lab tests
# pytest caches its assert-rewritten test modules in __pycache__ only where Python may write
# bytecode; some images forbid it (PYTHONDONTWRITEBYTECODE), and then each of the run's pytest
# processes rewrote every test module again (7.4 instead of 2.5 CPU-s per collection, 9 of them).
unset PYTHONDONTWRITEBYTECODE
# In parallel (pytest-xdist): most integration tests wait on brokers, daemons and cameras, so more
# workers than cores pay. loadgroup hands out test by test, except that each xdist_group runs on
# one worker (tests/conftest.py). Later arguments win: `./scripts/test.sh -n 0` runs serially.
parallel=("$VENV/bin/python" -m pytest -n "${EDGEDSM_TEST_WORKERS:-4}" --dist loadgroup)
if [ $# -gt 0 ]; then
    exec "${parallel[@]}" "$@"
fi
# The whole suite in two phases. The tests marked `alone` bound wall-clock times that tests beside
# them would push over: first they run one after the other with no other test of theirs beside
# them, then the rest in parallel. (Under xdist an `alone` test waits for every running test to end
# while the other workers wait for it: the suite's cores sat idle for minutes.) The `alone` tests
# mostly wait on timers, daemons and cameras: beside them the tests that only compute (marker
# `compute`, tests/conftest.py) run at idle priority (SCHED_IDLE), which takes a core only while
# nothing else wants it, so the `alone` tests keep their cores whenever they need them; each
# module's tests on one worker (loadscope), so a module fixture (a benchmark's quick run) is
# computed once. Their report comes after the `alone` tests' one.
status=0
compute_log="$(mktemp "${TMPDIR:-/tmp}/edgedsm-compute-tests.XXXXXX")"
chrt --idle 0 "$VENV/bin/python" -m pytest -n 2 --dist loadscope -m "compute and not alone" \
    >"$compute_log" 2>&1 &
compute=$!
trap 'kill "$compute" 2>/dev/null; rm -f "$compute_log"' EXIT
"$VENV/bin/python" -m pytest -n 0 -m alone || status=$?
echo "edgedsm: the alone tests are done; waiting for the compute tests that ran beside them" >&2
wait "$compute" || status=$?
trap 'rm -f "$compute_log"' EXIT  # reaped: its process id may be another's now
cat "$compute_log"
"${parallel[@]}" -m "not alone and not compute" || status=$?
exit "$status"
