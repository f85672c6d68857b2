//! The whole of training past one machine on a real Slurm: a single-node cluster started here
//! (`scripts/slurm-node.sh`: its own munge key, config, state and logs in a temp dir), a 2×1
//! plan of the bundled scene submitted as a job array plus a merge job after it, the merged
//! model checked against the blocks' own models and scored on the whole scene, then one block
//! lost and the plan submitted again: only that block runs, and the merge after it.
//!
//! Skips, saying why, only where the daemons cannot start outside CI; under CI (which
//! installs the packages) a cluster that does not come up fails the test.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use crate::cli_support::{lpmsplat, run_ok};
use lpmsplat::partition::Plan;

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/lund_door_small");
const NODE_SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/slurm-node.sh");

/// The cluster's daemons, stopped when dropped (a failing assertion included).
struct Cluster {
    dir: PathBuf,
    conf: String,
}

impl Cluster {
    fn start(dir: &Path) -> Result<Cluster, String> {
        let out = Command::new("bash")
            .arg(NODE_SCRIPT)
            .arg("start")
            .arg(dir)
            .output()
            .map_err(|e| format!("cannot run {NODE_SCRIPT}: {e}"))?;
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        if !out.status.success() {
            return Err(format!(
                "{NODE_SCRIPT} start failed ({}):\n{text}{}",
                out.status,
                String::from_utf8_lossy(&out.stderr)
            ));
        }
        let conf = text
            .lines()
            .find_map(|l| l.strip_prefix("SLURM_CONF="))
            .ok_or_else(|| format!("no SLURM_CONF line in:\n{text}"))?
            .to_string();
        Ok(Cluster {
            dir: dir.to_path_buf(),
            conf,
        })
    }

    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    /// Waits until no job of ours is queued or running.
    fn wait_idle(&self, timeout: Duration) {
        let start = Instant::now();
        loop {
            let out = self
                .command("squeue")
                .args(["-h", "-o", "%i %T %R"])
                .output();
            let text = out
                .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
                .unwrap_or_default();
            if text.trim().is_empty() {
                return;
            }
            assert!(
                start.elapsed() < timeout,
                "jobs still queued after {timeout:?}:\n{text}"
            );
            std::thread::sleep(Duration::from_millis(500));
        }
    }

    fn job_state(&self, id: &str) -> String {
        let out = self
            .command("scontrol")
            .args(["show", "job", id])
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        text.split_whitespace()
            .find_map(|w| w.strip_prefix("JobState="))
            .unwrap_or("unknown")
            .to_string()
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new("bash")
            .arg(NODE_SCRIPT)
            .arg("stop")
            .arg(&self.dir)
            .status();
    }
}

fn submit(cluster: &Cluster, plan_dir: &Path) -> (String, String) {
    let out = cluster
        .command("bash")
        // The jobs inherit it (sbatch exports the environment): the validation layer on.
        .env("LPMSPLAT_VALIDATION", "1")
        .arg(plan_dir.join("slurm/submit.sh"))
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "submit.sh failed:\n{text}");
    let merge = text
        .lines()
        .find_map(|l| l.strip_prefix("merge: job "))
        .unwrap_or_else(|| panic!("no merge job in:\n{text}"))
        .trim()
        .to_string();
    (text, merge)
}

/// Submits `dir`'s scripts, checks what `submit.sh` says of the tasks (`tasks`), waits up to
/// `seconds` for the cluster to go idle, and checks the merge job completed.
fn submit_to_completion(cluster: &Cluster, dir: &Path, tasks: &str, seconds: u64) {
    let (text, merge_job) = submit(cluster, dir);
    assert!(text.contains(tasks), "{text}");
    cluster.wait_idle(Duration::from_secs(seconds));
    assert_eq!(cluster.job_state(&merge_job), "COMPLETED", "{}", logs(dir));
}

fn logs(plan_dir: &Path) -> String {
    let mut s = String::new();
    if let Ok(rd) = std::fs::read_dir(plan_dir.join("slurm/logs")) {
        for e in rd.flatten() {
            s += &format!(
                "== {}\n{}\n",
                e.path().display(),
                std::fs::read_to_string(e.path()).unwrap_or_default()
            );
        }
    }
    s
}

fn eval_psnr(scene: &str, ply: &Path) -> f64 {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("eval.json");
    run_ok(
        lpmsplat()
            .args(["eval", scene, "-r", "4", "--ply"])
            .arg(ply)
            .arg("--json")
            .arg(&json),
    );
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    j["psnr"]
        .as_f64()
        .or_else(|| j["mean"]["psnr"].as_f64())
        .unwrap_or_else(|| panic!("no psnr in {j}"))
}

