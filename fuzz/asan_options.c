/* AddressSanitizer defaults for every fuzz target (linked by build.rs; the environment's
 * ASAN_OPTIONS, as ClusterFuzzLite and OSS-Fuzz set it, still overrides them).
 *
 * detect_stack_use_after_return=0: since LLVM 15 ASan moves every frame with an
 * address-taken local to a heap "fake stack" on each call, to catch a pointer to a dead
 * frame being used. Safe Rust cannot do that (the borrow checker rejects it) and the one
 * unsafe module (codec::crc_clmul, SIMD loads from a slice) keeps no pointer past its
 * call; the fake stack cost the targets 10-20% of their time. Every other check stays. */
const char *__asan_default_options(void) {
  return "detect_stack_use_after_return=0";
}
