//! Compiles the C++ shim around MRPT (`shim/mrpt_peer.cpp`) and links MRPT's libraries.
//!
//! MRPT is found with pkg-config (`mrpt-maps`) where its installation ships `.pc` files. Debian's
//! `libmrpt-dev` (MRPT 2.5) ships only CMake package files, with each module's headers under
//! `/usr/include/mrpt/<module>/include`: without pkg-config that layout is used, under
//! `$MRPT_INCLUDE_DIR` (default `/usr/include/mrpt`), with Eigen's and SuiteSparse's Debian
//! include directories, which MRPT's math headers need.

use std::path::{Path, PathBuf};

/// The MRPT libraries the shim calls into (directly or through inline header code).
const LIBRARIES: [&str; 8] = [
    "mrpt-maps",
    "mrpt-obs",
    "mrpt-poses",
    "mrpt-math",
    "mrpt-serialization",
    "mrpt-rtti",
    "mrpt-system",
    "mrpt-core",
];

fn main() {
    println!("cargo:rerun-if-changed=shim/mrpt_peer.cpp");
    println!("cargo:rerun-if-env-changed=MRPT_INCLUDE_DIR");
    let mut build = cc::Build::new();
    build
        .cpp(true)
        .std("c++17")
        .file("shim/mrpt_peer.cpp")
        // MRPT's own headers warn under -Wall -Wextra (overloaded virtuals); not ours to fix.
        .warnings(false);
    match pkg_config::Config::new()
        .atleast_version("2.5")
        .probe("mrpt-maps")
    {
        // pkg-config has printed the link flags.
        Ok(library) => {
            build.includes(&library.include_paths);
        }
        Err(pkg_config_error) => {
            let root = std::env::var_os("MRPT_INCLUDE_DIR")
                .map_or_else(|| PathBuf::from("/usr/include/mrpt"), PathBuf::from);
            let modules = module_includes(&root);
            if !modules
                .iter()
                .any(|dir| dir.join("mrpt/maps/COccupancyGridMap2D.h").is_file())
            {
                panic!(
                    "MRPT not found: pkg-config said {pkg_config_error}, and {} holds no \
                     maps/include/mrpt/maps/COccupancyGridMap2D.h. Install Debian's libmrpt-dev \
                     (scripts/bench.sh mrpt does) or set MRPT_INCLUDE_DIR.",
                    root.display()
                );
            }
            build.includes(&modules);
            for dir in ["/usr/include/eigen3", "/usr/include/suitesparse"] {
                if Path::new(dir).is_dir() {
                    build.include(dir);
                }
            }
            for library in LIBRARIES {
                println!("cargo:rustc-link-lib=dylib={library}");
            }
        }
    }
    build.compile("mrpt_peer_shim");
}

/// `<root>/<module>/include` of every module of a Debian-style MRPT installation.
fn module_includes(root: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(root) else {
        return Vec::new();
    };
    let mut dirs: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|entry| entry.path().join("include"))
        .filter(|dir| dir.is_dir())
        .collect();
    dirs.sort();
    dirs
}
