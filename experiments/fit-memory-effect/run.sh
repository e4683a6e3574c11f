#!/usr/bin/env bash
# Recover (mfp, g) of a slab from its memory-effect curve, rendered at another seed.
set -euo pipefail
cd "$(dirname "$0")"
lp() { cargo run --release -q -- "$@"; }
lp memory-effect truth.toml --out out/target --quiet
time lp fit start.toml --target out/target/memory_effect.json --fit mfp,g --out out/fit --stages 8 --iterations 6 --quiet
