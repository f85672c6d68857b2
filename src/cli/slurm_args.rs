//! `--slurm` and the jobs' resources, shared by `partition` and `bench trade`.

use clap::Args;
use lpmsplat::partition::slurm::SlurmOptions;

#[derive(Args, Debug, Clone)]
pub struct SlurmArgs {
    /// Write Slurm job scripts instead of running here: slurm/task.sh (a job array, one task
    /// a block or a sweep's seed), slurm/merge.sh (after the array, afterok) and
    /// slurm/submit.sh (submits what has not finished; run it again after a failure).
    #[arg(long)]
    pub slurm: bool,
    /// Generic resource of each task (`gpu:1`; `none` for none, e.g. a CPU cluster).
    #[arg(long, default_value = "gpu:1", value_name = "GRES")]
    pub slurm_gres: String,
    /// CPUs of each task.
    #[arg(long, default_value_t = 8, value_name = "N")]
    pub slurm_cpus: u32,
    /// The Slurm partition to submit to.
    #[arg(long, value_name = "NAME")]
    pub slurm_partition: Option<String>,
    /// Each task's time limit (Slurm's forms: 4:00:00, 1-00:00:00).
    #[arg(long, value_name = "TIME")]
    pub slurm_time: Option<String>,
    /// More #SBATCH lines for every job (repeatable): --sbatch=--account=lab.
    #[arg(long = "sbatch", value_name = "FLAG", allow_hyphen_values = true)]
    pub sbatch: Vec<String>,
    /// A block's task saves a checkpoint this often (unless its train arguments say), so a
    /// lost node loses at most this many iterations.
    #[arg(long, default_value_t = 1000, value_name = "N")]
    pub slurm_checkpoint_every: u32,
}

impl SlurmArgs {
    /// The jobs' options; they run this very binary unless `LPMSPLAT` names another.
    pub fn options(&self) -> anyhow::Result<SlurmOptions> {
        anyhow::ensure!(
            self.slurm_cpus > 0,
            "--slurm-cpus 0: a task needs at least one CPU"
        );
        Ok(SlurmOptions {
            gres: (self.slurm_gres != "none").then(|| self.slurm_gres.clone()),
            cpus_per_task: self.slurm_cpus,
            partition: self.slurm_partition.clone(),
            time: self.slurm_time.clone(),
            extra: self.sbatch.clone(),
            checkpoint_every: self.slurm_checkpoint_every,
            binary: std::env::current_exe()?,
        })
    }

    /// The flags of this struct that take a value, for taking them out of a command line
    /// that the tasks run again.
    pub const VALUE_FLAGS: [&'static str; 6] = [
        "--slurm-gres",
        "--slurm-cpus",
        "--slurm-partition",
        "--slurm-time",
        "--sbatch",
        "--slurm-checkpoint-every",
    ];
}
