#!/usr/bin/env bash
# Regenerates everything in docs/results/ from the shared data sets (SPEC §7).
# Usage: docs/results/reproduce.sh [DATA_DIR]   (default: ../shared/data beside the repository)
# Cost on a 2-core machine: about 25 min, most of it the parameter study's re-extractions.
set -euo pipefail
repo="$(cd "$(dirname "$0")/../.." && pwd)"
data="$(cd "${1:-$repo/../shared/data}" && pwd)"
out="$repo/docs/results"
cache="$repo/target/eval-cache"
cargo build --release --manifest-path "$repo/Cargo.toml"
salient="nice -n 19 $repo/target/release/salient"
cd "$data" # relative collection paths in the reports
for set in shrec07-watertight capod; do
    # The paper's Fig. 14 comparison, then SPEC's ECC against the paper read literally.
    $salient eval retrieval "$set" --methods ecc,d2,lfd --cache-dir "$cache/$set" --out "$out/$set"
    $salient eval retrieval "$set" --methods ecc,ecc-paper --cache-dir "$cache/$set" \
        --out "$out/ecc-paper-$set"
    rm "$out/ecc-paper-$set/distances-ecc.csv" # the same as in "$out/$set"
    gzip -9nf "$out/$set"/distances-*.csv "$out/ecc-paper-$set"/distances-*.csv
    $salient eval study "$set" --cache-dir "$cache/$set" --out "$out/study-$set"
done
for mesh in shrec07-watertight/ant/81.off shrec07-watertight/teddy/171.off \
    shrec07-watertight/hand/181.off capod/dog/m100.obj; do
    name="$(basename "$(dirname "$mesh")")-$(basename "${mesh%.*}")"
    $salient eval robustness "$mesh" --out "$out/robustness/$name"
done
# Pictures: CAPOD only (CC BY 3.0); SHREC'07 meshes must not be redistributed, not even drawn.
for mesh in dog/m100 human/m1 hand/m85 spider/m133 horse/m145 airplane/m37; do
    $salient render "capod/$mesh.obj" -o "$out/renders/capod-${mesh%%/*}-${mesh##*/}.png" --size 320
done
