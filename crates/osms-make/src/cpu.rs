//! The CPU time a build used: its own thread's plus its worker pool's, read from the kernel's
//! per-thread CPU clocks.
//!
//! Each build runs on a pool of its own, so what its threads used is its cost whatever else
//! ran beside it: a record's core-seconds (and so `--dry-run`'s estimates and `exp show`'s
//! times) do not depend on `--stages`.

use std::sync::{Arc, Mutex, PoisonError};

/// CPU seconds the calling thread has used since it started (`CLOCK_THREAD_CPUTIME_ID`), the
/// clock a build's own thread is metered by.
pub fn thread_secs() -> f64 {
    clock_secs(libc::CLOCK_THREAD_CPUTIME_ID).unwrap_or(0.0)
}

/// The workspace denies `unsafe_code`; the per-thread CPU clocks have no safe wrapper in std.
#[allow(unsafe_code)]
fn clock_secs(clock: libc::clockid_t) -> Option<f64> {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; an invalid clock id is an error return.
    let rc = unsafe { libc::clock_gettime(clock, &mut ts) };
    (rc == 0).then_some(ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9)
}

/// Bytes an unprivileged process may still write on the filesystem holding `path`
/// (`statvfs`'s available blocks), or `None` where the kernel does not say.
#[allow(unsafe_code)]
pub fn free_bytes(path: &std::path::Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).ok()?;
    // SAFETY: an all-zero statvfs is a valid value of the plain C struct the call fills in.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c` is a NUL-terminated path and `st` a valid, writable statvfs.
    let rc = unsafe { libc::statvfs(c.as_ptr(), &mut st) };
    (rc == 0).then(|| st.f_bavail as u64 * st.f_frsize as u64)
}

/// A rayon pool that can say how much CPU time its threads have used.
pub(crate) struct MeteredPool {
    pub(crate) pool: rayon::ThreadPool,
    threads: Arc<Mutex<Vec<libc::pthread_t>>>,
}

impl MeteredPool {
    pub(crate) fn new(
        threads: usize,
        prefix: &'static str,
    ) -> Result<Self, rayon::ThreadPoolBuildError> {
        let handles: Arc<Mutex<Vec<libc::pthread_t>>> = Arc::default();
        let register = Arc::clone(&handles);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.max(1))
            .thread_name(move |i| format!("{prefix}-{i}"))
            .start_handler(move |_| {
                register
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .push(pthread_self());
            })
            .build()?;
        Ok(MeteredPool {
            pool,
            threads: handles,
        })
    }

    /// CPU seconds used so far by the pool's threads (those started yet: the others have used
    /// none).
    #[allow(unsafe_code)]
    pub(crate) fn secs(&self) -> f64 {
        let threads = self.threads.lock().unwrap_or_else(PoisonError::into_inner);
        threads
            .iter()
            .filter_map(|&t| {
                let mut clock: libc::clockid_t = 0;
                // SAFETY: `t` names a thread of `self.pool`, which is alive while `self` is
                // borrowed: rayon's workers run until their pool is dropped.
                let rc = unsafe { libc::pthread_getcpuclockid(t, &mut clock) };
                if rc == 0 { clock_secs(clock) } else { None }
            })
            .sum()
    }
}

#[allow(unsafe_code)]
fn pthread_self() -> libc::pthread_t {
    // SAFETY: always succeeds, no arguments.
    unsafe { libc::pthread_self() }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spin(secs: f64) -> u64 {
        let start = thread_secs();
        let mut x = 0u64;
        while thread_secs() - start < secs {
            for i in 0..10_000u64 {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(i);
            }
        }
        x
    }

    /// Two workers that each spin 0.2 s of CPU: the pool reads ≥ 0.4 s, and an idle pool ≈ 0,
    /// whatever the wall time (the threads may have shared one core).
    #[test]
    fn a_pool_reads_its_threads_cpu_time() {
        let idle = MeteredPool::new(2, "idle").expect("pool");
        idle.pool.install(|| ());
        assert!(idle.secs() < 0.05, "an idle pool used {}", idle.secs());

        let metered = MeteredPool::new(2, "busy").expect("pool");
        let before = thread_secs();
        metered.pool.install(|| {
            rayon::join(|| spin(0.2), || spin(0.2));
        });
        let used = metered.secs();
        assert!((0.4..1.0).contains(&used), "the pool used {used} s");
        // The caller only waited.
        assert!(thread_secs() - before < 0.1);
    }
}
