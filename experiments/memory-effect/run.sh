#!/usr/bin/env bash
# Reproduce paper 001, Fig. 10a (memory effect vs optical depth) with lightpath.
set -euo pipefail
cd "$(dirname "$0")"
for od in 5 10 20; do
  cargo run --release -q -- memory-effect od$od.toml --out out/od$od --quiet
done
