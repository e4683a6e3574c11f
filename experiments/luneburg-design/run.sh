#!/usr/bin/env bash
# Recover a Luneburg lens by design: see README.md.
set -euo pipefail
cd "$(dirname "$0")"
time cargo run --release -q -- design luneburg.toml --out out
python3 compare.py out/design.json
