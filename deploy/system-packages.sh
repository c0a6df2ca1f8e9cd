#!/usr/bin/env bash
# System packages the test suite needs beyond pip: old HDF5 readers for tests/test_old_readers.py (Debian 12's
# Octave 7.3 and h5dump, both on the system HDF5 1.10.8; docs/decisions/0018-hdf5-for-old-readers.md).
# `make test` runs this; it installs only what is missing (apt-get, as root or through sudo) and fails loudly,
# since the tests fail without them. About 20 s on a fresh machine (octave 19 s, hdf5-tools 3 s, measured).
set -euo pipefail
if ! command -v octave >/dev/null || ! command -v h5dump >/dev/null; then
    echo "== installing octave and hdf5-tools for tests/test_old_readers.py"
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    apt_log="$(mktemp)"
    if ! { $sudo apt-get update -qq \
           && $sudo env DEBIAN_FRONTEND=noninteractive \
              apt-get install -y -qq --no-install-recommends octave hdf5-tools; } >"$apt_log" 2>&1; then
        cat "$apt_log" >&2
        echo "system-packages: FAILED to install octave and hdf5-tools (log above); tests/test_old_readers.py needs them" >&2
        exit 1
    fi
    if ! command -v octave >/dev/null || ! command -v h5dump >/dev/null; then
        echo "system-packages: FAILED: octave or h5dump still missing after apt-get install" >&2
        exit 1
    fi
fi
echo "== octave: $(octave --no-gui --norc -q --eval 'printf("%s\n", version)' 2>/dev/null); $(h5dump -V)"
