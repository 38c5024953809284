//! Links `asan_options.c` (AddressSanitizer defaults, see there) into every fuzz target.

fn main() {
    println!("cargo:rerun-if-changed=asan_options.c");
    cc::Build::new()
        .file("asan_options.c")
        .cargo_metadata(false)
        .compile("asan_options");
    let out = std::env::var("OUT_DIR").expect("cargo sets OUT_DIR");
    // As an object, not an archive member: nothing references the symbol, and a weak
    // definition in the sanitizer runtime would keep an archive member out of the link.
    let objects: Vec<_> = std::fs::read_dir(&out)
        .expect("OUT_DIR")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "o"))
        .collect();
    for o in objects {
        println!("cargo:rustc-link-arg-bins={}", o.display());
    }
}
