//! GPU timestamp queries: per-stage times of a recorded command buffer.

use super::GpuContext;
use anyhow::Context as _;
use ash::vk;
use std::sync::Arc;

/// A pool of timestamp queries with a label per written timestamp.
pub struct TimestampPool {
    ctx: Arc<GpuContext>,
    pub(crate) pool: vk::QueryPool,
    capacity: u32,
    pub(crate) labels: Vec<String>,
}

/// Per-stage durations in milliseconds, in recording order.
#[derive(Debug, Clone, Default)]
pub struct StageTimes {
    pub stages: Vec<(String, f64)>,
}

impl StageTimes {
    pub fn total_ms(&self) -> f64 {
        self.stages.iter().map(|s| s.1).sum()
    }
    /// Adds another measurement stage by stage (matching names).
    pub fn accumulate(&mut self, other: &StageTimes) {
        for (name, ms) in &other.stages {
            if let Some(s) = self.stages.iter_mut().find(|s| &s.0 == name) {
                s.1 += ms;
            } else {
                self.stages.push((name.clone(), *ms));
            }
        }
    }
}

impl TimestampPool {
    pub fn new(ctx: &Arc<GpuContext>, capacity: u32) -> anyhow::Result<Self> {
        let pool = unsafe {
            ctx.device.create_query_pool(
                &vk::QueryPoolCreateInfo::default()
                    .query_type(vk::QueryType::TIMESTAMP)
                    .query_count(capacity),
                None,
            )
        }
        .context("creating timestamp query pool")?;
        Ok(Self {
            ctx: ctx.clone(),
            pool,
            capacity,
            labels: Vec::new(),
        })
    }

    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// Reads the timestamps of the last completed submission. Stage `i` is the time between
    /// timestamp `i` and `i + 1`, named by the label of timestamp `i + 1` (the label says which
    /// stage just finished). Stages recorded more than once under one label (a frame drawn in
    /// bands, several views an iteration) are summed, in the order of their first use.
    pub fn read(&self) -> anyhow::Result<StageTimes> {
        let n = self.labels.len();
        if n < 2 {
            return Ok(StageTimes::default());
        }
        let mut ticks = vec![0u64; n];
        unsafe {
            self.ctx.device.get_query_pool_results(
                self.pool,
                0,
                &mut ticks,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
            )
        }
        .context("reading timestamps")?;
        let period = self.ctx.info.timestamp_period_ns;
        let mut times = StageTimes::default();
        for i in 1..n {
            let ms = ticks[i].saturating_sub(ticks[i - 1]) as f64 * period * 1e-6;
            times.accumulate(&StageTimes {
                stages: vec![(self.labels[i].clone(), ms)],
            });
        }
        Ok(times)
    }
}

impl Drop for TimestampPool {
    fn drop(&mut self) {
        unsafe { self.ctx.device.destroy_query_pool(self.pool, None) };
    }
}
