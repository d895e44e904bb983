//! How fast the streaming PLY reader (`oavm::mesh::stream::PlyStream`, what `oavm-pack` reads a
//! mesh with when it does not fit the memory budget) goes over a big binary PLY: the time to
//! open it, the positions pass, the triangle pass (batches of 65536 triangles, each summed so
//! that the pass is not optimised away), both passes in MiB/s of file, and the process's peak
//! resident memory against the positions' size.
//!
//! `cargo run --release --features tools --example stream_bench -- BIG.ply`, a binary PLY (`make_copies` writes
//! big ones; `parse_bench` leaves the dragon's in the temporary directory). One run: the first
//! pass may read the file from disk, later runs from the page cache. Numbers for us, not for the
//! docs.

use std::path::PathBuf;
use std::time::Instant;

use oavm::mesh::stream::PlyStream;

const USAGE: &str = "usage: stream_bench BIG.ply (a binary PLY)";

fn main() {
    if let Err(e) = run() {
        eprintln!("stream_bench: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), String> {
    let mut path = None;
    for a in std::env::args().skip(1) {
        match a.as_str() {
            "-h" | "--help" => {
                println!("{USAGE}");
                return Ok(());
            }
            _ if path.is_none() && !a.starts_with('-') => path = Some(PathBuf::from(a)),
            _ => return Err(format!("unexpected argument {a:?}\n{USAGE}")),
        }
    }
    let path = path.ok_or(USAGE)?;
    let t = Instant::now();
    let s = PlyStream::open(&path).map_err(|e| e.to_string())?;
    let open = t.elapsed().as_secs_f64();
    let mib = s.file_len() as f64 / (1 << 20) as f64;
    let t = Instant::now();
    let positions = s.read_positions(&|_| {}).map_err(|e| e.to_string())?;
    let pass1 = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut sum = 0f64;
    let n = s
        .for_each_triangle_batch(&positions, 1 << 16, &|_| {}, &mut |b| {
            sum += b.iter().map(|(_, t)| f64::from(t[0][0])).sum::<f64>();
            Ok(())
        })
        .map_err(|e| e.to_string())?;
    let pass2 = t.elapsed().as_secs_f64();
    s.check_unchanged().map_err(|e| e.to_string())?;
    let vbytes = s.vertex_count() as f64 * 12.0 / (1 << 20) as f64;
    println!(
        "{}: {mib:.0} MiB, {} vertices, {} faces, {n} triangles (checksum {sum:.3})",
        path.display(),
        s.vertex_count(),
        s.face_count()
    );
    println!(
        "open {:.1} ms; positions {pass1:.2} s; triangle pass {pass2:.2} s; \
         both {:.2} s = {:.0} MiB/s of file; peak RSS {:.0} MiB (positions {vbytes:.0} MiB)",
        open * 1e3,
        pass1 + pass2,
        mib / (pass1 + pass2),
        peak_rss_mib()
    );
    Ok(())
}

/// The process's peak resident set (`VmHWM` of `/proc/self/status`), NaN where it is missing.
fn peak_rss_mib() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}
