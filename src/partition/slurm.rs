//! Slurm job scripts: a job array and a job that collects it after the array (`afterok`), for
//! a plan's blocks (one task a block, then `merge`) and for `bench trade` sweeps (one task a
//! seed, then `bench merge`). Slurm is the scheduler; these are its ordinary batch scripts,
//! nothing of ours runs between the jobs.
//!
//! A block's task trains its block into `runs/<block>/` and writes nothing else. It is idempotent and
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

/// One task of an array: its name (its output folder is `runs/<name>/`) and the `lpmsplat`
/// arguments it runs with.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    pub name: String,
    pub args: Vec<String>,
    /// Arguments it gets only when it starts fresh (a block's `--init-ply` of its start from
    /// the coarse model, which `train` refuses beside `--resume`).
    pub fresh_args: Vec<String>,
}

/// A job array and the job that collects it, as scripts.
#[derive(Debug, Clone, PartialEq)]
pub struct JobArray {
    /// Slurm's job name of the tasks (the collecting job gets `<name>-merge`).
    pub job_name: String,
    /// The folder the scripts, runs and results live in (absolute).
    pub dir: std::path::PathBuf,
    pub cells: Vec<Cell>,
    /// The file a finished cell's run folder holds (what `submit.sh` skips by).
    pub done_file: String,
    /// Whether a cell whose folder holds `checkpoint.bin` resumes from it (`--resume`).
    pub resumes: bool,
    pub cell_mem_mib: u64,
    /// The collecting job's `lpmsplat` arguments.
    pub merge_args: Vec<String>,
    pub merge_mem_mib: u64,
}

