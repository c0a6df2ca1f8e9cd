#!/usr/bin/env bash
# System packages the test suite needs beyond pip:
# - old HDF5 readers for tests/test_old_readers.py (Debian 12's Octave 7.3 and h5dump, both on the system
#   HDF5 1.10.8; docs/decisions/0018-hdf5-for-old-readers.md);
# - headless Chromium and its WebDriver for tests/test_web.py (the live page in a real browser;
#   docs/decisions/0020-live-web-page.md).
# `make test` runs this; it installs only what is missing (apt-get, as root or through sudo) and fails loudly,
# since the tests fail without them. Measured on a fresh machine: octave 19 s, hdf5-tools 3 s,
# chromium + chromium-driver 15 s.
set -euo pipefail
want=()
if ! command -v octave >/dev/null || ! command -v h5dump >/dev/null; then
    want+=(octave hdf5-tools)
fi
if [ ! -x /usr/bin/chromium ] || [ ! -x /usr/bin/chromedriver ]; then
    want+=(chromium chromium-driver)
fi
if [ "${#want[@]}" -gt 0 ]; then
    echo "== installing ${want[*]} (tests/test_old_readers.py, tests/test_web.py)"
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    apt_log="$(mktemp)"
    if ! { $sudo apt-get update -qq \
           && $sudo env DEBIAN_FRONTEND=noninteractive \
              apt-get install -y -qq --no-install-recommends "${want[@]}"; } >"$apt_log" 2>&1; then
        cat "$apt_log" >&2
        echo "system-packages: FAILED to install ${want[*]} (log above); the tests that need them fail" >&2
        exit 1
    fi
    if ! command -v octave >/dev/null || ! command -v h5dump >/dev/null; then
        echo "system-packages: FAILED: octave or h5dump still missing after apt-get install" >&2
        exit 1
    fi
    if [ ! -x /usr/bin/chromium ] || [ ! -x /usr/bin/chromedriver ]; then
        echo "system-packages: FAILED: /usr/bin/chromium or /usr/bin/chromedriver still missing after apt-get install" >&2
        exit 1
    fi
fi
echo "== octave: $(octave --no-gui --norc -q --eval 'printf("%s\n", version)' 2>/dev/null); $(h5dump -V)"
echo "== $(/usr/bin/chromium --version 2>/dev/null); $(/usr/bin/chromedriver --version 2>/dev/null | cut -d' ' -f1-2)"
