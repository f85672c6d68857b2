//! `bench trade --slurm`: the sweep as a Slurm job array instead of a run here. One task a
//! seed (each task the same `bench trade` with `--seed S --seeds 1`, its runs interleaved as
//! ever, so the count-matched runs still follow their own seed's ADC), then `bench merge` of
//! every seed after the array (afterok), pairing ΔPSNR seed by seed as one process would.
//! A task that stops starts its seed again (bench trade keeps no checkpoint).

use std::path::Path;

use lpmsplat::partition::slurm::{self, Cell, JobArray};

use super::trade_args::TradeArgs;
use crate::cli::slurm_args::SlurmArgs;

/// The flags the tasks set themselves, taken out of the command line they repeat.
const SET_BY_TASK: [&str; 4] = ["--seed", "--seeds", "--out", "-o"];

/// `argv` (without the program) less `--slurm`, the Slurm flags and the seed and output
/// flags, in both `--flag value` and `--flag=value` forms.
pub fn task_command_line(argv: &[String]) -> Vec<String> {
    let takes_value = |f: &str| SET_BY_TASK.contains(&f) || SlurmArgs::VALUE_FLAGS.contains(&f);
    let mut out = Vec::new();
    let mut it = argv.iter();
    while let Some(a) = it.next() {
        if a == "--slurm" {
            continue;
        }
        if takes_value(a) {
            it.next();
            continue;
        }
        if let Some((flag, _)) = a.split_once('=') {
            if takes_value(flag) {
                continue;
            }
        }
        if a.starts_with("-o") && a.len() > 2 && !a.starts_with("--") {
            continue;
        }
        out.push(a.clone());
    }
    out
}

/// Writes the sweep's scripts into `args.out`.
pub fn write(args: &TradeArgs, slurm_args: &SlurmArgs) -> anyhow::Result<()> {
    let opts = slurm_args.options()?;
    std::fs::create_dir_all(&args.out)?;
    let dir = std::path::absolute(&args.out)?;
    let argv: Vec<String> = std::env::args().skip(1).collect();
    let base = task_command_line(&argv);
    let run_dir = |seed: u64| dir.join("runs").join(format!("seed-{seed}"));
    let seeds: Vec<u64> = (0..args.seeds as u64).map(|k| args.seed + k).collect();
    let cells = seeds
        .iter()
        .map(|&s| {
            let mut a = base.clone();
            a.extend([
                "--seed".into(),
                s.to_string(),
                "--seeds".into(),
                "1".into(),
                "-o".into(),
                run_dir(s).display().to_string(),
            ]);
            Cell {
                name: format!("seed-{s}"),
                args: a,
                fresh_args: Vec::new(),
            }
        })
        .collect();
    let mut merge_args = vec!["bench".to_string(), "merge".into()];
    merge_args.extend(seeds.iter().map(|&s| run_dir(s).display().to_string()));
    merge_args.extend(["-o".into(), dir.join("merged").display().to_string()]);
    let array = JobArray {
        job_name: "lpmsplat-trade".into(),
        dir: dir.clone(),
        cells,
        // trade.json is rewritten after every run: the task's own marker says it finished.
        done_file: "task.done".into(),
        resumes: false,
        cell_mem_mib: 16384,
        merge_args,
        merge_mem_mib: 2048,
    };
    slurm::write_scripts(&array, &opts)?;
    println!(
        "{} seeds as a Slurm job array ({}), then bench merge into {}",
        seeds.len(),
        dir.join("slurm/task.sh").display(),
        dir.join("merged").display()
    );
    println!(
        "submit: bash {}   (again after a failure: only what is missing)",
        Path::new(&dir).join("slurm/submit.sh").display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::task_command_line;

    #[test]
    fn the_task_line_drops_what_each_task_sets() {
        let argv: Vec<String> = [
            "--validation",
            "bench",
            "trade",
            "scene",
            "-r",
            "4",
            "--seed",
            "3",
            "--seeds=5",
            "--slurm",
            "--slurm-gres",
            "gpu:1",
            "--sbatch=--account=x",
            "-o",
            "out",
            "--runs",
            "adc,mcmc",
            "-oelsewhere",
        ]
        .map(String::from)
        .to_vec();
        assert_eq!(
            task_command_line(&argv),
            [
                "--validation",
                "bench",
                "trade",
                "scene",
                "-r",
                "4",
                "--runs",
                "adc,mcmc"
            ]
        );
    }
}
