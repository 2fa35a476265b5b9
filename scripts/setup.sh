#!/usr/bin/env bash
# Install what a fresh Debian machine with Rust lacks for building and testing twistopt.
# Idempotent: only installs what is missing.
set -euo pipefail

need_apt=()
command -v python3 >/dev/null 2>&1 || need_apt+=(python3)
python3 -m pip --version >/dev/null 2>&1 || need_apt+=(python3-pip)
command -v cmake >/dev/null 2>&1 || need_apt+=(cmake)
command -v ccx >/dev/null 2>&1 || need_apt+=(calculix-ccx)   # CalculiX, for the crosscheck test

if [ ${#need_apt[@]} -gt 0 ]; then
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    echo "setup: installing ${need_apt[*]} with apt-get"
    $SUDO apt-get update
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y "${need_apt[@]}"
fi

if ! python3 -c "import meshio, numpy" >/dev/null 2>&1; then
    echo "setup: installing meshio and numpy with pip"
    # Debian 12+ marks the system Python as externally managed: retry with
    # --break-system-packages (user-level install) when the plain install is refused.
    python3 -m pip install --user meshio numpy \
        || python3 -m pip install --user --break-system-packages meshio numpy \
        || python3 -m pip install meshio numpy \
        || python3 -m pip install --break-system-packages meshio numpy
fi
python3 -c "import meshio, numpy; print('setup: meshio', meshio.__version__, 'numpy', numpy.__version__)"
