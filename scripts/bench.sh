#!/usr/bin/env bash
# Runs gonio's benchmarks and, when they can be installed, their peers on the same inputs
# (scipy's Nelder–Mead and least_squares on the same samples and model, OpenCV's Debevec
# merge on the same frames), then writes README.md's "What accuracy costs in time" table
# from what it measured (scripts/bench_table.py), each row against its floor (what this
# machine allows: its memory bandwidth, one point of a fit's loss): no number in it is
# written by hand.
# The peers go into a virtual environment of their own, .venv-bench/ (numpy, scipy,
# opencv-python-headless from PyPI); --no-peers skips them.
# The machine must be idle: with a load average above 0.5, or a virtual machine whose host
# takes more than 5 % of its CPU time (steal), it refuses to start; the table is not
# written when a measurement was too unsteady or the host took more than that over the
# run (scripts/bench_table.py); the table states the load average when the run started
# and the steal over the run.
# Usage: bash scripts/bench.sh [--no-peers]
set -euo pipefail
cd "$(dirname "$0")/.."

peers=1
if [ "${1:-}" = --no-peers ]; then
    peers=0
fi
# Busier than this (the 1-minute load average), the numbers would measure the other work.
max_load=0.5
load=$(cut -d' ' -f1 /proc/loadavg)
if ! python3 -c 'import sys; sys.exit(float(sys.argv[1]) > float(sys.argv[2]))' "$load" "$max_load"; then
    echo "bench.sh: the machine is busy (load average $load, above $max_load): not measuring" >&2
    exit 1
fi
# Nor does it see the CPU time a virtual machine's host gives to other guests (steal):
# more of it than scripts/bench_table.py's MAX_STEAL over a few seconds before the run,
# or over the whole run (which that script checks), and the numbers would measure the host.
max_steal=$(python3 -c 'import sys; sys.path.insert(0, "scripts"); import bench_table; print(bench_table.MAX_STEAL)')
# Ticks of every CPU since boot, and those stolen (/proc/stat: user nice system idle
# iowait irq softirq steal).
cpu_ticks() {
    awk '/^cpu / { print $2 + $3 + $4 + $5 + $6 + $7 + $8 + $9, $9 }' /proc/stat
}
# The share stolen between two `cpu_ticks` readings (total₀ steal₀ total₁ steal₁).
steal_share() {
    python3 -c 'import sys; t0, s0, t1, s1 = map(float, sys.argv[1:]); print(f"{(s1 - s0) / max(t1 - t0, 1):.4f}")' "$@"
}
read -r total_before steal_before < <(cpu_ticks)
sleep 5
read -r total_now steal_now < <(cpu_ticks)
steal=$(steal_share "$total_before" "$steal_before" "$total_now" "$steal_now")
if ! python3 -c 'import sys; sys.exit(float(sys.argv[1]) > float(sys.argv[2]))' "$steal" "$max_steal"; then
    echo "bench.sh: the host takes $steal of the CPU time (steal, above $max_steal): not measuring" >&2
    exit 1
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir -p target/bench
results="$PWD/target/bench/results.jsonl"
: >"$results"
target=${CARGO_TARGET_DIR:-target}
gonio=$target/release/gonio

# Shows a benchmark's output and keeps its result lines (`{"bench": ...}`) for the table.
keep() {
    tee /dev/stderr | { grep '^{"bench"' || true; } >>"$results"
}

# One JSON line for the table: bench name, then the object on stdin merged in.
record() {
    python3 -c 'import json, sys; print(json.dumps({"bench": sys.argv[1], **json.load(sys.stdin)}))' "$1" >>"$results"
}

conditions() {
    local cpu
    cpu=$(grep -m1 'model name' /proc/cpuinfo | sed 's/.*: //' || echo unknown)
    printf '{"date": "%s", "cpu": "%s", "cores": %s, "load": "%s"}' \
        "$(date -u +%Y-%m-%d)" "$cpu" "$(nproc)" "$(cut -d' ' -f1 /proc/loadavg)" | record conditions
}

