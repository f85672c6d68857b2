//! The fuzz corpus's harness: cases run in-process under `catch_unwind` on a watched thread, and
//! the structure-aware mutations (truncations, byte flips, number substitutions) the formats
//! share.
#![allow(dead_code)] // not every format uses every mutation

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// One input: a name that says how it was made (and the seed, for random mutations) and the
/// bytes of the file.
#[derive(Clone)]
pub struct Case {
    pub name: String,
    pub bytes: Vec<u8>,
}

impl Case {
    pub fn new(name: impl Into<String>, bytes: Vec<u8>) -> Case {
        Case {
            name: name.into(),
            bytes,
        }
    }
}

/// A fixed-seed generator per corpus, so a failing case's name and seed reproduce it.
pub fn rng(seed: u64) -> Pcg64 {
    Pcg64::seed_from_u64(seed)
}

/// The longest one case may take: every reader here works on files of a few KiB, so a case
/// that takes seconds is looping over an untrusted count.
pub const CASE_LIMIT: Duration = Duration::from_secs(5);

/// Runs `check` on every case on a separate thread, each under `catch_unwind`, and fails the
/// test with every panicking, slow or wrong case (name and corpus seed), or when the whole
/// corpus has not finished within `limit` (a hang: the case it was in is named).
///
/// `check` returns `Err(why)` when the outcome is wrong (an error that does not name the file,
/// a load that is not valid); a panic inside it counts as a panic of the reader.
pub fn run_corpus<F>(corpus: &str, seed: u64, cases: Vec<Case>, limit: Duration, check: F)
where
    F: FnMut(&Case) -> Result<(), String> + Send + 'static,
{
    assert!(!cases.is_empty(), "{corpus}: empty corpus");
    let n = cases.len();
    let current = Arc::new(Mutex::new(String::new()));
    let failures = Arc::new(Mutex::new(Vec::<String>::new()));
    let (done_tx, done_rx) = std::sync::mpsc::channel();
    {
        let current = current.clone();
        let failures = failures.clone();
        let mut check = check;
        std::thread::Builder::new()
            .name(format!("fuzz {corpus}"))
            .spawn(move || {
                for case in &cases {
                    *current.lock().unwrap() = case.name.clone();
                    let start = Instant::now();
                    let outcome = catch_unwind(AssertUnwindSafe(|| check(case)));
                    let took = start.elapsed();
                    let mut f = failures.lock().unwrap();
                    match outcome {
                        Ok(Ok(())) => {}
                        Ok(Err(why)) => f.push(format!("{} (seed {seed:#x}): {why}", case.name)),
                        Err(p) => {
                            let msg = p
                                .downcast_ref::<String>()
                                .cloned()
                                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                                .unwrap_or_default();
                            f.push(format!("{} (seed {seed:#x}): PANIC: {msg}", case.name));
                        }
                    }
                    if took > CASE_LIMIT {
                        f.push(format!(
                            "{} (seed {seed:#x}): took {took:?} (> {CASE_LIMIT:?})",
                            case.name
                        ));
                    }
                }
                let _ = done_tx.send(());
            })
            .unwrap();
    }
    if done_rx.recv_timeout(limit).is_err() {
        panic!(
            "{corpus}: the corpus of {n} cases did not finish within {limit:?}; stuck in case \
             {:?} (seed {seed:#x})",
            current.lock().unwrap()
        );
    }
    let f = failures.lock().unwrap();
    assert!(
        f.is_empty(),
        "{corpus}: {} of {n} cases failed:\n{}",
        f.len(),
        f.iter().take(40).cloned().collect::<Vec<_>>().join("\n")
    );
    eprintln!("{corpus}: {n} cases passed");
}

/// Checks an error message for bad input: it names `file` and, where the reader follows the
/// `InputError` convention, says what to do (`Fix:`).
pub fn names_file(e: &anyhow::Error, file: &Path, want_fix: bool) -> Result<(), String> {
    let text = format!("{e:#}");
    let shown = file.display().to_string();
    if !text.contains(&shown) {
        return Err(format!("the error does not name {shown}: {text}"));
    }
    if want_fix && !text.contains("Fix:") {
        return Err(format!("the error has no `Fix:`: {text}"));
    }
    Ok(())
}

/// A file name unique to the case inside `dir`, with extension `ext`.
pub fn case_path(dir: &Path, index: usize, ext: &str) -> PathBuf {
    dir.join(format!("case{index}.{ext}"))
}

