//! `bench merge FILE...`: the trade.json files of several `bench trade` processes (more seeds,
//! another machine, another setting) as one table. Rows are pooled by run and iteration, and
//! ΔPSNR is paired seed by seed with a baseline run, as `bench trade --seeds` does in one
//! process. A file whose recorded settings differ from the first file's names its runs with the
//! difference (`adc+lpm [lpm_block_fraction=0.7]`), so only runs trained alike are pooled.
//! Times are compared only between runs of one process: runs of different processes did not
//! share the machine's load. Its trade.html shows the pooled plot and tables and links each
//! input's own page, where that run's renders are.

use crate::cli::output_folder::prepare_output;
use anyhow::Context;
use clap::Args;
use lpmsplat::bench::report::{write_html, Page};
use lpmsplat::bench::summary::{
    column_header, paired_table, plot, summarize_against, table_rows, Summary, TradeRow,
};
use lpmsplat::error::write_atomic;
use serde_json::Value;
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct MergeArgs {
    /// trade.json files written by `bench trade`, or the folders holding them. All must be of
    /// one scene, base model, resolution and calendar; the first file's settings are the
    /// reference that the other files' run names show their differences from.
    #[arg(required = true, value_name = "TRADE_JSON")]
    pub inputs: Vec<PathBuf>,
    /// Output folder for the merged trade.json, trade.md, trade.png and trade.html (which links
    /// the inputs' own trade.html, where their renders are); not an input's folder.
    #[arg(long, short = 'o', default_value = "bench_merge")]
    pub out: PathBuf,
    /// The run every other is paired with, seed by seed, in ΔPSNR (its name as the merged
    /// table shows it, e.g. `adc` or `adc+lpm [lpm_block_fraction=0.7]`).
    #[arg(long, default_value = "adc")]
    pub baseline: String,
}

/// The pooled rows and what the table says about where they came from.
#[derive(Debug)]
pub struct Merged {
    pub rows: Vec<TradeRow>,
    pub scene: String,
    pub model: String,
    pub resolution: Value,
    pub calendar: u64,
    /// Each input's devices, in input order (one per file).
    pub devices: Vec<String>,
    /// The reference settings (the first file's).
    pub settings: Value,
    /// Per input: the settings that differ from the reference, as `name=value`.
    pub differences: Vec<Vec<String>>,
    /// Remarks for the table (e.g. files that record fewer settings).
    pub remarks: Vec<String>,
}

/// Reads `path` (a trade.json, or a folder holding one).
pub fn read_input(path: &Path) -> anyhow::Result<(PathBuf, Value)> {
    let file = if path.is_dir() {
        path.join("trade.json")
    } else {
        path.to_path_buf()
    };
    let bytes = std::fs::read(&file).with_context(|| {
        format!(
            "{}: cannot read it. Fix: pass a trade.json written by `bench trade`, or its folder",
            file.display()
        )
    })?;
    let json: Value = serde_json::from_slice(&bytes).with_context(|| {
        format!(
            "{}: not JSON. Fix: pass a trade.json written by `bench trade`",
            file.display()
        )
    })?;
    Ok((file, json))
}

