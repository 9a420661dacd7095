//! What benches record about the machine and the process: the CPU and core count, the
//! process's CPU time, and its peak resident memory over a stretch of work (Linux `/proc`;
//! `None` elsewhere).

/// "2 cores, AMD EPYC, 24 GiB RAM, linux": the cores this process may use, the CPU model,
/// the RAM and the OS.
pub fn describe_machine() -> String {
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let model = cpuinfo
        .lines()
        .find_map(|l| l.strip_prefix("model name"))
        .and_then(|l| l.split_once(':'))
        .map_or_else(
            || std::env::consts::ARCH.to_string(),
            |(_, m)| m.trim().to_string(),
        );
    let ram = meminfo_kib("MemTotal:").map_or(String::new(), |kib| {
        format!(", {:.0} GiB RAM", kib as f64 / 1048576.0)
    });
    format!("{cores} cores, {model}{ram}, {}", std::env::consts::OS)
}

fn meminfo_kib(key: &str) -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    status_kib(&text, key)
}

/// The `kB` value of `key` in a `/proc` status-style text.
fn status_kib(text: &str, key: &str) -> Option<u64> {
    text.lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
}

/// User + system CPU seconds this process has used so far (all threads).
pub fn cpu_seconds() -> Option<f64> {
    let mut usage = std::mem::MaybeUninit::<libc::rusage>::uninit();
    // SAFETY: getrusage fills the struct it is given and touches nothing else.
    let ok = unsafe { libc::getrusage(libc::RUSAGE_SELF, usage.as_mut_ptr()) } == 0;
    if !ok {
        return None;
    }
    // SAFETY: a 0 return means the struct was written.
    let u = unsafe { usage.assume_init() };
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    Some(secs(u.ru_utime) + secs(u.ru_stime))
}

/// The process's peak resident memory from the moment of [`PeakMemory::reset`].
pub struct PeakMemory {
    reset: bool,
}

impl PeakMemory {
    /// Start a measurement: resets the kernel's high-water mark (`VmHWM`) of this process.
    pub fn reset() -> Self {
        Self {
            reset: std::fs::write("/proc/self/clear_refs", "5").is_ok(),
        }
    }

    /// Peak resident memory since the reset, in MiB (`None` where it cannot be reset or
    /// read: the peak would include earlier work).
    pub fn peak_mib(&self) -> Option<f64> {
        if !self.reset {
            return None;
        }
        let text = std::fs::read_to_string("/proc/self/status").ok()?;
        status_kib(&text, "VmHWM:").map(|kib| kib as f64 / 1024.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_values_parse() {
        let text = "Name:\tx\nVmHWM:\t  123456 kB\nVmRSS:\t 1000 kB\n";
        assert_eq!(status_kib(text, "VmHWM:"), Some(123456));
        assert_eq!(status_kib(text, "VmPeak:"), None);
    }

    #[test]
    fn peak_memory_sees_a_large_allocation_and_cpu_time_grows() {
        let cpu0 = cpu_seconds().unwrap();
        let memory = PeakMemory::reset();
        let before = memory.peak_mib();
        // 256 MiB touched, then freed: the peak keeps it.
        let mut big = vec![0u8; 256 << 20];
        for i in (0..big.len()).step_by(4096) {
            big[i] = 1;
        }
        let touched: usize = big.iter().step_by(4096).map(|&b| b as usize).sum();
        drop(big);
        if cfg!(target_os = "linux") {
            let (before, after) = (before.unwrap(), memory.peak_mib().unwrap());
            assert!(after >= before + 200.0, "{before} → {after} MiB");
        }
        let mut x = 0u64;
        for i in 0..20_000_000u64 {
            x = x.wrapping_mul(31).wrapping_add(i);
        }
        std::hint::black_box(x);
        assert!(cpu_seconds().unwrap() > cpu0);
        assert_eq!(touched, 65536);
        let m = describe_machine();
        assert!(m.contains(" cores, ") && !m.starts_with("0 "), "{m}");
    }
}
