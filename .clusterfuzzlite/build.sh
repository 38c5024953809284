#!/bin/bash -eu
# Builds every fuzz target for ClusterFuzzLite / OSS-Fuzz and puts into $OUT, per target:
# the binary, <target>_seed_corpus.zip (the kept corpus fuzz/corpus-kept/<target>, the
# vectors' seeds fuzz/corpus/<target> when generated, and the regression inputs
# fuzz/regressions/<target>) and <target>.dict (fuzz/modbus.dict).
#
# In the builder image (Dockerfile) OUT, SRC and the toolchain are set and the working
# directory is the repository. Outside it, only OUT is needed:
#   OUT=/tmp/out .clusterfuzzlite/build.sh
# REPO (default: the working directory if it holds fuzz/Cargo.toml, else this script's
# parent, else $SRC/teco-modbus-conformance), CARGO_TARGET_DIR (default fuzz/target),
# CARGO_BUILD_TARGET (default the host triple), FUZZ_BUILD_FLAGS (extra `cargo fuzz
# build` flags) are honoured; without a nightly rustc on PATH the nightly toolchain is
# used through rustup.
#
# Built with debug assertions and overflow checks (`--debug-assertions`): an arithmetic
# overflow on hostile input is a finding, not a silent wrap (a release build wrapped a
# piece length in the tap framer that a debug build caught: fuzz/README.md).

: "${OUT:?set OUT to the output directory}"
mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
if [ -z "${REPO:-}" ]; then
  for cand in "$PWD" "$here/.." "${SRC:-/src}/teco-modbus-conformance"; do
    if [ -f "$cand/fuzz/Cargo.toml" ]; then REPO="$cand"; break; fi
  done
fi
: "${REPO:?cannot find the repository (a directory with fuzz/Cargo.toml): set REPO}"
REPO="$(cd "$REPO" && pwd)"
export SRC="${SRC:-$(dirname "$REPO")}"

# cargo-fuzz needs nightly. The builder image's default toolchain is nightly; a developer
# machine's usually is not.
if ! rustc --version 2>/dev/null | grep -q nightly && [ -z "${RUSTUP_TOOLCHAIN:-}" ] \
  && command -v rustup >/dev/null; then
  export RUSTUP_TOOLCHAIN=nightly
fi

triple="${CARGO_BUILD_TARGET:-$(rustc -vV | sed -n 's/^host: //p')}"
cd "$REPO/fuzz"
# shellcheck disable=SC2086 # FUZZ_BUILD_FLAGS is a list of flags
cargo fuzz build -O --debug-assertions --target "$triple" ${FUZZ_BUILD_FLAGS:-}
bin_dir="${CARGO_TARGET_DIR:-$REPO/fuzz/target}"
case "$bin_dir" in /*) ;; *) bin_dir="$REPO/fuzz/$bin_dir" ;; esac
bin_dir="$bin_dir/$triple/release"

zip_dir() { # zip_dir ZIP DIR...: the files of the DIRs, flat, into ZIP
  local zip="$1"; shift
  rm -f "$zip"
  if command -v zip >/dev/null; then
    local d
    for d in "$@"; do
      if [ -d "$d" ] && [ -n "$(ls -A "$d")" ]; then zip -q -j -r "$zip" "$d" -x "*/.*"; fi
    done
  else
    python3 - "$zip" "$@" <<'PY'
import os, sys, zipfile
with zipfile.ZipFile(sys.argv[1], "w", zipfile.ZIP_DEFLATED) as z:
    for d in sys.argv[2:]:
        if os.path.isdir(d):
            for n in sorted(os.listdir(d)):
                p = os.path.join(d, n)
                if os.path.isfile(p) and not n.startswith("."):
                    z.write(p, n)
PY
  fi
}

targets="$(cargo fuzz list)"
for t in $targets; do
  cp "$bin_dir/$t" "$OUT/"
  # The kept corpus, the seeds from the vectors when generated (fuzz/corpus, see
  # fuzz/README.md) and the regression inputs.
  zip_dir "$OUT/${t}_seed_corpus.zip" "$REPO/fuzz/corpus-kept/$t" "$REPO/fuzz/corpus/$t" \
    "$REPO/fuzz/regressions/$t"
  cp "$REPO/fuzz/modbus.dict" "$OUT/$t.dict"
done
echo "build.sh: $(echo $targets | wc -w) targets in $OUT"
