#!/usr/bin/env bash
# Set up (idempotent) and run the whole test suite in release mode.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo test --release --workspace
# the optimiser without the nlopt feature (pure-Rust SQP only): builds and solves the same problems
cargo test --release -p twistopt --no-default-features --test optimise