/// Truncations: every length up to `dense` bytes, every `boundaries` point ± 1, and `random`
/// more lengths drawn from `rng`.
pub fn truncations(
    base: &Case,
    boundaries: &[usize],
    dense: usize,
    random: usize,
    rng: &mut Pcg64,
) -> Vec<Case> {
    let len = base.bytes.len();
    let mut at: Vec<usize> = (0..dense.min(len)).collect();
    for &b in boundaries {
        at.extend(
            [b.saturating_sub(1), b, b + 1]
                .into_iter()
                .filter(|&k| k < len),
        );
    }
    at.extend((0..random).map(|_| rng.gen_range(0..len.max(1))));
    at.sort_unstable();
    at.dedup();
    at.into_iter()
        .map(|k| {
            Case::new(
                format!("{} cut at {k}", base.name),
                base.bytes[..k].to_vec(),
            )
        })
        .collect()
}

/// `count` random byte edits of `base`: a bit flip, a byte set to 0x00 / 0xFF / random, a byte
/// inserted or removed, each at a random offset (`from..` only, e.g. past a checksum'd part).
pub fn byte_edits(base: &Case, from: usize, count: usize, rng: &mut Pcg64) -> Vec<Case> {
    let len = base.bytes.len();
    (0..count)
        .map(|k| {
            let mut b = base.bytes.clone();
            let at = rng.gen_range(from.min(len.saturating_sub(1))..len.max(1));
            let kind = rng.gen_range(0..6);
            let what = match kind {
                0 => {
                    let bit = rng.gen_range(0..8);
                    b[at] ^= 1 << bit;
                    format!("bit {bit} of byte {at} flipped")
                }
                1 => {
                    b[at] = 0;
                    format!("byte {at} = 0x00")
                }
                2 => {
                    b[at] = 0xFF;
                    format!("byte {at} = 0xFF")
                }
                3 => {
                    let v: u8 = rng.gen();
                    b[at] = v;
                    format!("byte {at} = {v:#x}")
                }
                4 => {
                    let v: u8 = rng.gen();
                    b.insert(at, v);
                    format!("{v:#x} inserted at {at}")
                }
                _ => {
                    b.remove(at);
                    format!("byte {at} removed")
                }
            };
            Case::new(format!("{} edit {k}: {what}", base.name), b)
        })
        .collect()
}

/// Integers a header count is replaced by: too small, too large, huge, out of range, not one.
pub const BAD_COUNTS: [&str; 12] = [
    "0",
    "1",
    "2",
    "7",
    "4294967296",
    "1099511627776",
    "9223372036854775807",
    "18446744073709551615",
    "18446744073709551616",
    "-1",
    "1e3",
    "x",
];

/// Binary counts (u64) a header count is replaced by.
pub const BAD_U64: [u64; 8] = [
    0,
    1,
    2,
    1 << 32,
    1 << 40,
    (1 << 62) + 1,
    u64::MAX / 2,
    u64::MAX,
];

/// The non-finite values every numeric field is tried with.
pub const NON_FINITE_F32: [f32; 3] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
pub const NON_FINITE_F64: [f64; 3] = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY];

/// Tokens a number in a text format is replaced by.
pub const BAD_TOKENS: [&str; 14] = [
    "nan",
    "NaN",
    "inf",
    "-inf",
    "infinity",
    "1e39",
    "-1e400",
    "1e-400",
    "18446744073709551616",
    "-1",
    "0",
    "",
    "abc",
    "0x10",
];

