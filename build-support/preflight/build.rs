//! lpmsplat's build script compiles the shaders with the `shaderc` crate, which
//! `.cargo/config.toml` links against Debian's static shaderc / glslang / SPIRV-Tools archives.
//! When those archives are missing the linker fails with "could not find native static library
//! shaderc_combined", which says nothing about the fix. This build script runs first (it is a
//! build-dependency of lpmsplat) and fails with the package names and the command instead.

use std::path::PathBuf;

/// The archives `.cargo/config.toml` links, with the Debian package that ships each.
const ARCHIVES: &[(&str, &str)] = &[
    ("libshaderc_combined.a", "libshaderc-dev"),
    ("libglslang.a", "glslang-dev"),
    ("libSPIRV.a", "glslang-dev"),
    ("libSPIRV-Tools-opt.a", "spirv-tools"),
    ("libSPIRV-Tools.a", "spirv-tools"),
];

fn main() {
    println!("cargo:rerun-if-env-changed=SHADERC_LIB_DIR");
    println!("cargo:rerun-if-env-changed=LPMSPLAT_SKIP_PREFLIGHT");
    if std::env::var_os("LPMSPLAT_SKIP_PREFLIGHT").is_some() {
        return;
    }
    let os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    let arch = std::env::var("CARGO_CFG_TARGET_ARCH").unwrap_or_default();
    let env = std::env::var("CARGO_CFG_TARGET_ENV").unwrap_or_default();
    // The override in .cargo/config.toml covers exactly these two targets; elsewhere the
    // shaderc crate finds (or builds) shaderc itself and reports its own errors.
    if os != "linux" || env != "gnu" || !(arch == "x86_64" || arch == "aarch64") {
        return;
    }
    let dir = match std::env::var_os("SHADERC_LIB_DIR") {
        Some(d) => PathBuf::from(d),
        None => PathBuf::from(format!("/usr/lib/{arch}-linux-gnu")),
    };
    let mut missing = Vec::new();
    let mut packages: Vec<&str> = Vec::new();
    // shaderc-sys's build (link-cplusplus) needs a C++ compiler even with the link override.
    println!("cargo:rerun-if-env-changed=CXX");
    println!("cargo:rerun-if-env-changed=PATH");
    if !cxx_available() {
        missing.push("a C++ compiler (`c++`, or the one $CXX names)".to_string());
        packages.push("g++");
    }
    for (file, package) in ARCHIVES {
        let path = dir.join(file);
        // A missing file counts as changed, so the check repeats until the archive appears.
        println!("cargo:rerun-if-changed={}", path.display());
        if !path.is_file() {
            missing.push(path.display().to_string());
            if !packages.contains(package) {
                packages.push(package);
            }
        }
    }
    if missing.is_empty() {
        return;
    }
    panic!(
        "\n\nlpmsplat cannot be built: what the shader compiler needs is missing:\n  {}\n\
         Fix (Debian 12 / Ubuntu): `bash scripts/install-deps.sh` (installs everything lpmsplat \
         needs), or `sudo apt-get install {}`.\n\
         Elsewhere: install shaderc, glslang and SPIRV-Tools with static archives and point \
         SHADERC_LIB_DIR at their folder (and adjust .cargo/config.toml's `shaderc` link \
         override), or set LPMSPLAT_SKIP_PREFLIGHT=1 to skip this check.\n",
        missing.join("\n  "),
        packages.join(" ")
    );
}

/// Whether `$CXX` (or `c++`) resolves to an executable on PATH.
fn cxx_available() -> bool {
    let cxx = std::env::var("CXX").unwrap_or_else(|_| "c++".to_string());
    let cxx = cxx.split_whitespace().next().unwrap_or("c++").to_string();
    if cxx.contains('/') {
        return std::path::Path::new(&cxx).is_file();
    }
    std::env::var_os("PATH")
        .map(|paths| std::env::split_paths(&paths).any(|d| d.join(&cxx).is_file()))
        .unwrap_or(false)
}
