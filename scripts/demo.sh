#!/usr/bin/env bash
# The README's first command: set up, then run the main job on the built-in simulated default.
source "$(dirname "${BASH_SOURCE[0]}")/_env.sh"
# mosquitto: the private broker the daemon demo publishes to; openssl: its TLS certificates
apt_install mosquitto openssl
ensure_venv demo  # requirements/demo.lock: the runtime dependencies and numba ([fast])
exec "$VENV/bin/edgedsm" demo "$@"