#[test]
fn a_plan_trains_as_a_slurm_job_array_and_merges_after_it() {
    let tmp = tempfile::tempdir().unwrap();
    let cluster = match Cluster::start(&tmp.path().join("slurm")) {
        Ok(c) => c,
        Err(why) if std::env::var_os("CI").is_none() => {
            eprintln!("skipped: a single-node Slurm cannot start here: {why}");
            return;
        }
        Err(why) => panic!("CI installs Slurm, yet the node did not start: {why}"),
    };
    let plan_dir = tmp.path().join("plan");
    run_ok(
        lpmsplat()
            .args(["partition", SCENE, "-r", "4", "--blocks", "2x1", "--slurm"])
            .args(["--slurm-gres", "gpu:1", "--slurm-cpus", "1"])
            .arg("-o")
            .arg(&plan_dir)
            .args(["--", "--iterations", "60", "--densify-from", "20"])
            .args(["--densify-interval", "20", "--densify-until", "50"]),
    );
    let plan = Plan::read(&plan_dir.join("plan.json")).unwrap();
    assert_eq!(plan.blocks.len(), 2);
    let task = std::fs::read_to_string(plan_dir.join("slurm/task.sh")).unwrap();
    assert!(task.contains("#SBATCH --gres=gpu:1"), "{task}");

    submit_to_completion(&cluster, &plan_dir, "tasks 0,1 of 2", 600);

    // The merged model: each block's Gaussians in its own core, recounted here from the
    // blocks' files.
    let merged_ply = plan_dir.join("merged/point_cloud.ply");
    let merged = lpmsplat::splats::read_ply(&merged_ply).unwrap();
    let mut expected = 0;
    for b in &plan.blocks {
        let own = lpmsplat::splats::read_ply(
            &plan_dir.join("runs").join(&b.name).join("point_cloud.ply"),
        )
        .unwrap();
        let kept = own
            .positions
            .iter()
            .filter(|p| {
                b.core
                    .contains(plan.ground.coordinates(p.map(|x| x as f64)).0)
            })
            .count();
        assert!(
            kept > 0 && kept < own.len(),
            "block {}: {kept} of {}",
            b.name,
            own.len()
        );
        let in_merged = merged
            .positions
            .iter()
            .filter(|p| {
                plan.owner(plan.ground.coordinates(p.map(|x| x as f64)).0)
                    == plan.blocks.iter().position(|o| o.name == b.name)
            })
            .count();
        assert_eq!(in_merged, kept, "block {}", b.name);
        expected += kept;
    }
    assert_eq!(merged.len(), expected);
    assert!(plan_dir.join("merged/point_cloud.splat").is_file());
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(plan_dir.join("merged/merge_report.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(report["gaussians"].as_u64(), Some(expected as u64));

    // The merged model renders the whole scene better than either block's own model, each of
    // which holds only its region.
    let whole = eval_psnr(SCENE, &merged_ply);
    for b in &plan.blocks {
        let alone = eval_psnr(
            SCENE,
            &plan_dir.join("runs").join(&b.name).join("point_cloud.ply"),
        );
        assert!(
            whole > alone + 0.5,
            "merged {whole:.2} dB, block {} alone {alone:.2}",
            b.name
        );
    }

    // A lost block: submitting again runs only it, then the merge.
    let lost = &plan.blocks[1].name;
    std::fs::remove_dir_all(plan_dir.join("runs").join(lost)).unwrap();
    let first_other = std::fs::metadata(
        plan_dir
            .join("runs")
            .join(&plan.blocks[0].name)
            .join("metrics.json"),
    )
    .unwrap()
    .modified()
    .unwrap();
    submit_to_completion(&cluster, &plan_dir, "tasks 1 of 2", 600);
    assert!(plan_dir
        .join("runs")
        .join(lost)
        .join("metrics.json")
        .is_file());
    // The finished block was not trained again.
    let again = std::fs::metadata(
        plan_dir
            .join("runs")
            .join(&plan.blocks[0].name)
            .join("metrics.json"),
    )
    .unwrap()
    .modified()
    .unwrap();
    assert_eq!(first_other, again);

    // Everything finished: a third submission submits no block, only a merge.
    submit_to_completion(&cluster, &plan_dir, "every task has finished", 120);

    // A benchmark sweep on the same cluster: one task a seed, then bench merge of both.
    let sweep = tmp.path().join("sweep");
    run_ok(
        lpmsplat()
            .args(["bench", "trade", SCENE, "-r", "8", "--iterations", "10"])
            .args([
                "--runs",
                "adc,adc-1e-4",
                "--fps-frames",
                "1",
                "--seeds",
                "2",
            ])
            .args(["--slurm", "--slurm-cpus", "1", "--slurm-gres", "none", "-o"])
            .arg(&sweep),
    );
    submit_to_completion(&cluster, &sweep, "tasks 0,1 of 2", 600);
    let merged: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sweep.join("merged/trade.json")).unwrap())
            .unwrap();
    let mut seeds: Vec<u64> = merged["runs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["seed"].as_u64().unwrap())
        .collect();
    seeds.sort();
    seeds.dedup();
    assert_eq!(seeds, [0, 1], "{merged}");
}
