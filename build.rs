//! Compiles every `glsl/**/*.comp` to SPIR-V with shaderc (glslang) and embeds the result.
//!
//! `#include "name.glsl"` resolves against `glsl/common/` and the including file's folder.
//! A shader error fails the build and prints the file and line glslang reports.

use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};

fn collect(dir: &Path, ext: &str, out: &mut Vec<PathBuf>) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<_> = entries.flatten().map(|e| e.path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            collect(&p, ext, out);
        } else if p.extension().and_then(|e| e.to_str()) == Some(ext) {
            out.push(p);
        }
    }
}

/// `glsl/render/preprocess.comp` -> `RENDER_PREPROCESS`
fn const_name(rel: &Path) -> String {
    let s = rel.with_extension("").to_string_lossy().to_string();
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_uppercase()
            } else {
                '_'
            }
        })
        .collect()
}

/// The source of `path` with its `#include "name"` lines replaced by the included text (looked
/// up as the compiler does: beside the including file, then in `glsl/common/`), each once.
fn expanded(path: &Path, common: &Path, seen: &mut Vec<PathBuf>) -> String {
    let text = fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut out = String::new();
    for line in text.lines() {
        let inc = line
            .trim()
            .strip_prefix("#include")
            .map(|r| r.trim().trim_matches('"'));
        match inc {
            Some(name) => {
                let dir = path.parent().unwrap_or(Path::new("."));
                let found = [dir.join(name), common.join(name)]
                    .into_iter()
                    .find(|c| c.is_file());
                if let Some(f) = found {
                    if !seen.contains(&f) {
                        seen.push(f.clone());
                        out.push_str(&expanded(&f, common, seen));
                    }
                }
            }
            None => {
                out.push_str(line);
                out.push('\n');
            }
        }
    }
    out
}

/// The storage buffers a kernel declares, by binding: the name of each block's member (the
/// name the kernel's code uses), e.g. `binding = 3) readonly buffer Positions { float
/// positions[]; }` gives "positions" at 3. Every binding from 0 up must be declared.
fn binding_names(source: &str, file: &Path) -> Vec<String> {
    let mut found: Vec<(u32, String)> = Vec::new();
    for line in source.lines() {
        let l = line.trim();
        if l.starts_with("//") {
            continue;
        }
        let Some(at) = l.find("binding") else {
            continue;
        };
        let rest = &l[at + "binding".len()..];
        let Some(rest) = rest.trim_start().strip_prefix('=') else {
            continue;
        };
        let digits: String = rest
            .trim_start()
            .chars()
            .take_while(|c| c.is_ascii_digit())
            .collect();
        let Ok(binding) = digits.parse::<u32>() else {
            continue;
        };
        let (Some(open), Some(close)) = (l.find('{'), l.rfind('}')) else {
            panic!(
                "{}: the buffer at binding {binding} is not declared on one line",
                file.display()
            );
        };
        // The block's first member: `type name[]` or `type name`.
        let member = l[open + 1..close].split(';').next().unwrap_or("").trim();
        let name: String = member
            .rsplit(char::is_whitespace)
            .next()
            .unwrap_or("")
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        assert!(
            !name.is_empty(),
            "{}: binding {binding} has no member name",
            file.display()
        );
        found.push((binding, name));
    }
    // A binding declared again (the same buffer seen as another type, e.g. uint bits and
    // float for atomics) keeps its first declaration's name.
    let mut first: Vec<(u32, String)> = Vec::new();
    for (b, name) in found {
        if !first.iter().any(|(f, _)| *f == b) {
            first.push((b, name));
        }
    }
    let mut found = first;
    found.sort();
    for (k, (b, name)) in found.iter().enumerate() {
        assert_eq!(
            *b as usize,
            k,
            "{}: bindings must run 0, 1, 2, … once each ({name} is at {b})",
            file.display()
        );
    }
    found.into_iter().map(|(_, n)| n).collect()
}

fn main() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let glsl = root.join("glsl");
    let out_dir = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    println!("cargo:rerun-if-changed=glsl");

    let mut shaders = Vec::new();
    collect(&glsl, "comp", &mut shaders);
    let mut includes = Vec::new();
    collect(&glsl, "glsl", &mut includes);
    for p in shaders.iter().chain(includes.iter()) {
        println!("cargo:rerun-if-changed={}", p.display());
    }

    let compiler = shaderc::Compiler::new().expect("shaderc: cannot create a compiler");
    let common = glsl.join("common");
    let mut generated = String::new();
    let mut table = String::from("pub const ALL: &[(&str, &[u8])] = &[\n");
    let mut binding_table =
        String::from("/// Every kernel's storage buffers by binding (see `build.rs`).\npub const BINDINGS: &[(&[u8], &[&str])] = &[\n");
    let mut failures = Vec::new();

    for path in &shaders {
        let rel = path.strip_prefix(&glsl).unwrap().to_path_buf();
        let source = fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let mut opts = shaderc::CompileOptions::new().unwrap();
        opts.set_target_env(
            shaderc::TargetEnv::Vulkan,
            shaderc::EnvVersion::Vulkan1_2 as u32,
        );
        opts.set_target_spirv(shaderc::SpirvVersion::V1_5);
        opts.set_optimization_level(shaderc::OptimizationLevel::Performance);
        opts.set_generate_debug_info();
        let common_dir = common.clone();
        opts.set_include_callback(move |name, _ty, includer, _depth| {
            let includer_dir = Path::new(includer)
                .parent()
                .map(Path::to_path_buf)
                .unwrap_or_default();
            for dir in [includer_dir, common_dir.clone()] {
                let candidate = dir.join(name);
                if let Ok(content) = fs::read_to_string(&candidate) {
                    return Ok(shaderc::ResolvedInclude {
                        resolved_name: candidate.to_string_lossy().to_string(),
                        content,
                    });
                }
            }
            Err(format!(
                "cannot find include \"{name}\" (looked in glsl/common and beside {includer})"
            ))
        });
        let display = path.to_string_lossy().to_string();
        match compiler.compile_into_spirv(
            &source,
            shaderc::ShaderKind::Compute,
            &display,
            "main",
            Some(&opts),
        ) {
            Ok(artifact) => {
                let spv = out_dir.join(rel.with_extension("spv"));
                fs::create_dir_all(spv.parent().unwrap()).unwrap();
                fs::write(&spv, artifact.as_binary_u8()).unwrap();
                let name = const_name(&rel);
                writeln!(
                    generated,
                    "/// SPIR-V of `glsl/{}`\npub const {name}: &[u8] = include_bytes!({:?});",
                    rel.display(),
                    spv.to_string_lossy()
                )
                .unwrap();
                writeln!(table, "    ({:?}, {name}),", rel.to_string_lossy()).unwrap();
                let names = binding_names(&expanded(path, &common, &mut Vec::new()), path);
                writeln!(
                    binding_table,
                    "    ({name}, &[{}]),",
                    names
                        .iter()
                        .map(|n| format!("{n:?}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                )
                .unwrap();
            }
            Err(e) => failures.push(format!("{e}")),
        }
    }
    if !failures.is_empty() {
        for f in &failures {
            for line in f.lines() {
                println!("cargo:warning={line}");
            }
        }
        panic!("GLSL compilation failed:\n{}", failures.join("\n"));
    }
    table.push_str("];\n");
    binding_table.push_str("];\n");
    generated.push_str(&table);
    generated.push_str(&binding_table);
    fs::write(out_dir.join("shaders.rs"), generated).unwrap();
}
