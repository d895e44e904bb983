//! Links Embree 4 for the benchmark peer when the `embree` feature is on (off by default; nothing
//! else in the crate uses it). The library itself is named in `tools/peers/embree.rs`
//! (`#[link(name = "embree4")]`); this only says where it is: the directory in `OAVM_EMBREE_DIR`,
//! as linker search path and as rpath, so the binaries find it at run time. `tools/embree.sh`
//! fetches the library and sets the variable.

fn main() {
    println!("cargo::rerun-if-changed=build.rs");
    println!("cargo::rerun-if-env-changed=OAVM_EMBREE_DIR");
    if std::env::var_os("CARGO_FEATURE_EMBREE").is_none() {
        return;
    }
    let Some(dir) = std::env::var_os("OAVM_EMBREE_DIR") else {
        panic!(
            "the `embree` feature needs OAVM_EMBREE_DIR, the directory holding libembree4.so; \
             run through tools/embree.sh (e.g. `tools/embree.sh cargo bench --bench trace \
             --features embree`) or export what `tools/embree.sh` prints"
        );
    };
    let dir = dir.to_string_lossy();
    println!("cargo::rustc-link-search=native={dir}");
    println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
}
