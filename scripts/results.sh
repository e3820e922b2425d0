#!/usr/bin/env bash
# Regenerates docs/results: for each example scene, simulate a full scan (6 θL, the
# scene's bracket), extract the samples, run the θL-combination study against the
# scene's reference (every model, scored on all points and on the held-out θL), and the
# accuracy-against-time tradeoff on the same scan (the scene's own model, or
# Cook–Torrance–Fresnel for the goniochromatic scenes); then write the tables of
# docs/results/README.md and the README's Results summary from those outputs
# (scripts/results_docs.py), so that no number in them is written by hand.
# One function per section; a new section adds its function and its call in main.
# Usage: bash scripts/results.sh [SCENE...]   (default: gold red blue-green opal)
set -euo pipefail
cd "$(dirname "$0")/.."

gonio=${CARGO_TARGET_DIR:-target}/release/gonio

# Simulates SCENE's full scan into $scans/SCENE and extracts its samples there; keeps
# the scene's truth, setup and the extraction's summary in docs/results/SCENE.
scan_section() {
    local scene=$1 scan="$scans/$1" out="docs/results/$1"
    rm -rf "$out"
    mkdir -p "$out"
    echo "== $scene: simulate"
    "$gonio" simulate --scene "$scene" --out "$scan"
    cp "$scan/truth.json" "$scan/setup.json" "$out/"
    local white
    white=$(grep -o '"white_reflectance": *[0-9.eE+-]*' "$scan/truth.json" | sed 's/.*: *//')
    echo "== $scene: extract (white reflectance $white)"
    "$gonio" extract "$scan" --out "$scan/samples.csv" --white-reflectance "$white" \
        | sed "s|$scans/|<scans>/|g" | tee "$out/extract.txt"
}

# The θL-combination study of SCENE's samples against its reference.
study_section() {
    local scene=$1 scan="$scans/$1" out="docs/results/$1"
    # The goniochromatic samples are also fitted with one roughness per channel (paper
    # eq. 8, 9).
    local roughness=shared
    if [ "$scene" = blue-green ] || [ "$scene" = opal ]; then
        roughness=both
    fi
    echo "== $scene: study"
    "$gonio" study "$scan/samples.csv" --reference "$scan/reference.csv" --out "$out/study" \
        --roughness "$roughness" --name "$scene" | tee "$out/study.txt"
}

# Acquisition and processing time against accuracy on SCENE's scan.
tradeoff_section() {
    local scene=$1 scan="$scans/$1" out="docs/results/$1"
    echo "== $scene: tradeoff"
    "$gonio" tradeoff --scene "$scene" --scan "$scan" --out "$out/tradeoff" \
        | tee "$out/tradeoff.txt"
}

# The tables of docs/results/README.md and the README's summary, from the outputs.
docs_section() {
    echo "== tables of docs/results/README.md and README.md"
    python3 scripts/results_docs.py
}

main() {
    cargo build --release --locked -p gonio-daemon
    scans=$(mktemp -d)
    trap 'rm -rf "$scans"' EXIT
    local scenes=("$@")
    if [ ${#scenes[@]} -eq 0 ]; then
        scenes=(gold red blue-green opal)
    fi
    for scene in "${scenes[@]}"; do
        scan_section "$scene"
        study_section "$scene"
        tradeoff_section "$scene"
    done
    docs_section
    echo "results written under docs/results/"
}

main "$@"
