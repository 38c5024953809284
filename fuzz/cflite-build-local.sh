#!/usr/bin/env bash
# Runs .clusterfuzzlite/build.sh as the OSS-Fuzz base image (base-builder-rust, which
# ClusterFuzzLite uses) runs it, without Docker, and checks that every fuzz target of
# fuzz/Cargo.toml lands in $OUT with its seed zip and dictionary.
#
# What the image gives build.sh, and what this script sets in its place:
# - the project copied to $SRC/teco-modbus-conformance, build.sh copied to $SRC, the
#   working directory the project (the Dockerfile's COPY and WORKDIR): here $SRC is a
#   temporary directory holding a link to this checkout and a copy of build.sh;
# - $OUT (the binaries' directory, /out) and $WORK (scratch, /work): temporary
#   directories unless given;
# - the compile script's environment for SANITIZER=address, FUZZING_ENGINE=libfuzzer,
#   ARCHITECTURE=x86_64, FUZZING_LANGUAGE=rust: CC/CXX clang, CFLAGS/CXXFLAGS with
#   -fsanitize=address -fsanitize=fuzzer-no-link, LIB_FUZZING_ENGINE, and RUSTFLAGS
#   (--cfg fuzzing, debug info, frame pointers), to which `cargo fuzz build` adds its own
#   sanitizer and coverage flags.
#
# Any of these already set in the environment is kept. CARGO_TARGET_DIR defaults to
# fuzz/target-cflite: the image's RUSTFLAGS differ from a plain `cargo fuzz build`'s, and a
# directory of their own keeps the two builds from rebuilding each other.
#
#   fuzz/cflite-build-local.sh            # OUT, WORK temporary; prints OUT
#   OUT=/tmp/out fuzz/cflite-build-local.sh
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
start=$SECONDS

export SANITIZER="${SANITIZER:-address}"
export FUZZING_ENGINE="${FUZZING_ENGINE:-libfuzzer}"
export ARCHITECTURE="${ARCHITECTURE:-x86_64}"
export FUZZING_LANGUAGE="${FUZZING_LANGUAGE:-rust}"
if [ "$SANITIZER" != address ] || [ "$FUZZING_ENGINE" != libfuzzer ]; then
  echo "cflite-build-local: .clusterfuzzlite/project.yaml builds address + libfuzzer only, not $SANITIZER + $FUZZING_ENGINE" >&2
  exit 2
fi
for tool in clang clang++; do
  if ! command -v "$tool" >/dev/null; then
    echo "cflite-build-local: $tool not found (the image builds C and C++ with clang): apt-get install clang libc++-dev libc++abi-dev" >&2
    exit 2
  fi
done
# The image's CXXFLAGS take libc++ (libfuzzer-sys builds libFuzzer's C++ with them).
if ! echo '#include <cstdint>' | clang++ -stdlib=libc++ -x c++ -fsyntax-only - 2>/dev/null; then
  echo "cflite-build-local: clang++ finds no libc++ headers (the image's CXXFLAGS use -stdlib=libc++): apt-get install libc++-dev libc++abi-dev" >&2
  exit 2
fi
export CC="${CC:-clang}"
export CXX="${CXX:-clang++}"
common="-O1 -fno-omit-frame-pointer -gline-tables-only -DFUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION"
sanitizer_flags="-fsanitize=address -fsanitize-address-use-after-scope"
export CFLAGS="${CFLAGS:-$common $sanitizer_flags -fsanitize=fuzzer-no-link}"
export CXXFLAGS="${CXXFLAGS:-$CFLAGS -stdlib=libc++}"
export LIB_FUZZING_ENGINE="${LIB_FUZZING_ENGINE:--fsanitize=fuzzer}"
export RUSTFLAGS="${RUSTFLAGS:---cfg fuzzing -Cdebuginfo=1 -Cforce-frame-pointers}"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$repo/fuzz/target-cflite}"

export OUT="${OUT:-$(mktemp -d)}"
export WORK="${WORK:-$(mktemp -d)}"
mkdir -p "$OUT" "$WORK"
src="$(mktemp -d)"
export SRC="$src"
ln -s "$repo" "$SRC/teco-modbus-conformance"
cp "$repo/.clusterfuzzlite/build.sh" "$SRC/build.sh"
trap 'rm -rf "$src"' EXIT

# As the image's `compile` does: build.sh from the project's directory, under bash -eu.
(cd "$SRC/teco-modbus-conformance" && bash -eu "$SRC/build.sh")

mapfile -t targets < <(sed -n 's/^name = "\(.*\)"$/\1/p' "$repo/fuzz/Cargo.toml" | grep -v '^conformance-fuzz$')
missing=0
for t in "${targets[@]}"; do
  for f in "$t" "${t}_seed_corpus.zip" "$t.dict"; do
    if [ ! -s "$OUT/$f" ]; then
      echo "cflite-build-local: $OUT/$f missing"
      missing=1
    fi
  done
  if [ -s "$OUT/$t" ] && [ ! -x "$OUT/$t" ]; then
    echo "cflite-build-local: $OUT/$t is not executable"
    missing=1
  fi
done
echo "cflite-build-local: ${#targets[@]} targets expected, $(find "$OUT" -maxdepth 1 -type f -perm -u+x | wc -l) binaries in OUT=$OUT, $((SECONDS - start)) s"
exit "$missing"
