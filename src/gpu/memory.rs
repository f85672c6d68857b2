//! Device memory accounting: the bytes of live device-local buffers, an optional limit on them
//! (`--memory-limit`: sharing a GPU between runs, or rehearsing a smaller device), and the
//! typed error every device-local allocation fails with when memory runs out, so that callers
//! (the trainer's loop) can tell running out of memory from any other failure and save their
//! work instead of crashing.

use std::sync::atomic::{AtomicU64, Ordering};

/// Live device-local bytes and the limit they may not pass.
#[derive(Debug, Default)]
pub struct DeviceMemory {
    limit: Option<u64>,
    in_use: AtomicU64,
    peak: AtomicU64,
}

impl DeviceMemory {
    pub fn new(limit: Option<u64>) -> Self {
        Self {
            limit,
            ..Default::default()
        }
    }

    /// The limit in bytes, if one was set.
    pub fn limit(&self) -> Option<u64> {
        self.limit
    }

    /// Bytes of live device-local buffers.
    pub fn in_use(&self) -> u64 {
        self.in_use.load(Ordering::Relaxed)
    }

    /// The most bytes of device-local buffers alive at once so far.
    pub fn peak(&self) -> u64 {
        self.peak.load(Ordering::Relaxed)
    }

    /// Books `bytes` for buffer `name`, or refuses them when the limit would be passed.
    pub fn reserve(&self, name: &str, bytes: u64) -> Result<(), OutOfDeviceMemory> {
        let mut now = self.in_use.load(Ordering::Relaxed);
        loop {
            let next = now.saturating_add(bytes);
            if self.limit.is_some_and(|l| next > l) {
                return Err(OutOfDeviceMemory {
                    buffer: name.to_string(),
                    bytes,
                    in_use: now,
                    limit: self.limit,
                    driver: None,
                });
            }
            match self
                .in_use
                .compare_exchange_weak(now, next, Ordering::Relaxed, Ordering::Relaxed)
            {
                Ok(_) => {
                    self.peak.fetch_max(next, Ordering::Relaxed);
                    return Ok(());
                }
                Err(actual) => now = actual,
            }
        }
    }

    /// Returns `bytes` booked by [`Self::reserve`].
    pub fn release(&self, bytes: u64) {
        self.in_use.fetch_sub(bytes, Ordering::Relaxed);
    }
}

/// A device-local buffer could not be allocated: the limit would be passed, or the driver
/// refused the memory (`driver` holds its message).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutOfDeviceMemory {
    pub buffer: String,
    pub bytes: u64,
    pub in_use: u64,
    pub limit: Option<u64>,
    pub driver: Option<String>,
}

impl std::fmt::Display for OutOfDeviceMemory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mib = |b: u64| b as f64 / (1u64 << 20) as f64;
        write!(
            f,
            "out of device memory: buffer '{}' needs {:.1} MiB with {:.1} MiB already in use",
            self.buffer,
            mib(self.bytes),
            mib(self.in_use)
        )?;
        match (&self.driver, self.limit) {
            (Some(d), _) => write!(f, " (the driver refused it: {d})"),
            (None, Some(l)) => write!(f, " (--memory-limit {:.0} MiB)", mib(l)),
            (None, None) => Ok(()),
        }
    }
}

impl std::error::Error for OutOfDeviceMemory {}

/// The out-of-memory error anywhere in `e`'s chain of causes.
pub fn out_of_memory(e: &anyhow::Error) -> Option<&OutOfDeviceMemory> {
    e.chain()
        .find_map(|c| c.downcast_ref::<OutOfDeviceMemory>())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_limit_refuses_what_would_pass_it_and_release_gives_back() {
        let m = DeviceMemory::new(Some(100));
        m.reserve("a", 60).unwrap();
        let e = m.reserve("b", 41).unwrap_err();
        assert_eq!((e.bytes, e.in_use, e.limit), (41, 60, Some(100)));
        assert!(e.to_string().contains("buffer 'b'"), "{e}");
        m.reserve("c", 40).unwrap();
        m.release(60);
        assert_eq!((m.in_use(), m.peak()), (40, 100));
        let unlimited = DeviceMemory::new(None);
        unlimited.reserve("big", u64::MAX / 2).unwrap();
        let wrapped = anyhow::Error::new(e).context("growing the model");
        assert!(out_of_memory(&wrapped).is_some());
        assert!(out_of_memory(&anyhow::anyhow!("other")).is_none());
    }
}
