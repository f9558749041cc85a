#!/usr/bin/env bash
# Regenerates everything in docs/results/ from the shared data sets (SPEC §7).
# Usage: docs/results/reproduce.sh [DATA_DIR]   (default: ../shared/data beside the repository)
# Cost on a 2-core machine: about 45 min, most of it the parameter study's re-extractions.
set -euo pipefail
repo="$(cd "$(dirname "$0")/../.." && pwd)"
data="$(cd "${1:-$repo/../shared/data}" && pwd)"
out="$repo/docs/results"
cache="$repo/target/eval-cache"
cargo build --release --manifest-path "$repo/Cargo.toml"
salient="nice -n 19 $repo/target/release/salient"
cd "$data" # relative collection paths in the reports
for set in shrec07-watertight capod; do
    # The default (hybrid) beside every single method, including the paper's Fig. 14
    # comparison; then SPEC's ECC against the paper read literally.
    $salient eval retrieval "$set" --methods hybrid,ecc,d2,lfd,geodesic --cache-dir "$cache/$set" \
        --out "$out/$set"
    $salient eval retrieval "$set" --methods ecc,ecc-paper --cache-dir "$cache/$set" \
        --out "$out/ecc-paper-$set"
    rm "$out/ecc-paper-$set/distances-ecc.csv" # the same as in "$out/$set"
    gzip -9nf "$out/$set"/distances-*.csv "$out/ecc-paper-$set"/distances-*.csv
    $salient eval study "$set" --cache-dir "$cache/$set" --out "$out/study-$set"
done
# The hybrid's weights, on the tuning halves of both collections together (its params.json is
# the default HybridParams), then retrieval on a copy of SHREC'07 with 1 % noise.
$salient eval tune shrec07-watertight capod --cache-dir "$cache" --out "$out/tune"
$salient eval retrieval shrec07-watertight --methods hybrid,ecc,d2,lfd,geodesic --perturb noise=0.01 \
    --cache-dir "$cache/shrec07-watertight" --out "$out/noise-shrec07-watertight"
gzip -9nf "$out/noise-shrec07-watertight"/distances-*.csv
# Near-duplicates: disguised copies mixed into each collection; thresholds chosen on the
# tuning halves, judged on the held-out ones.
for set in shrec07-watertight capod; do
    for half in tuning held-out; do
        $salient eval duplicates "$set" --half "$half" --out "$out/duplicates/$set-$half"
    done
done
# Partial retrieval: a part cut from every model of each half, searched as a part (fitted,
# then verified by registration) and as a whole model; the part sizes and the registration's
# settings were chosen on the tuning halves.
for set in shrec07-watertight capod; do
    for half in tuning held-out; do
        $salient eval partial "$set" --half "$half" --cache-dir "$cache/$set" \
            --out "$out/partial/$set-$half"
    done
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
