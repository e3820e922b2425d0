#!/usr/bin/env bash
# Regenerates docs/results: for each example scene, simulate a full scan (6 θL, the
# scene's bracket), extract the samples, run the θL-combination study against the
# scene's reference (every model, scored on all points and on the held-out θL), and the
# accuracy-against-time tradeoff on the same scan (the scene's own model, or
# Cook–Torrance–Fresnel for the goniochromatic scenes).
# Usage: bash scripts/results.sh [SCENE...]   (default: gold red blue-green opal)
set -euo pipefail
cd "$(dirname "$0")/.."

cargo build --release --locked -p gonio-daemon
gonio=target/release/gonio
scans=$(mktemp -d)
trap 'rm -rf "$scans"' EXIT

scenes=("$@")
if [ ${#scenes[@]} -eq 0 ]; then
    scenes=(gold red blue-green opal)
fi

for scene in "${scenes[@]}"; do
    scan="$scans/$scene"
    out="docs/results/$scene"
    rm -rf "$out"
    mkdir -p "$out"
    echo "== $scene: simulate"
    "$gonio" simulate --scene "$scene" --out "$scan"
    cp "$scan/truth.json" "$scan/setup.json" "$out/"
    white=$(grep -o '"white_reflectance": *[0-9.eE+-]*' "$scan/truth.json" | sed 's/.*: *//')
    echo "== $scene: extract (white reflectance $white)"
    "$gonio" extract "$scan" --out "$scan/samples.csv" --white-reflectance "$white" \
        | sed "s|$scans/|<scans>/|g" | tee "$out/extract.txt"
    # The goniochromatic samples are also fitted with one roughness per channel (paper
    # eq. 8, 9).
    study_roughness=shared
    if [ "$scene" = blue-green ] || [ "$scene" = opal ]; then
        study_roughness=both
    fi
    echo "== $scene: study"
    "$gonio" study "$scan/samples.csv" --reference "$scan/reference.csv" --out "$out/study" \
        --roughness "$study_roughness" --name "$scene" | tee "$out/study.txt"
    echo "== $scene: tradeoff"
    "$gonio" tradeoff --scene "$scene" --scan "$scan" --out "$out/tradeoff" \
        | tee "$out/tradeoff.txt"
done
echo "results written under docs/results/"