/// 64-bit FNV-1a (the checkpoint's and the match cache's checksum), so that mutated files can
/// be re-sealed and reach the parser behind the checksum.
pub fn fnv1a(bytes: &[u8]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Replaces the trailing 8-byte FNV-1a checksum of `bytes` with the one of what precedes it.
pub fn reseal(mut bytes: Vec<u8>) -> Vec<u8> {
    if bytes.len() >= 8 {
        let body = bytes.len() - 8;
        let h = fnv1a(&bytes[..body]);
        bytes[body..].copy_from_slice(&h.to_le_bytes());
    }
    bytes
}

/// Every numeric leaf of a JSON value, as paths of keys / indices.
pub fn json_number_paths(v: &serde_json::Value) -> Vec<Vec<PathStep>> {
    fn walk(v: &serde_json::Value, at: &mut Vec<PathStep>, out: &mut Vec<Vec<PathStep>>) {
        match v {
            serde_json::Value::Number(_) => out.push(at.clone()),
            serde_json::Value::Array(a) => {
                for (i, x) in a.iter().enumerate() {
                    at.push(PathStep::Index(i));
                    walk(x, at, out);
                    at.pop();
                }
            }
            serde_json::Value::Object(o) => {
                for (k, x) in o {
                    at.push(PathStep::Key(k.clone()));
                    walk(x, at, out);
                    at.pop();
                }
            }
            _ => {}
        }
    }
    let mut out = Vec::new();
    walk(v, &mut Vec::new(), &mut out);
    out
}

/// Every key / index path of a JSON value (numbers, strings, lists and objects alike).
pub fn json_all_paths(v: &serde_json::Value) -> Vec<Vec<PathStep>> {
    fn walk(v: &serde_json::Value, at: &mut Vec<PathStep>, out: &mut Vec<Vec<PathStep>>) {
        if !at.is_empty() {
            out.push(at.clone());
        }
        match v {
            serde_json::Value::Array(a) => {
                for (i, x) in a.iter().enumerate() {
                    at.push(PathStep::Index(i));
                    walk(x, at, out);
                    at.pop();
                }
            }
            serde_json::Value::Object(o) => {
                for (k, x) in o {
                    at.push(PathStep::Key(k.clone()));
                    walk(x, at, out);
                    at.pop();
                }
            }
            _ => {}
        }
    }
    let mut out = Vec::new();
    walk(v, &mut Vec::new(), &mut out);
    out
}

#[derive(Clone, Debug)]
pub enum PathStep {
    Key(String),
    Index(usize),
}

pub fn path_text(p: &[PathStep]) -> String {
    p.iter()
        .map(|s| match s {
            PathStep::Key(k) => format!(".{k}"),
            PathStep::Index(i) => format!("[{i}]"),
        })
        .collect()
}

/// The value at `p`, mutable.
pub fn json_at<'a>(v: &'a mut serde_json::Value, p: &[PathStep]) -> &'a mut serde_json::Value {
    p.iter().fold(v, |v, s| match s {
        PathStep::Key(k) => &mut v[k.as_str()],
        PathStep::Index(i) => &mut v[*i],
    })
}

/// Removes the value at `p` from its parent (a key from an object, an item from a list).
pub fn json_remove(v: &mut serde_json::Value, p: &[PathStep]) {
    let (last, parent) = p.split_last().unwrap();
    match (json_at(v, parent), last) {
        (serde_json::Value::Object(o), PathStep::Key(k)) => {
            o.remove(k);
        }
        (serde_json::Value::Array(a), PathStep::Index(i)) => {
            a.remove(*i);
        }
        _ => {}
    }
}

/// JSON text with the number at `p` replaced by the raw token `token` (e.g. `NaN`, `1e999`,
/// which JSON itself cannot hold but hand-edited and Python-written files do).
pub fn json_with_token(v: &serde_json::Value, p: &[PathStep], token: &str) -> Vec<u8> {
    const MARK: &str = "@@FUZZ_TOKEN@@";
    let mut v = v.clone();
    *json_at(&mut v, p) = serde_json::Value::String(MARK.into());
    serde_json::to_string(&v)
        .unwrap()
        .replace(&format!("\"{MARK}\""), token)
        .into_bytes()
}

/// Mutations of a JSON document: every number replaced by each of `tokens`, every value
/// replaced by null / a string / an empty list / an object and removed, and the text cut and
/// byte-edited. `numbers_step` samples the number paths (1: all).
pub fn json_cases(
    name: &str,
    v: &serde_json::Value,
    tokens: &[&str],
    numbers_step: usize,
    edits: usize,
    rng: &mut Pcg64,
) -> Vec<Case> {
    let mut out = Vec::new();
    let text = serde_json::to_vec(v).unwrap();
    out.push(Case::new(format!("{name} valid"), text.clone()));
    for (k, p) in json_number_paths(v).iter().enumerate() {
        if k % numbers_step != 0 {
            continue;
        }
        for t in tokens {
            out.push(Case::new(
                format!("{name} {} = {t}", path_text(p)),
                json_with_token(v, p, t),
            ));
        }
    }
    let replacements = [
        serde_json::Value::Null,
        serde_json::json!("text"),
        serde_json::json!([]),
        serde_json::json!({}),
        serde_json::json!(true),
        serde_json::json!(-1),
    ];
    for p in json_all_paths(v) {
        // Deep paths inside matrices are covered by the number substitutions above.
        if p.len() > 3 {
            continue;
        }
        for r in &replacements {
            let mut w = v.clone();
            *json_at(&mut w, &p) = r.clone();
            out.push(Case::new(
                format!("{name} {} = {r}", path_text(&p)),
                serde_json::to_vec(&w).unwrap(),
            ));
        }
        let mut w = v.clone();
        json_remove(&mut w, &p);
        out.push(Case::new(
            format!("{name} {} removed", path_text(&p)),
            serde_json::to_vec(&w).unwrap(),
        ));
    }
    let base = Case::new(name, text);
    out.extend(truncations(&base, &[], 0, 12, rng));
    out.extend(byte_edits(&base, 0, edits, rng));
    out.push(Case::new(format!("{name} empty"), Vec::new()));
    out
}