/// A settings value as a run name shows it (floats stored from f32 without their f64 tail).
fn show(v: &Value) -> String {
    match v {
        Value::Number(n) => match n.as_f64() {
            Some(x) if n.is_f64() && (x as f32) as f64 == x => format!("{}", x as f32),
            _ => n.to_string(),
        },
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// The settings a file records, and whether that is all of them: its `settings` object (true),
/// or for files written before that existed the LPM block settings at its top level (false).
fn settings_of(json: &Value) -> (serde_json::Map<String, Value>, bool) {
    if let Some(Value::Object(m)) = json.get("settings") {
        let mut m = m.clone();
        // Written before --match-adc-count existed: its runs did not follow adc's count.
        m.entry("match_adc_count").or_insert(Value::Bool(false));
        // Before --lpm-threshold-ratio: each rule set's own ratio (null, as when not given).
        m.entry("lpm_threshold_ratio").or_insert(Value::Null);
        // Before --budget, --lpm-zone-weight and --lpm-surface-share: no budget, LPM's own
        // weight, no surface samples.
        for k in [
            "budget",
            "budget_growth",
            "lpm_zone_weight",
            "lpm_surface_share",
        ] {
            m.entry(k).or_insert(Value::Null);
        }
        // Before --budget-draw: every mcmc run below its start drew it at random.
        let drew = if m["budget"].is_null() {
            Value::Null
        } else {
            Value::from("random")
        };
        m.entry("budget_draw").or_insert(drew);
        return (m, true);
    }
    let mut m = serde_json::Map::new();
    for k in ["lpm_block", "lpm_block_fraction"] {
        if let Some(v) = json.get(k) {
            m.insert(k.to_string(), v.clone());
        }
    }
    (m, false)
}

/// Pools the rows of `inputs` (path, parsed trade.json), refusing files of another scene,
/// model, resolution or calendar and rows that two files both hold.
pub fn merge(inputs: &[(PathBuf, Value)]) -> anyhow::Result<Merged> {
    anyhow::ensure!(
        !inputs.is_empty(),
        "bench merge: no inputs. Fix: pass the trade.json files to merge"
    );
    let field = |i: usize, name: &str| -> anyhow::Result<Value> {
        inputs[i].1.get(name).cloned().with_context(|| {
            format!(
                "{}: field `{name}` missing: not a trade.json written by `bench trade`. Fix: \
                 pass the trade.json of a `bench trade` output folder",
                inputs[i].0.display()
            )
        })
    };
    // The scene is compared by its folder's name: the files may come from other machines.
    let scene_name = |v: &Value| -> String {
        let s = v.as_str().unwrap_or_default();
        Path::new(s.trim_end_matches('/'))
            .file_name()
            .map_or(s.to_string(), |n| n.to_string_lossy().into_owned())
    };
    let identity = |i: usize| -> anyhow::Result<[(&'static str, Value); 4]> {
        Ok([
            ("scene", Value::String(scene_name(&field(i, "scene")?))),
            ("model", field(i, "model")?),
            ("resolution", field(i, "resolution")?),
            ("calendar", field(i, "calendar")?),
        ])
    };
    let first = identity(0)?;
    let (reference, _) = settings_of(&inputs[0].1);
    let mut rows: Vec<TradeRow> = Vec::new();
    let mut devices = Vec::new();
    let mut differences = Vec::new();
    let mut incomplete = Vec::new();
    // The input file of each row.
    let mut file_of: Vec<usize> = Vec::new();
    for (i, (path, json)) in inputs.iter().enumerate() {
        let interleaved = json.get("interleaved") != Some(&Value::Bool(false));
        for ((name, want), (_, got)) in first.iter().zip(identity(i)?) {
            anyhow::ensure!(
                *want == got,
                "{}: `{name}` is {} where {} has {}: runs of another scene, base model, \
                 resolution or calendar are not the same runs. Fix: merge only files of one \
                 scene, model, resolution and calendar",
                path.display(),
                show(&got),
                inputs[0].0.display(),
                show(want)
            );
        }
        devices.push(
            json.get("device")
                .and_then(Value::as_str)
                .unwrap_or("unknown device")
                .to_string(),
        );
        let (settings, complete) = settings_of(json);
        if !complete {
            incomplete.push(path.display().to_string());
        }
        // Settings both files record and that differ name this file's runs.
        let differ: Vec<(String, String)> = settings
            .iter()
            .filter(|(k, v)| reference.get(*k).is_some_and(|r| r != *v))
            .map(|(k, v)| (k.clone(), show(v)))
            .collect();
        differences.push(differ.iter().map(|(k, v)| format!("{k}={v}")).collect());
        let runs = field(i, "runs")?;
        let runs = runs.as_array().with_context(|| {
            format!(
                "{}: `runs` is not a list. Fix: pass a trade.json written by `bench trade`",
                path.display()
            )
        })?;
        for (j, r) in runs.iter().enumerate() {
            let mut row: TradeRow = serde_json::from_value(r.clone()).with_context(|| {
                format!(
                    "{}: runs[{j}] is not a `bench trade` row. Fix: pass a trade.json written \
                     by `bench trade`",
                    path.display()
                )
            })?;
            // `lpm_*` settings change only the LPM runs; following adc's count, all but adc.
            let tags: Vec<String> = differ
                .iter()
                .filter(|(k, _)| !k.starts_with("lpm_") || row.run.contains("lpm"))
                .filter(|(k, _)| k != "match_adc_count" || row.run != "adc")
                .map(|(k, v)| format!("{k}={v}"))
                .collect();
            if !tags.is_empty() {
                row.run = format!("{} [{}]", row.run, tags.join(", "));
            }
            // Rows of one interleaved process share a source (their times compare); those of
            // a sequential run or an earlier merge each get their own.
            row.source = if interleaved {
                i
            } else {
                inputs.len() + rows.len()
            };
            if let Some(k) = rows.iter().position(|o| {
                o.run == row.run && o.seed == row.seed && o.iteration == row.iteration
            }) {
                anyhow::bail!(
                    "{} and {} both hold run `{}` with seed {} at iteration {}: merging would \
                     count that seed twice. Fix: leave one of the two files out, or run one \
                     with another --seed",
                    inputs[file_of[k]].0.display(),
                    path.display(),
                    row.run,
                    row.seed,
                    row.iteration
                );
            }
            rows.push(row);
            file_of.push(i);
        }
    }
    let mut remarks = Vec::new();
    if !incomplete.is_empty() {
        remarks.push(format!(
            "{} of {} files record only their LPM block settings (written before trade.json \
             recorded its settings), so other settings, e.g. --max-gaussians, were not checked: {}",
            incomplete.len(),
            inputs.len(),
            incomplete.join(", ")
        ));
    }
    let [(_, scene), (_, model), (_, resolution), (_, calendar)] = first;
    Ok(Merged {
        rows,
        scene: show(&scene),
        model: show(&model),
        resolution,
        calendar: calendar.as_u64().unwrap_or_default(),
        devices,
        settings: Value::Object(reference),
        differences,
        remarks,
    })
}

/// The merged table: where the rows came from, how to read it, the summary and the pairs.
fn table(m: &Merged, summary: &[Summary], inputs: &[(PathBuf, Value)], baseline: &str) -> String {
    let mut devices = m.devices.clone();
    devices.dedup();
    let mut s = format!(
        "bench merge: {} files of {} {}, base model {}, calendar of {}, on {}. Rows of one run \
         and iteration are pooled over the files' seeds: PSNR and SSIM ± their standard \
         deviation, ΔPSNR ± the standard error of the per-seed differences from {baseline} (only \
         seeds the baseline also ran), the rest means. The runs of different files were not \
         interleaved: a time ratio is shown only where a run and the baseline come from one \
         process.\n\n",
        inputs.len(),
        m.scene,
        m.resolution
            .as_u64()
            .map_or("full resolution".to_string(), |r| format!("-r {r}")),
        m.model,
        m.calendar,
        devices.join(", ")
    );
    for (i, (path, _)) in inputs.iter().enumerate() {
        let d = &m.differences[i];
        s += &format!(
            "- {}{}\n",
            path.display(),
            if d.is_empty() {
                String::new()
            } else {
                format!(" (its runs named with [{}])", d.join(", "))
            }
        );
    }
    for r in &m.remarks {
        s += &format!("- Note: {r}\n");
    }
    s += "\n";
    s += &column_header(baseline);
    s += &table_rows(summary);
    s += "\n";
    s += &paired_table(&m.rows, baseline);
    s
}

/// `target` as a link from a page in folder `from`: relative where both paths resolve (so the
/// pages can move together), else `target` as given. The characters a URL reads as syntax
/// (`%`, `#`, `?`) or that break an address (spaces) are percent-encoded, so a folder named
/// `seed #3` still links.
fn relative_link(from: &Path, target: &Path) -> String {
    let encode = |s: &str| {
        s.replace('%', "%25")
            .replace('#', "%23")
            .replace('?', "%3F")
            .replace(' ', "%20")
    };
    let (Ok(from), Ok(to)) = (from.canonicalize(), target.canonicalize()) else {
        return encode(&target.display().to_string());
    };
    let common = from
        .components()
        .zip(to.components())
        .take_while(|(a, b)| a == b)
        .count();
    let ups = from.components().count() - common;
    let mut parts: Vec<String> = vec!["..".to_string(); ups];
    parts.extend(
        to.components()
            .skip(common)
            .map(|c| c.as_os_str().to_string_lossy().into_owned()),
    );
    encode(&parts.join("/"))
}

pub fn run(args: &MergeArgs) -> anyhow::Result<()> {
    let inputs = args
        .inputs
        .iter()
        .map(|p| read_input(p))
        .collect::<anyhow::Result<Vec<_>>>()?;
    // Never write over an input.
    let out_file = args.out.join("trade.json");
    for (path, _) in &inputs {
        let same = match (path.canonicalize(), out_file.canonicalize()) {
            (Ok(a), Ok(b)) => a == b,
            _ => false,
        };
        anyhow::ensure!(
            !same,
            "{}: --out {} would overwrite this input. Fix: choose another --out",
            path.display(),
            args.out.display()
        );
    }
    // Nor over a `bench trade` result: only an earlier merge's files are replaced.
    if out_file.exists() {
        let earlier_merge =
            read_input(&out_file).is_ok_and(|(_, j)| j.get("merged_from").is_some());
        anyhow::ensure!(
            earlier_merge,
            "{}: not a merge (a `bench trade` result, or unreadable); merging into its folder \
             would overwrite it. Fix: choose another --out",
            out_file.display()
        );
    }
    let merged = merge(&inputs)?;
    anyhow::ensure!(
        merged.rows.iter().any(|r| r.run == args.baseline),
        "bench merge: no run is named `{}` (--baseline). Fix: choose one of {}",
        args.baseline,
        {
            let mut names: Vec<&str> = merged.rows.iter().map(|r| r.run.as_str()).collect();
            names.dedup();
            names.sort_unstable();
            names.dedup();
            names
                .iter()
                .map(|n| format!("`{n}`"))
                .collect::<Vec<_>>()
                .join(", ")
        }
    );
    let summary = summarize_against(&merged.rows, &args.baseline);
    let text = table(&merged, &summary, &inputs, &args.baseline);
    prepare_output(&args.out)?;
    write_atomic(&args.out.join("trade.md"), |f| {
        Ok(f.write_all(text.as_bytes())?)
    })?;
    let json = serde_json::json!({
        "merged_from": inputs.iter().map(|(p, _)| p.display().to_string()).collect::<Vec<_>>(),
        "differences": merged.differences,
        "scene": merged.scene,
        "model": merged.model,
        "resolution": merged.resolution,
        "calendar": merged.calendar,
        "interleaved": inputs.len() == 1,
        "devices": merged.devices,
        "settings": merged.settings,
        "baseline": args.baseline,
        "summary": summary,
        "runs": merged.rows,
    });
    let body = serde_json::to_string_pretty(&json)?;
    write_atomic(&out_file, |f| Ok(f.write_all(body.as_bytes())?))?;
    let png = plot(&summary.iter().map(Summary::as_row).collect::<Vec<_>>())?;
    write_atomic(&args.out.join("trade.png"), |f| Ok(f.write_all(&png)?))?;
    let sources: Vec<(String, Option<String>)> = inputs
        .iter()
        .map(|(path, _)| {
            let html = path.with_file_name("trade.html");
            let link = html.is_file().then(|| relative_link(&args.out, &html));
            (path.display().to_string(), link)
        })
        .collect();
    let title = format!(
        "bench merge: {}, {}, {} files",
        merged.scene,
        merged.model,
        inputs.len()
    );
    let page = Page {
        title: &title,
        baseline: &args.baseline,
        view: None,
        sources: &sources,
    };
    write_html(&args.out, &page, &merged.rows, &summary, &text)?;
    print!("{text}");
    println!("wrote {}", args.out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn row(run: &str, seed: u64, iteration: u32, psnr: f64) -> Value {
        json!({"run": run, "seed": seed, "iteration": iteration, "colour": [1, 2, 3],
               "psnr": psnr, "ssim": 0.8, "lpips": null, "gaussians": 1000,
               "train_seconds": 10.0, "view_psnr": null})
    }

    fn file(name: &str, settings: Value, runs: Vec<Value>) -> (PathBuf, Value) {
        (
            PathBuf::from(name),
            json!({"scene": format!("/data/{}/tnt_truck", name), "model": "3dgs",
                   "resolution": 4, "calendar": 3000, "iterations": 3000,
                   "device": "llvmpipe", "settings": settings, "runs": runs}),
        )
    }

    /// The merged rows' run names and seeds, in order.
    fn run_names(m: &Merged) -> Vec<(&str, u64)> {
        m.rows.iter().map(|r| (r.run.as_str(), r.seed)).collect()
    }

    /// An ADC row and an LPM row of one seed at 3,000 iterations.
    fn adc_lpm(seed: u64, adc: f64, lpm: f64) -> Vec<Value> {
        vec![row("adc", seed, 3000, adc), row("adc+lpm", seed, 3000, lpm)]
    }

    fn settings(fraction: f32, cap: Option<usize>) -> Value {
        json!({"lpm_block": 0, "lpm_block_fraction": fraction, "max_gaussians": cap})
    }

    #[test]
    fn an_lpm_setting_names_only_the_lpm_runs_and_another_names_every_run() {
        let a = file("a", settings(0.85, Some(150_000)), adc_lpm(2, 23.0, 23.2));
        let b = file("b", settings(0.7, Some(150_000)), adc_lpm(3, 23.1, 23.4));
        let c = file("c", settings(0.85, None), adc_lpm(2, 22.0, 22.5));
        let m = merge(&[a, b, c]).unwrap();
        assert_eq!(
            run_names(&m),
            [
                ("adc", 2),
                ("adc+lpm", 2),
                // The block fraction changes LPM runs only: b's ADC pools with a's.
                ("adc", 3),
                ("adc+lpm [lpm_block_fraction=0.7]", 3),
                // The cap changes every run, so c's seed 2 does not collide with a's.
                ("adc [max_gaussians=null]", 2),
                ("adc+lpm [max_gaussians=null]", 2),
            ]
        );
        assert_eq!(m.differences[1], ["lpm_block_fraction=0.7"]);
        assert_eq!(m.rows[2].source, 1);
        assert!(m.remarks.is_empty(), "{:?}", m.remarks);
        // The scene is compared by its folder's name (the paths differ).
        assert_eq!(m.scene, "tnt_truck");
    }

    #[test]
    fn following_adcs_count_names_every_run_but_adc_and_older_files_did_not_follow_it() {
        let mut matched = settings(0.85, None);
        matched["match_adc_count"] = json!(true);
        // Written before the flag existed: no key, so its runs did not follow adc's count.
        let old = file("old", settings(0.85, None), adc_lpm(2, 23.0, 23.2));
        let new = file("new", matched, adc_lpm(3, 23.1, 23.3));
        let m = merge(&[old, new]).unwrap();
        assert_eq!(
            run_names(&m),
            [
                ("adc", 2),
                ("adc+lpm", 2),
                ("adc", 3),
                ("adc+lpm [match_adc_count=true]", 3),
            ]
        );
        assert_eq!(m.settings["match_adc_count"], json!(false));
    }

    #[test]
    fn pooled_differences_pair_seed_by_seed_and_times_stay_within_one_process() {
        let a = file("a", settings(0.85, None), adc_lpm(2, 23.0, 23.3));
        let b = file("b", settings(0.85, None), adc_lpm(3, 24.0, 24.1));
        let c = file(
            "c",
            settings(0.85, None),
            vec![row("adc+lpm", 4, 3000, 30.0)],
        );
        let m = merge(&[a.clone(), b, c]).unwrap();
        let s = summarize_against(&m.rows, "adc");
        let lpm = s.iter().find(|r| r.run == "adc+lpm").unwrap();
        assert_eq!(lpm.seeds, 3);
        // Seed 4 has no ADC run: it counts in the mean PSNR, not in the pairs.
        assert!((lpm.delta_psnr.unwrap() - 0.2).abs() < 1e-12, "{lpm:?}");
        assert!((lpm.delta_psnr_se.unwrap() - 0.1).abs() < 1e-12, "{lpm:?}");
        assert!(lpm.time_vs_adc.is_none(), "three processes: no time ratio");
        let one = merge(std::slice::from_ref(&a)).unwrap();
        let s = summarize_against(&one.rows, "adc");
        assert_eq!(s[1].time_vs_adc, Some(1.0));
        // Nor within a file whose runs were not interleaved (`--sequential`, or a merge).
        let mut sequential = a;
        sequential.1["interleaved"] = json!(false);
        let s = summarize_against(&merge(&[sequential]).unwrap().rows, "adc");
        assert!(s[1].time_vs_adc.is_none());
        let pairs = paired_table(&m.rows, "adc");
        assert!(
            pairs.contains("| adc+lpm | 3000 | 2: +0.300, 3: +0.100 |"),
            "{pairs}"
        );
        assert!(!pairs.contains("| adc | 3000"), "{pairs}");
    }

    #[test]
    fn files_of_another_calendar_scene_or_model_and_repeated_rows_are_refused() {
        let a = file("a", settings(0.85, None), vec![row("adc", 2, 3000, 23.0)]);
        for (field, value) in [
            ("calendar", json!(1200)),
            ("scene", json!("/data/mip360_bonsai")),
            ("model", json!("2dgs")),
            ("resolution", json!(2)),
        ] {
            let mut b = file("b", settings(0.85, None), vec![row("adc", 3, 3000, 23.0)]);
            b.1[field] = value;
            let e = format!("{:#}", merge(&[a.clone(), b]).unwrap_err());
            assert!(
                e.starts_with("b: `") && e.contains(&format!("`{field}`")) && e.contains("Fix:"),
                "{e}"
            );
        }
        let again = file("b", settings(0.85, None), vec![row("adc", 2, 3000, 23.5)]);
        let e = format!("{:#}", merge(&[a.clone(), again]).unwrap_err());
        assert!(
            e.contains("a and b both hold run `adc` with seed 2 at iteration 3000"),
            "{e}"
        );
        let mut broken = file("b", settings(0.85, None), vec![json!({"run": "adc"})]);
        let e = format!("{:#}", merge(&[a.clone(), broken.clone()]).unwrap_err());
        assert!(e.contains("b: runs[0] is not a `bench trade` row"), "{e}");
        broken.1.as_object_mut().unwrap().remove("runs");
        let e = format!("{:#}", merge(&[a, broken]).unwrap_err());
        assert!(e.contains("b: field `runs` missing"), "{e}");
    }

    #[test]
    fn files_without_recorded_settings_are_named_in_one_remark() {
        let a = file("a", settings(0.85, None), vec![row("adc", 2, 3000, 23.0)]);
        let mut old = file("old", Value::Null, vec![row("adc+lpm", 2, 3000, 23.0)]);
        let o = old.1.as_object_mut().unwrap();
        o.remove("settings");
        o.insert("lpm_block_fraction".into(), json!(0.7f32));
        let m = merge(&[a, old.clone(), with_seed(old, 3)]).unwrap();
        assert_eq!(m.remarks.len(), 1, "{:?}", m.remarks);
        assert!(m.remarks[0].starts_with("2 of 3 files"), "{:?}", m.remarks);
        // The block fraction an older file does record still names its runs.
        assert_eq!(m.rows[1].run, "adc+lpm [lpm_block_fraction=0.7]");
    }

    /// The same file with its rows' seed changed (another process).
    fn with_seed(mut f: (PathBuf, Value), seed: u64) -> (PathBuf, Value) {
        for r in f.1["runs"].as_array_mut().unwrap() {
            r["seed"] = json!(seed);
        }
        f
    }

    #[test]
    fn links_to_the_inputs_pages_are_relative_to_the_merged_page() {
        let dir = tempfile::tempdir().unwrap();
        let (out, input) = (dir.path().join("merged"), dir.path().join("runs/seed3"));
        std::fs::create_dir_all(&out).unwrap();
        std::fs::create_dir_all(&input).unwrap();
        let html = input.join("trade.html");
        std::fs::write(&html, "").unwrap();
        assert_eq!(relative_link(&out, &html), "../runs/seed3/trade.html");
        assert_eq!(
            relative_link(&input, &html),
            "trade.html",
            "a page beside the merged one"
        );
        // A path that does not resolve is given as it is.
        let gone = dir.path().join("gone/trade.html");
        assert_eq!(relative_link(&out, &gone), gone.display().to_string());
        // Characters a URL reads as syntax are encoded.
        let odd = dir.path().join("seed #3 100%?");
        std::fs::create_dir_all(&odd).unwrap();
        std::fs::write(odd.join("trade.html"), "").unwrap();
        assert_eq!(
            relative_link(&out, &odd.join("trade.html")),
            "../seed%20%233%20100%25%3F/trade.html"
        );
    }

    #[test]
    fn settings_show_as_typed_on_the_command_line() {
        assert_eq!(show(&json!(0.7f32)), "0.7");
        assert_eq!(show(&json!(0.85f32)), "0.85");
        assert_eq!(show(&json!(0.123456789f64)), "0.123456789");
        assert_eq!(show(&json!(150000)), "150000");
        assert_eq!(show(&json!("additive")), "additive");
        assert_eq!(show(&Value::Null), "null");
    }
}
