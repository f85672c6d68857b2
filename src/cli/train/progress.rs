//! A training run's record as it goes: the progress bar (plain lines every ~10 s without a
//! terminal), the samples and evaluations that training.png and metrics.json draw, the stage
//! times, and the time intermediate evaluations and checkpoints take, which the training's own
//! rate leaves out.

use crate::cli::train_plot::{EvalPoint, Sample};
use indicatif::{ProgressBar, ProgressStyle};
use lpmsplat::gpu::StageTimes;
use lpmsplat::train::trainer::{StepReport, ViewMetrics};
use std::time::Instant;

pub struct TrainingLog {
    bar: ProgressBar,
    /// No terminal (CI, logs): the bar is hidden and a plain line printed instead.
    plain: bool,
    last_line: Instant,
    t0: Instant,
    start_iteration: u32,
    iterations: u32,
    ema_loss: Option<f64>,
    pub stages: StageTimes,
    /// The intermediate evaluations, as metrics.json lists them.
    pub evals: Vec<serde_json::Value>,
    /// For training.png: a sample every 10 iterations, and the evaluations, on a clock that
    /// leaves out evaluations and checkpoints.
    pub samples: Vec<Sample>,
    pub eval_points: Vec<EvalPoint>,
    /// Seconds of intermediate evaluations and checkpoints.
    pub paused_s: f64,
    /// What the base model's own rules reported, as JSON.
    pub model_events: Vec<serde_json::Value>,
    /// Under --max-gaussians: additions the budget dropped, and on how many density steps.
    pub budget: (usize, usize),
    /// The Gaussian count after each iteration of this run, summed: over the iterations, the
    /// model size the run paid for, which the final count alone does not say.
    count_sum: f64,
    recorded: u32,
}

impl TrainingLog {
    /// Starts the clock of a run from `start_iteration` (a resumed run's) to `iterations`.
    pub fn new(iterations: u32, start_iteration: u32) -> TrainingLog {
        let bar = ProgressBar::new(iterations as u64);
        bar.set_position(start_iteration as u64);
        bar.set_style(
            ProgressStyle::with_template(
                "{bar:30} {pos}/{len} {msg} [{elapsed_precise} < {eta_precise}, {per_sec}]",
            )
            .unwrap(),
        );
        TrainingLog {
            bar,
            plain: !std::io::IsTerminal::is_terminal(&std::io::stderr()),
            last_line: Instant::now(),
            t0: Instant::now(),
            start_iteration,
            iterations,
            ema_loss: None,
            stages: StageTimes::default(),
            evals: Vec::new(),
            samples: Vec::new(),
            eval_points: Vec::new(),
            paused_s: 0.0,
            model_events: Vec::new(),
            budget: (0, 0),
            count_sum: 0.0,
            recorded: 0,
        }
    }

    /// Prints a line above the bar (or plainly without a terminal).
    pub fn println(&self, line: String) {
        if self.plain {
            eprintln!("{line}");
        } else {
            self.bar.println(line);
        }
    }

    /// Leaves the bar where it is (the run stops early).
    pub fn abandon(&self) {
        self.bar.abandon();
    }

    pub fn finish(&self) {
        self.bar.finish();
    }

    /// Seconds since the run started, evaluations and checkpoints included.
    pub fn elapsed_s(&self) -> f64 {
        self.t0.elapsed().as_secs_f64()
    }

    /// Takes in a finished iteration: the model's events, the stage times, the budget's drops,
    /// the smoothed loss, a sample every 10 iterations, the bar and the plain line.
    pub fn record(&mut self, r: &StepReport) {
        for e in &r.model_events {
            self.println(e.describe());
            self.model_events.push(e.to_json());
        }
        if let Some(s) = &r.stages {
            self.stages.accumulate(s);
        }
        if let Some(d) = r.densified.as_ref().filter(|d| d.budget_dropped > 0) {
            self.budget.0 += d.budget_dropped;
            self.budget.1 += 1;
        }
        self.count_sum += r.gaussians as f64;
        self.recorded += 1;
        let l = r.loss as f64;
        let ema = self.ema_loss.map_or(l, |e| 0.9 * e + 0.1 * l);
        self.ema_loss = Some(ema);
        if !r.iteration.is_multiple_of(10) && r.iteration != self.iterations {
            return;
        }
        self.samples.push(Sample {
            iteration: r.iteration,
            seconds: self.elapsed_s() - self.paused_s,
            loss: ema,
            gaussians: r.gaussians,
        });
        let psnr_l1 = -10.0 * (r.l1 as f64).max(1e-12).log10();
        self.bar.set_message(format!(
            "loss {ema:.4} (L1 {:.4}, ~{psnr_l1:.1} dB) | {} Gaussians",
            r.l1, r.gaussians
        ));
        self.bar.set_position(r.iteration as u64);
        if self.plain
            && (self.last_line.elapsed().as_secs_f64() > 10.0 || r.iteration == self.iterations)
        {
            self.last_line = Instant::now();
            let rate = (r.iteration - self.start_iteration) as f64 / self.elapsed_s();
            eprintln!(
                "[{}/{}] loss {ema:.4} (L1 {:.4}) | {} Gaussians | {rate:.2} it/s | ETA {:.0} s",
                r.iteration,
                self.iterations,
                r.l1,
                r.gaussians,
                (self.iterations - r.iteration) as f64 / rate
            );
        }
    }

    /// The Gaussian count averaged over the iterations recorded so far (a resumed run's own,
    /// not the checkpoint's); 0 before the first.
    pub fn mean_gaussians(&self) -> f64 {
        self.count_sum / self.recorded.max(1) as f64
    }

    /// Runs `work` (a checkpoint) on the paused clock.
    pub fn paused<T>(&mut self, work: impl FnOnce() -> anyhow::Result<T>) -> anyhow::Result<T> {
        let t_pause = Instant::now();
        let out = work();
        self.paused_s += t_pause.elapsed().as_secs_f64();
        out
    }

    /// An intermediate evaluation after `iteration` with `gaussians` (`evaluate` scores the test
    /// views), on the paused clock: printed, and kept for metrics.json and training.png.
    pub fn evaluation(
        &mut self,
        iteration: u32,
        gaussians: usize,
        evaluate: impl FnOnce() -> anyhow::Result<(Vec<ViewMetrics>, Option<f64>)>,
    ) -> anyhow::Result<()> {
        let t_pause = Instant::now();
        let (m, lp) = evaluate()?;
        let (p, s) = ViewMetrics::means(&m);
        self.eval_points.push(EvalPoint {
            iteration,
            seconds: t_pause.duration_since(self.t0).as_secs_f64() - self.paused_s,
            psnr: p,
            gaussians,
        });
        self.println(format!(
            "[{iteration}] test PSNR {p:.3} dB, SSIM {s:.4},{} {gaussians} Gaussians",
            lp.map_or(String::new(), |d| format!(" LPIPS {d:.4},")),
        ));
        self.evals.push(serde_json::json!({
            "iteration": iteration,
            "psnr": p,
            "ssim": s,
            "lpips": lp,
            "gaussians": gaussians,
            "per_view": m,
        }));
        self.paused_s += t_pause.elapsed().as_secs_f64();
        Ok(())
    }
}
