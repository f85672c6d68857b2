//! Slurm job scripts for a plan: a job array with one task a block, and a merge job that
//! waits for the array (`afterok`). Slurm is the scheduler; these are its ordinary batch
//! scripts, nothing of ours runs between the jobs.
//!
//! A task trains its block into `runs/<block>/` and writes nothing else. It is idempotent and
//! restartable: a block whose run finished (`metrics.json`) is skipped, one that stopped
//! (pre-empted, timed out: Slurm's SIGTERM makes `train` save a checkpoint, as Ctrl-C does;
//! out of memory; a node lost after a periodic checkpoint) resumes from `checkpoint.bin`. So
//! `submit.sh` run again submits only the blocks with no finished run, and the merge after
//! them. Nothing needs the network or a database: the plan folder on a shared filesystem is
//! the whole state.

use std::path::Path;

use super::plan::Plan;

/// Resources of the jobs, from the command line.
#[derive(Debug, Clone, PartialEq)]
pub struct SlurmOptions {
    /// `--gres` of a task (e.g. `gpu:1`); `None` for none.
    pub gres: Option<String>,
    pub cpus_per_task: u32,
    /// `--partition`, if any.
    pub partition: Option<String>,
    /// `--time` of a task (Slurm's forms, e.g. `4:00:00`), if any.
    pub time: Option<String>,
    /// More `#SBATCH` lines, verbatim (`--account=x`, `--constraint=a100`).
    pub extra: Vec<String>,
    /// Write a checkpoint this often, so that a lost node loses at most this many iterations.
    pub checkpoint_every: u32,
    /// The `lpmsplat` binary the jobs run (the `LPMSPLAT` variable overrides it at run time).
    pub binary: std::path::PathBuf,
}

/// Host memory a task asks for, MiB: the block's device estimate twice over (the images are
/// decoded on the host, and lavapipe's device memory is host memory), at least 4 GiB.
pub fn task_memory_mib(plan: &Plan) -> u64 {
    let largest = plan.largest().map_or(0.0, |b| b.memory_mib);
    ((2.0 * largest).ceil() as u64 + 1024).max(4096)
}

/// Host memory the merge asks for, MiB: the whole model a few times over (each block's model
/// read, its cropped copy, the merged one), at least 2 GiB.
pub fn merge_memory_mib(plan: &Plan) -> u64 {
    let model_mib = plan.whole.expected_gaussians as f64 * 248.0 / (1u64 << 20) as f64;
    ((4.0 * model_mib).ceil() as u64 + 512).max(2048)
}

