#!/usr/bin/env bash
# Checks the ClusterFuzzLite / OSS-Fuzz build outside the container, as CI runs it:
# .clusterfuzzlite/build.sh run as the OSS-Fuzz image runs it (fuzz/cflite-build-local.sh:
# $SRC, $WORK, the sanitizer's CC/CFLAGS/RUSTFLAGS) into a temporary OUT (or $OUT), which
# checks that every target landed there; then for every target that
# $OUT holds a runnable binary, <target>_seed_corpus.zip and <target>.dict, and that the
# binary runs its seeds and FUZZ_RUNS (default 3000) mutated inputs without a finding.
# FUZZ_SECONDS, when set, makes each run a time-bounded fuzz smoke instead.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
start=$SECONDS
OUT="${OUT:-$(mktemp -d)}"
export OUT
"$repo/fuzz/cflite-build-local.sh"
mapfile -t targets < <(sed -n 's/^name = "\(.*\)"$/\1/p' "$repo/fuzz/Cargo.toml" | grep -v '^conformance-fuzz$')
built=$SECONDS
fail=0
for t in "${targets[@]}"; do
  for f in "$t" "${t}_seed_corpus.zip" "$t.dict"; do
    if [ ! -s "$OUT/$f" ]; then echo "$t: $OUT/$f missing"; fail=1; continue 2; fi
  done
  seeds="$(mktemp -d)"
  unzip -q "$OUT/${t}_seed_corpus.zip" -d "$seeds"
  nseeds="$(find "$seeds" -type f | wc -l)"
  log="$(mktemp)"
  if [ -n "${FUZZ_SECONDS:-}" ]; then bound="-max_total_time=$FUZZ_SECONDS"; else bound="-runs=${FUZZ_RUNS:-3000}"; fi
  # A copy of the seeds is the working corpus: nothing is written back into $OUT.
  if (cd "$seeds" && "$OUT/$t" "$bound" -dict="$OUT/$t.dict" -artifact_prefix="$seeds/../$t-" \
      -print_final_stats=1 "$seeds") >"$log" 2>&1; then
    runs="$(sed -n 's/^stat::number_of_executed_units: *//p' "$log")"
    cov="$(grep -o 'cov: [0-9]*' "$log" | tail -1)"
    printf '%-18s ok: %s seeds, %s executions, %s\n' "$t" "$nseeds" "$runs" "$cov"
  else
    tail -40 "$log"
    echo "$t: FAILED on its seed corpus (log above)"
    fail=1
  fi
  rm -rf "$seeds" "$log"
done
echo "check-build: build $((built - start)) s, runs $((SECONDS - built)) s, OUT=$OUT"
exit "$fail"
