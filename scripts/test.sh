#!/usr/bin/env bash
# The whole test suite, from a fresh machine: installs what the tests need, then runs them.
set -euo pipefail
cd "$(dirname "$0")/.."

# Debian packages the tests need: Chromium for the page's browser tests
# (tests/tests/end_to_end/page_browser.rs, page_states.rs); libgphoto2-dev, libclang-dev (bindgen)
# and pkg-config to build the `gphoto2` feature; python3-venv for the tests' own Python
# below.
missing=()
for pkg in chromium libgphoto2-dev libclang-dev pkg-config python3-venv; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
    echo "installing ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -q </dev/null
    apt-get install -y -q --no-install-recommends "${missing[@]}" </dev/null
fi

# ---- The tests' Python: a virtual environment of its own, .venv-test at the root ----
# (git-ignored, created once and reused), never the system interpreter's packages.
# numpy and OpenCV: the Debevec–Malik test compares our merge with OpenCV's; Mitsuba 3
# (the PyPI wheel mitsuba, with drjit, whose scalar variants run on the CPU) loads and
# evaluates `gonio export --format mitsuba` output. Tests run GONIO_PYTHON.
venv="$PWD/.venv-test"
if [ ! -x "$venv/bin/python" ]; then
    echo "creating $venv"
    python3 -m venv "$venv"
fi
if ! "$venv/bin/python" -c 'import cv2, numpy, mitsuba' 2>/dev/null; then
    echo "installing numpy, opencv-python-headless and mitsuba into $venv"
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check \
        numpy==2.2.6 opencv-python-headless==4.12.0.88 mitsuba==3.9.1 </dev/null
fi
export GONIO_PYTHON="$venv/bin/python"
export GONIO_REQUIRE_OPENCV=1

# The workspace, including the README's offline commands (daemon/tests/cli/readme_commands.rs)
# and the page in Chromium.
cargo test --workspace --locked

# ---- gonio-drivers with the `gphoto2` feature, against libgphoto2's virtual camera ----
cargo test -p gonio-drivers --features gphoto2 --locked --no-run

# Debian's libgphoto2 (2.5.30) has no virtual camera. The PyPI wheel gphoto2==2.6.4
# bundles libgphoto2 2.5.34 with the `vusb` port driver (a virtual Nikon DSC D750).
# Its gphoto2/libgphoto2/libgphoto2.so.6 and libgphoto2_port.so.12 carry the same
# sonames the crate links against, so LD_LIBRARY_PATH swaps them in at run time (their
# own dependencies resolve through their RPATH into the wheel's gphoto2.libs/).
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$GONIO_PYTHON" -m pip download --quiet --disable-pip-version-check --no-deps \
    --only-binary=:all: gphoto2==2.6.4 -d "$work/wheel" </dev/null
"$GONIO_PYTHON" -m zipfile -e "$work"/wheel/gphoto2-2.6.4-*.whl "$work/wheel/unzipped"
lib="$work/wheel/unzipped/gphoto2/libgphoto2"
test -f "$lib/vusb/vusb.so" -a -f "$lib/libgphoto2.so.6" || {
    echo "gphoto2 wheel layout changed: no $lib/vusb/vusb.so" >&2
    exit 1
}
mkdir "$work/vcamera" "$work/home"
cp drivers/tests/fixtures/vcamera.jpg "$work/vcamera/"
# HOME is a scratch directory (libgphoto2 reads ~/.gphoto); keep cargo's and rustup's own.
RUSTUP_HOME="${RUSTUP_HOME:-$HOME/.rustup}" CARGO_HOME="${CARGO_HOME:-$HOME/.cargo}" \
    HOME="$work/home" \
    LD_LIBRARY_PATH="$lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" \
    CAMLIBS="$lib/camlibs" IOLIBS="$lib/vusb" VCAMERADIR="$work/vcamera" \
    cargo test -p gonio-drivers --features gphoto2 --locked

# ---- Mitsuba 3 (in .venv-test) loads and evaluates `gonio export --format mitsuba` output ----
# --workspace: the features the suite was built with, so nothing is compiled again.
cargo test --workspace --test cli --locked -- --ignored export::
