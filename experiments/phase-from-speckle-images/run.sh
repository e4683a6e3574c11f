#!/usr/bin/env bash
# Speckle images of Mie and HG slabs at OD 1, 4, 7 → acquire-phase → recovered g vs the truth.
set -euo pipefail
cd "$(dirname "$0")"
cargo build --release --quiet
mkdir -p out
python3 run.py "$@" | tee out/results.md
