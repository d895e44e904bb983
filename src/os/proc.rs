//! What the kernel says about this process and the memory it may use (Linux `/proc` and the
//! memory cgroup). Every reading is `None` where the file is missing or unreadable (another OS,
//! a sandbox), and callers treat that as "unknown".

use std::path::Path;

/// The process's peak resident set size (`VmHWM` of `/proc/self/status`), in bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    field("/proc/self/status", "VmHWM:").map(|kb| kb * 1024)
}

/// Bytes this process has caused to be read from storage (`read_bytes` of `/proc/self/io`).
pub fn read_bytes() -> Option<u64> {
    field("/proc/self/io", "read_bytes:")
}

/// The memory this process can use without pushing others out: the kernel's estimate of
/// available memory (`MemAvailable`), lowered to what the process's memory cgroup has left
/// (v1 `memory.limit_in_bytes - memory.usage_in_bytes`, or v2 `memory.max -
/// memory.current`), in bytes. `None` when neither can be read.
pub fn available_memory() -> Option<u64> {
    let meminfo = field("/proc/meminfo", "MemAvailable:").map(|kb| kb * 1024);
    [meminfo, cgroup_headroom()].into_iter().flatten().min()
}

/// What the memory cgroup of this process has left before its limit.
fn cgroup_headroom() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    for line in text.lines() {
        // `hierarchy-id:controllers:path`; v1 memory has "memory" among its controllers, v2
        // has id 0 and no controllers.
        let mut parts = line.splitn(3, ':');
        let (id, controllers, path) = (parts.next()?, parts.next()?, parts.next()?);
        let rel = path.trim_start_matches('/');
        if controllers.split(',').any(|c| c == "memory") {
            let dir = Path::new("/sys/fs/cgroup/memory").join(rel);
            return headroom(
                &dir.join("memory.limit_in_bytes"),
                &dir.join("memory.usage_in_bytes"),
            );
        }
        if id == "0" && controllers.is_empty() {
            let dir = Path::new("/sys/fs/cgroup").join(rel);
            return headroom(&dir.join("memory.max"), &dir.join("memory.current"));
        }
    }
    None
}

fn headroom(limit: &Path, usage: &Path) -> Option<u64> {
    let read = |p: &Path| std::fs::read_to_string(p).ok()?.trim().parse::<u64>().ok();
    // "max" (v2) or a huge number (v1: the largest page multiple) mean no limit.
    let limit = read(limit).filter(|&l| l < 1 << 60)?;
    Some(limit.saturating_sub(read(usage).unwrap_or(0)))
}

/// The number after `key` in a `/proc` file of `key value` lines.
fn field(path: &str, key: &str) -> Option<u64> {
    let text = std::fs::read_to_string(path).ok()?;
    let line = text.lines().find(|l| l.starts_with(key))?;
    line[key.len()..].split_whitespace().next()?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readings_are_plausible_on_linux() {
        let rss = peak_rss_bytes().expect("VmHWM");
        assert!(rss > 1 << 20, "peak RSS {rss}");
        assert!(read_bytes().is_some());
        let avail = available_memory().expect("MemAvailable");
        assert!(avail > 1 << 20, "available {avail}");
    }
}
