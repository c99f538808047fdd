//! Compiles the simavr shim (`src/board.c`) and links simavr when `pkg-config` finds it, and sets
//! `cfg(simavr)`. Without simavr the crate still builds (the workspace is built for the robot, where
//! nobody needs a firmware simulator): the binary then says how to install it and exits non-zero.
//!
//! `SONAR_FIRMWARE_SIM_NO_SIMAVR=1` builds without simavr even where it is installed, to try that
//! path.

use std::env;
use std::process::Command;

const INSTALL_HINT: &str = "apt-get install simavr libsimavr-dev libelf-dev";

/// What `pkg-config` says about a package: include directories, library directories, libraries.
#[derive(Debug, Default)]
struct Flags {
    include: Vec<String>,
    link_dirs: Vec<String>,
    libs: Vec<String>,
}

fn pkg_config(args: &[&str]) -> Result<String, String> {
    let program = env::var("PKG_CONFIG").unwrap_or_else(|_| "pkg-config".to_owned());
    let out = Command::new(&program)
        .args(args)
        .output()
        .map_err(|e| format!("cannot run {program}: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "{program} {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    String::from_utf8(out.stdout).map_err(|e| format!("{program} printed non-UTF-8: {e}"))
}

fn probe() -> Result<Flags, String> {
    let mut flags = Flags::default();
    for token in pkg_config(&["--cflags", "--libs", "simavr"])?.split_whitespace() {
        if let Some(dir) = token.strip_prefix("-I") {
            flags.include.push(dir.to_owned());
        } else if let Some(dir) = token.strip_prefix("-L") {
            flags.link_dirs.push(dir.to_owned());
        } else if let Some(lib) = token.strip_prefix("-l") {
            flags.libs.push(lib.to_owned());
        }
    }
    // simavr reads the firmware's ELF file with libelf.
    if !flags.libs.iter().any(|l| l == "elf") {
        flags.libs.push("elf".to_owned());
    }
    Ok(flags)
}

/// The folders `pkg-config` looks for `.pc` files in, those that exist: `PKG_CONFIG_PATH`, then
/// `PKG_CONFIG_LIBDIR` or else its built-in path.
fn pkg_config_search_path() -> Vec<String> {
    let builtin = env::var("PKG_CONFIG_LIBDIR")
        .ok()
        .or_else(|| pkg_config(&["--variable", "pc_path", "pkg-config"]).ok())
        .unwrap_or_default();
    env::var("PKG_CONFIG_PATH")
        .unwrap_or_default()
        .split(':')
        .chain(builtin.trim().split(':'))
        .filter(|dir| !dir.is_empty() && std::path::Path::new(dir).is_dir())
        .map(str::to_owned)
        .collect()
}

fn main() {
    println!("cargo::rustc-check-cfg=cfg(simavr)");
    println!("cargo::rerun-if-changed=build.rs");
    // The firmware's protocol code built for the host, whatever simavr: its command parser is
    // checked against the Rust one (`src/protocol_oracle.rs`).
    for file in ["protocol.c", "protocol.h", "compat.h"] {
        println!("cargo::rerun-if-changed=../firmware/src/{file}");
    }
    cc::Build::new()
        .file("../firmware/src/protocol.c")
        .include("../firmware/src")
        .std("c11")
        .warnings(true)
        .extra_warnings(true)
        .warnings_into_errors(true)
        .compile("sonar_firmware_protocol");
    println!("cargo::rerun-if-changed=src/board.c");
    for var in [
        "SONAR_FIRMWARE_SIM_NO_SIMAVR",
        "PKG_CONFIG",
        "PKG_CONFIG_PATH",
        "PKG_CONFIG_LIBDIR",
    ] {
        println!("cargo::rerun-if-env-changed={var}");
    }
    if env::var_os("SONAR_FIRMWARE_SIM_NO_SIMAVR").is_some_and(|v| !v.is_empty() && v != "0") {
        println!(
            "cargo::warning=SONAR_FIRMWARE_SIM_NO_SIMAVR is set: sonar-firmware-sim is built without simavr"
        );
        return;
    }
    let flags = match probe() {
        Ok(flags) => flags,
        Err(why) => {
            // Installing simavr adds its `.pc` file to one of these folders: watching them makes
            // the next `cargo build` probe again, as the hint below promises.
            for dir in pkg_config_search_path() {
                println!("cargo::rerun-if-changed={dir}");
            }
            println!(
                "cargo::warning=simavr not found ({why}): sonar-firmware-sim is built without it and \
                 will only say so; {INSTALL_HINT}, then cargo build again"
            );
            return;
        }
    };
    let mut build = cc::Build::new();
    build
        .file("src/board.c")
        .std("gnu11")
        .warnings(true)
        .extra_warnings(true);
    for dir in &flags.include {
        build.include(dir);
    }
    build.compile("sonar_board");
    for dir in &flags.link_dirs {
        println!("cargo::rustc-link-search=native={dir}");
    }
    for lib in &flags.libs {
        println!("cargo::rustc-link-lib={lib}");
    }
    println!("cargo::rustc-cfg=simavr");
}
