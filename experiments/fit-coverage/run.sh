#!/usr/bin/env bash
# Coverage of the reported uncertainties: for each parameter set, fit N Monte Carlo targets (each
# at its own seed, 10^5 paths) with a model of 2·10^4 paths at another seed, from a start away from
# the truth, and count how often the truth lies within 1 and 2 reported standard deviations.
# Usage: ./run.sh [N]   (default 30 targets per set; about 15 minutes on 2 cores)
set -euo pipefail
cd "$(dirname "$0")"
n=${1:-30}
cargo build --release -q
lp=../../target/release/lightpath
mkdir -p out
scene() { # mfp albedo phase samples seed
  sed -e "s/MFP/$1/" -e "s/ALBEDO/$2/" -e "s/PHASE/$3/" -e "s/SAMPLES/$4/" -e "s/SEED/$5/" scene.toml.in
}
iso='{ kind = "isotropic" }'
hg_truth='{ kind = "hg", g = 0.5 }'
hg_start='{ kind = "hg", g = 0.3 }'
: > out/fits.tsv
for set in mfp mfp,albedo mfp,g; do
  case $set in
    mfp)        truth=(5.0 1.0 "$iso");      start=(10.0 1.0 "$iso") ;;
    mfp,albedo) truth=(5.0 0.8 "$iso");      start=(7.0 0.95 "$iso") ;;
    mfp,g)      truth=(5.0 1.0 "$hg_truth"); start=(7.0 1.0 "$hg_start") ;;
  esac
  for s in $(seq 1 "$n"); do
    d=out/$set/$s
    mkdir -p "$d"
    scene "${truth[0]}" "${truth[1]}" "${truth[2]}" 100000 "$s" > "$d/truth.toml"
    scene "${start[0]}" "${start[1]}" "${start[2]}" 20000 $((s + 1000)) > "$d/start.toml"
    $lp covariance "$d/truth.toml" --out "$d/target" --quiet > /dev/null
    status=0
    $lp fit "$d/start.toml" --target "$d/target/covariance.json" --fit "$set" --out "$d/fit" --quiet > /dev/null 2> "$d/stderr" || status=$?
    echo -e "$set\t$s\t$status" >> out/fits.tsv
  done
done
python3 analyse.py out
