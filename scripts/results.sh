#!/usr/bin/env bash
# Regenerates docs/results: for each example scene, simulate a full scan (6 θL, the
# scene's bracket), extract the samples, run the θL-combination study against the
# scene's reference, and the accuracy-against-time tradeoff on the same scan.
# Usage: bash scripts/results.sh [SCENE...]   (default: gold red blue-green)
set -euo pipefail
cd "$(dirname "$0")/.."

cargo build --release --locked -p gonio-daemon
gonio=target/release/gonio
scans=$(mktemp -d)
trap 'rm -rf "$scans"' EXIT

scenes=("$@")
if [ ${#scenes[@]} -eq 0 ]; then
    scenes=(gold red blue-green)
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
    # The goniochromatic sample is also fitted with one roughness per channel (paper eq. 8, 9).
    study_roughness=shared
    tradeoff_roughness=()
    if [ "$scene" = blue-green ]; then
        study_roughness=both
        tradeoff_roughness=(--roughness per-channel)
    fi
    echo "== $scene: study"
    "$gonio" study "$scan/samples.csv" --reference "$scan/reference.csv" --out "$out/study" \
        --roughness "$study_roughness" --name "$scene" | tee "$out/study.txt"
    echo "== $scene: tradeoff"
    "$gonio" tradeoff --scene "$scene" --scan "$scan" --out "$out/tradeoff" \
        "${tradeoff_roughness[@]}" | tee "$out/tradeoff.txt"
done
echo "results written under docs/results/"