# The inputs: a full-size gold scan and its samples; 8-bit frames for the OpenCV peer.
inputs() {
    cargo build --release --locked -p gonio-daemon
    "$gonio" simulate --scene gold --out "$work/gold" >/dev/null
    "$gonio" extract "$work/gold" --out "$work/gold/samples.csv" >/dev/null
    # The gold scene with an 8-bit non-linear response and a 7-exposure bracket.
    sed 's/^bracket_s = .*/bracket_s = [1.0, 0.5, 0.25, 0.125, 0.0625, 0.03125, 0.015625]/' \
        mock-hw/scenes/gold.toml >"$work/gold-8bit.toml"
    printf '\n[effects.response]\ngamma = 2.2\n' >>"$work/gold-8bit.toml"
    "$gonio" simulate --scene "$work/gold-8bit.toml" --theta-l -20 --out "$work/gold-8bit" >/dev/null
}

criterion_benches() {
    GONIO_BENCH_SAMPLES="$work/gold/samples.csv" cargo bench --locked -p gonio-processing --bench fit | keep
    cargo bench --locked -p gonio-processing --bench study | keep
    cargo bench --locked -p gonio-processing --bench hdr
    GONIO_BENCH_SCAN="$work/gold" cargo bench --locked -p gonio-processing --bench extract | keep
    cargo bench --locked -p gonio-processing --bench floors | keep
    cargo bench --locked -p gonio-mock-hw --bench render
}

# Peak memory of the linear merge alone, from its benchmark binary.
hdr_memory() {
    local bin peak
    bin=$(cargo bench --locked -p gonio-processing --bench hdr --no-run --message-format=json 2>/dev/null |
        python3 -c 'import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("executable") and m.get("target", {}).get("name") == "hdr":
        print(m["executable"])')
    peak=$(/usr/bin/time -f '%M' "$bin" --bench linear --profile-time 2 2>&1 >/dev/null | tail -1)
    echo "{\"peak_bytes\": $((peak * 1024))}" | record hdr_memory
}

process_benches() {
    cargo bench --locked -p gonio-daemon --bench study_command | keep
    cargo bench --locked -p gonio-daemon --bench fit_auto_command | keep
    cargo bench --locked -p gonio-daemon --bench hdr_command | keep
    cargo bench --locked -p gonio-daemon --bench scan -- --runs 5 | keep
    # The same scan at the hardware's own speeds (the emulators' time scale 1): a lab's
    # scan, whose steps leave the processing more time beside them. One run of a minute.
    cargo bench --locked -p gonio-daemon --bench scan -- --runs 1 --time-scale 1 |
        sed 's/^{"bench":"scan"/{"bench":"scan_time_scale_1"/' | keep
}

install_peers() {
    [ "$peers" = 1 ] || return 1
    if [ ! -x .venv-bench/bin/python ]; then
        python3 -m venv .venv-bench || return 1
    fi
    .venv-bench/bin/pip install --quiet --disable-pip-version-check \
        numpy scipy opencv-python-headless || return 1
}

peer_benches() {
    if ! install_peers; then
        echo "peers not installed: their rows say so"
        return 0
    fi
    .venv-bench/bin/python scripts/bench_peers.py fit "$work/gold/samples.csv" --repeats 3 |
        record peers_fit
    .venv-bench/bin/python scripts/bench_peers.py hdr --gonio "$gonio" \
        "$work/gold-8bit/theta_l_-20.0/"*.tiff | record peers_hdr
}

started=$(date +%s)
conditions
inputs
criterion_benches
hdr_memory
process_benches
peer_benches
echo "{\"seconds\": $(($(date +%s) - started))}" | record duration
read -r total_now steal_now < <(cpu_ticks)
echo "{\"share\": $(steal_share "$total_before" "$steal_before" "$total_now" "$steal_now")}" | record steal
python3 scripts/bench_table.py "$results" --criterion "$target/criterion"
echo "README.md's table rewritten from $results"