/// A word for the shell: as is when it is plainly safe, else in single quotes.
pub fn quote(s: &str) -> String {
    let safe = !s.is_empty()
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"-_./=:,+@%".contains(&b));
    if safe {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

fn header(name: &str, opts: &SlurmOptions, log: &str) -> String {
    let mut h = format!("#!/usr/bin/env bash\n#SBATCH --job-name={name}\n");
    h += &format!("#SBATCH --output={log}\n");
    h += &format!("#SBATCH --cpus-per-task={}\n", opts.cpus_per_task);
    if let Some(p) = &opts.partition {
        h += &format!("#SBATCH --partition={p}\n");
    }
    if let Some(t) = &opts.time {
        h += &format!("#SBATCH --time={t}\n");
    }
    for e in &opts.extra {
        h += &format!("#SBATCH {e}\n");
    }
    h
}

/// The three scripts (`task.sh`, `merge.sh`, `submit.sh`) for the plan in `dir` (absolute).
pub fn scripts(plan: &Plan, dir: &Path, opts: &SlurmOptions) -> Vec<(&'static str, String)> {
    let d = quote(&dir.display().to_string());
    let bin = quote(&opts.binary.display().to_string());
    let names: Vec<String> = plan.blocks.iter().map(|b| quote(&b.name)).collect();
    let budgets: Vec<String> = plan
        .blocks
        .iter()
        .map(|b| match plan.budget {
            Some(_) => b.expected_gaussians.to_string(),
            None => "-".into(),
        })
        .collect();
    let args: Vec<String> = plan.train_args.iter().map(|a| quote(a)).collect();
    let has_checkpoint_flag = plan
        .train_args
        .iter()
        .any(|a| a.starts_with("--checkpoint-every"));

    let mut task = header(
        "lpmsplat-block",
        opts,
        &format!("{d}/slurm/logs/block-%a.out"),
    );
    task += &format!("#SBATCH --mem={}\n", task_memory_mib(plan));
    if let Some(g) = &opts.gres {
        task += &format!("#SBATCH --gres={g}\n");
    }
    task += &format!(
        r#"# One block of the plan: Slurm's array index (or the first argument) picks it. Trains it
# into runs/<block>/, resuming from its checkpoint when an earlier attempt stopped, and does
# nothing when its run has finished.
set -euo pipefail
DIR={d}
LPMSPLAT=${{LPMSPLAT:-{bin}}}
BLOCKS=({names})
BUDGETS=({budgets})
k=${{SLURM_ARRAY_TASK_ID:-${{1:?give the block index}}}}
name=${{BLOCKS[$k]}}
run="$DIR/runs/$name"
if [ -f "$run/metrics.json" ]; then
  echo "block $name: finished before, nothing to do"
  exit 0
fi
mkdir -p "$run"
extra=()
if [ "${{BUDGETS[$k]}}" != - ]; then extra+=(--budget "${{BUDGETS[$k]}}"); fi
if [ -f "$run/checkpoint.bin" ]; then
  echo "block $name: resuming from $run/checkpoint.bin"
  extra+=(--resume "$run/checkpoint.bin")
fi
exec "$LPMSPLAT" train "$DIR/blocks/$name" -o "$run" {args}{ck} "${{extra[@]}}"
"#,
        names = names.join(" "),
        budgets = budgets.join(" "),
        args = args.join(" "),
        ck = if has_checkpoint_flag {
            String::new()
        } else {
            format!(" --checkpoint-every {}", opts.checkpoint_every)
        },
    );

    let mut merge = header("lpmsplat-merge", opts, &format!("{d}/slurm/logs/merge.out"));
    merge += &format!("#SBATCH --mem={}\n", merge_memory_mib(plan));
    merge += &format!(
        r#"# Merges the blocks' runs into merged/ once every block has finished (the job depends
# on the array with afterok); refuses, naming it, a block that is missing or broken.
set -euo pipefail
DIR={d}
LPMSPLAT=${{LPMSPLAT:-{bin}}}
exec "$LPMSPLAT" merge "$DIR/plan.json" --runs "$DIR/runs" -o "$DIR/merged"
"#
    );

    let submit = format!(
        r#"#!/usr/bin/env bash
# Submits the blocks that have no finished run as one job array, then the merge after them
# (afterok). Run it again after a failure: only what is missing is submitted. Extra arguments
# go to both sbatch calls (e.g. --partition=gpu).
set -euo pipefail
DIR={d}
BLOCKS=({names})
mkdir -p "$DIR/slurm/logs"
missing=()
for k in "${{!BLOCKS[@]}}"; do
  [ -f "$DIR/runs/${{BLOCKS[$k]}}/metrics.json" ] || missing+=("$k")
done
dependency=()
if [ ${{#missing[@]}} -gt 0 ]; then
  list=$(IFS=,; echo "${{missing[*]}}")
  array=$(sbatch --parsable "$@" --array="$list" "$DIR/slurm/task.sh")
  array=${{array%%;*}}
  echo "blocks: job array $array (tasks $list of {n})"
  dependency=(--dependency="afterok:$array")
else
  echo "blocks: every block has finished"
fi
merge=$(sbatch --parsable "$@" "${{dependency[@]}}" "$DIR/slurm/merge.sh")
echo "merge: job ${{merge%%;*}}"
"#,
        names = names.join(" "),
        n = plan.blocks.len(),
    );
    vec![
        ("task.sh", task),
        ("merge.sh", merge),
        ("submit.sh", submit),
    ]
}

/// Writes the scripts into `dir/slurm/` (executable).
pub fn write_scripts(plan: &Plan, dir: &Path, opts: &SlurmOptions) -> anyhow::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    let slurm = dir.join("slurm");
    std::fs::create_dir_all(slurm.join("logs"))?;
    for (name, text) in scripts(plan, dir, opts) {
        let path = slurm.join(name);
        std::fs::write(&path, text)?;
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::quote;

    #[test]
    fn quoting_keeps_safe_words_and_wraps_the_rest() {
        assert_eq!(quote("--iterations"), "--iterations");
        assert_eq!(quote("/a/b c"), "'/a/b c'");
        assert_eq!(quote("it's"), r"'it'\''s'");
        assert_eq!(quote(""), "''");
        assert_eq!(quote("$HOME"), "'$HOME'");
    }
}