/// The three scripts (`task.sh`, `merge.sh`, `submit.sh`) of `array`.
pub fn scripts(array: &JobArray, opts: &SlurmOptions) -> Vec<(&'static str, String)> {
    let d = quote(&array.dir.display().to_string());
    let bin = quote(&opts.binary.display().to_string());
    let names: String = array
        .cells
        .iter()
        .map(|c| quote(&c.name))
        .collect::<Vec<_>>()
        .join(" ");
    let words = |args: &[String]| args.iter().map(|a| quote(a)).collect::<Vec<_>>().join(" ");
    let cases: String = array
        .cells
        .iter()
        .enumerate()
        .map(|(k, c)| {
            format!(
                "  {k}) args=({}); fresh=({}) ;;\n",
                words(&c.args),
                words(&c.fresh_args)
            )
        })
        .collect();
    let done = quote(&array.done_file);

    let mut task = header(
        &array.job_name,
        opts,
        &format!("{d}/slurm/logs/task-%a.out"),
    );
    task += &format!("#SBATCH --mem={}\n", array.cell_mem_mib);
    if let Some(g) = &opts.gres {
        task += &format!("#SBATCH --gres={g}\n");
    }
    task += &format!(
        r#"# One task of the array: Slurm's array index (or the first argument) picks it. It writes
# only runs/<name>/, does nothing when that holds a finished run{resume_note}.
set -euo pipefail
DIR={d}
LPMSPLAT=${{LPMSPLAT:-{bin}}}
CELLS=({names})
k=${{SLURM_ARRAY_TASK_ID:-${{1:?give the task index}}}}
name=${{CELLS[$k]}}
run="$DIR/runs/$name"
if [ -f "$run"/{done} ]; then
  echo "$name: finished before, nothing to do"
  exit 0
fi
mkdir -p "$run"
case $k in
{cases}  *) echo "no task $k" >&2; exit 2 ;;
esac
{resume}"$LPMSPLAT" "${{args[@]}}"
touch "$run"/{done}
"#,
        resume_note = if array.resumes {
            ", and resumes from its checkpoint when an earlier attempt stopped"
        } else {
            " (a stopped one starts again)"
        },
        resume = match array.resumes {
            true => "if [ -f \"$run/checkpoint.bin\" ]; then\n  echo \"$name: resuming from $run/checkpoint.bin\"\n  args+=(--resume \"$run/checkpoint.bin\")\nelse\n  args+=(\"${fresh[@]}\")\nfi\n",
            false => "args+=(\"${fresh[@]}\")\n",
        },
    );

    let mut merge = header(
        &format!("{}-merge", array.job_name),
        opts,
        &format!("{d}/slurm/logs/merge.out"),
    );
    merge += &format!("#SBATCH --mem={}\n", array.merge_mem_mib);
    merge += &format!(
        r#"# Collects the tasks' runs once every task has finished (the job depends on the array with
# afterok); refuses, naming it, a run that is missing or broken.
set -euo pipefail
LPMSPLAT=${{LPMSPLAT:-{bin}}}
exec "$LPMSPLAT" {merge}
"#,
        merge = words(&array.merge_args)
    );

    let submit = format!(
        r#"#!/usr/bin/env bash
# Submits the tasks that have no finished run as one job array, then the collecting job after
# them (afterok). Run it again after a failure: only what is missing is submitted. Extra
# arguments go to both sbatch calls (e.g. --partition=gpu).
set -euo pipefail
DIR={d}
CELLS=({names})
mkdir -p "$DIR/slurm/logs"
missing=()
for k in "${{!CELLS[@]}}"; do
  [ -f "$DIR/runs/${{CELLS[$k]}}"/{done} ] || missing+=("$k")
done
dependency=()
if [ ${{#missing[@]}} -gt 0 ]; then
  list=$(IFS=,; echo "${{missing[*]}}")
  array=$(sbatch --parsable "$@" --array="$list" "$DIR/slurm/task.sh")
  array=${{array%%;*}}
  echo "tasks: job array $array (tasks $list of {n})"
  dependency=(--dependency="afterok:$array")
else
  echo "tasks: every task has finished"
fi
merge=$(sbatch --parsable "$@" "${{dependency[@]}}" "$DIR/slurm/merge.sh")
echo "merge: job ${{merge%%;*}}"
"#,
        n = array.cells.len(),
    );
    vec![
        ("task.sh", task),
        ("merge.sh", merge),
        ("submit.sh", submit),
    ]
}

/// The job array that trains `plan`'s blocks (in `dir`, absolute) and merges them: a task a
/// block, `train <block folder> -o runs/<block>` with the plan's train arguments, the block's
/// budget when the plan shares one out, the coarse model as its start when the plan has one
/// (on a fresh start), and a checkpoint every `opts.checkpoint_every`.
pub fn block_array(plan: &Plan, dir: &Path, opts: &SlurmOptions) -> JobArray {
    let has_checkpoint_flag = plan
        .train_args
        .iter()
        .any(|a| a.starts_with("--checkpoint-every"));
    let cells = plan
        .blocks
        .iter()
        .map(|b| {
            let mut args = vec![
                "train".to_string(),
                dir.join(&b.folder).display().to_string(),
                "-o".into(),
                dir.join("runs").join(&b.name).display().to_string(),
            ];
            args.extend(plan.train_args.iter().cloned());
            if plan.budget.is_some() {
                args.extend(["--budget".into(), b.expected_gaussians.to_string()]);
            }
            if plan.grow_within_region {
                args.extend([
                    "--grow-within".into(),
                    dir.join(super::blocks::region_path(b))
                        .display()
                        .to_string(),
                ]);
            }
            if !has_checkpoint_flag {
                args.extend([
                    "--checkpoint-every".into(),
                    opts.checkpoint_every.to_string(),
                ]);
            }
            Cell {
                name: b.name.clone(),
                args,
                fresh_args: match &plan.coarse {
                    Some(_) => vec![
                        "--init-ply".into(),
                        dir.join(super::blocks::block_start_path(b))
                            .display()
                            .to_string(),
                    ],
                    None => Vec::new(),
                },
            }
        })
        .collect();
    let s = |p: std::path::PathBuf| p.display().to_string();
    JobArray {
        job_name: "lpmsplat-block".into(),
        dir: dir.to_path_buf(),
        cells,
        done_file: super::merge::BLOCK_DONE.into(),
        resumes: true,
        cell_mem_mib: task_memory_mib(plan),
        merge_args: vec![
            "merge".into(),
            s(dir.join("plan.json")),
            "--runs".into(),
            s(dir.join("runs")),
            "-o".into(),
            s(dir.join("merged")),
        ],
        merge_mem_mib: merge_memory_mib(plan),
    }
}

/// Writes `array`'s scripts into `dir/slurm/` (executable).
pub fn write_scripts(array: &JobArray, opts: &SlurmOptions) -> anyhow::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    let slurm = array.dir.join("slurm");
    std::fs::create_dir_all(slurm.join("logs"))?;
    for (name, text) in scripts(array, opts) {
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
