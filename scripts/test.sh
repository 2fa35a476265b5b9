#!/usr/bin/env bash
# Set up (idempotent) and run the whole test suite in release mode.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo test --release --workspace
