//! Hostile inputs and outputs, as a review found them (each of these failed before its fix):
//! files changed while they are read, outputs that must not be replaced, counts and reads
//! without caps, errors that lost the output's name, processes killed mid-write. Every test
//! runs the real binaries (or the library where the case is deterministic only there) and
//! requires a clean error: exit status 1 with a message naming the file, never a signal, a
//! panic, a hang or a file left half-written.

use std::fs;
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use crate::common::*;
use oavm::{Hit, Ray, Scene};
use tempfile::TempDir;

fn bunny_ply() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/bunny.ply")
}

/// Runs `cmd` with no stdin.
fn go(cmd: &mut Command) -> (Output, String) {
    let (o, _, err) = run(cmd.stdin(Stdio::null()));
    (o, err)
}

/// A clean failure: exit status 1 (not a signal, not a panic's 101), stderr prefixed
/// `PROGRAM: error:` and containing `says`.
#[track_caller]
fn fails_with(o: &Output, err: &str, program: &str, says: &str) {
    assert_eq!(o.status.code(), Some(1), "{program}: {:?}\n{err}", o.status);
    assert!(err.starts_with(&format!("{program}: error: ")), "{err}");
    assert!(err.contains(says), "wanted {says:?} in: {err}");
    assert!(!err.contains("panicked"), "{err}");
}

/// The bunny packed into `dir/name`.
fn packed_bunny(dir: &Path, name: &str) -> PathBuf {
    let out = dir.join(name);
    pack(&bunny_ply(), &out, &[]);
    out
}

/// Names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

// ---------------------------------------------------------------------------------------------
// Files that change while they are read

/// A mapped file truncated after it was opened: every batch then reads zeros where the file
/// ended (no SIGBUS), and reports the change instead of its answers.
#[test]
fn a_file_truncated_under_a_scene_is_an_error_not_a_signal() {
    let dir = TempDir::new().unwrap();
    let file = packed_bunny(dir.path(), "bunny.oavm");
    let rays = oavm::rays::random_rays(&bounds(&load_shared("bunny/bun_zipper.ply")), 20_000, 3);
    for keep in [4096u64, 0] {
        let copy = dir.path().join(format!("t{keep}.oavm"));
        fs::copy(&file, &copy).unwrap();
        let scene = Scene::open(&copy).unwrap();
        let f = fs::OpenOptions::new().write(true).open(&copy).unwrap();
        f.set_len(keep).unwrap();
        let mut hits = vec![Hit::MISS; rays.len()];
        let e = scene
            .intersect_batch(&rays, &mut hits)
            .expect_err("a truncated file traces to an error")
            .to_string();
        assert!(e.contains("changed while it was being read"), "{e}");
        assert!(e.contains(&copy.display().to_string()), "{e}");
        let e = scene.verify().expect_err("and verifies to one").to_string();
        assert!(e.contains("changed while it was being read"), "{e}");
    }
}

/// A file rewritten in place with the same length (`cp -p`-like: even its size unchanged): the
/// change time tells that something wrote it. Written with the same bytes, the slot the reader
/// read still holds its header, so the file is what it opened (format-spec §2.1) and the batch
/// answers; written with another header (another pack of the same length), the batch is an
/// error.
#[test]
fn a_file_rewritten_in_place_is_an_error() {
    let dir = TempDir::new().unwrap();
    let file = packed_bunny(dir.path(), "bunny.oavm");
    let scene = Scene::open(&file).unwrap();
    let mut bytes = fs::read(&file).unwrap();
    let rays = [Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, f32::INFINITY)];
    let mut h = [Hit::MISS];
    std::thread::sleep(Duration::from_millis(20));
    fs::write(&file, &bytes).unwrap(); // the same bytes, written again
    scene
        .intersect_batch(&rays, &mut h)
        .expect("the same bytes: the reader's generation is intact");
    std::thread::sleep(Duration::from_millis(20));
    bytes[100] ^= 1; // a header field of slot 0 (and so its checksum) differs
    fs::write(&file, &bytes).unwrap();
    let e = scene
        .intersect_batch(&rays, &mut h)
        .unwrap_err()
        .to_string();
    assert!(e.contains("changed while it was being read"), "{e}");
}

/// Through the CLI: a long trace whose file is truncated, then one whose file is overwritten
/// by another (`cp other traced`), end with exit 1 and the message, never a signal (exit 135).
#[test]
fn the_tracer_reports_a_file_changed_under_it() {
    let dir = TempDir::new().unwrap();
    let dragon = dir.path().join("dragon.oavm");
    pack(&shared_scene("dragon/dragon_vrip_res2.ply"), &dragon, &[]);
    let other = packed_bunny(dir.path(), "bunny.oavm");
    for how in ["truncate", "overwrite"] {
        let traced = dir.path().join(format!("{how}.oavm"));
        fs::copy(&dragon, &traced).unwrap();
        let child = bin("oavm-trace")
            .arg(&traced)
            .args(["--random", "4000000", "--threads", "2"])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(400));
        match how {
            "truncate" => fs::OpenOptions::new()
                .write(true)
                .open(&traced)
                .unwrap()
                .set_len(4096)
                .unwrap(),
            _ => {
                fs::copy(&other, &traced).unwrap();
            }
        }
        let o = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        fails_with(&o, &err, "oavm-trace", "changed while it was being read");
    }
}

/// The streaming pack maps its PLY: truncated during the pack, it is an error, not a signal.
#[test]
fn the_streaming_pack_reports_its_ply_changed_under_it() {
    let dir = TempDir::new().unwrap();
    let dragon = load_shared("dragon/dragon_vrip.ply");
    let ply = dir.path().join("dragon.ply");
    fs::write(&ply, binary_ply(&dragon)).unwrap();
    let out = dir.path().join("out.oavm");
    let child = bin("oavm-pack")
        .arg(&ply)
        .arg(&out)
        .args(["--mem-budget", "64M", "--threads", "1"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Truncated as soon as the pack has mapped it (it reads it in several passes from then
    // on), not after a fixed delay: on a fast machine the passes were over within 300 ms,
    // after which the pack rightly builds from what it read.
    let maps = format!("/proc/{}/maps", child.id());
    let start = std::time::Instant::now();
    while !fs::read_to_string(&maps).is_ok_and(|m| m.contains("dragon.ply")) {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "the pack never mapped its PLY"
        );
        std::thread::sleep(Duration::from_micros(200));
    }
    fs::OpenOptions::new()
        .write(true)
        .open(&ply)
        .unwrap()
        .set_len(1000)
        .unwrap();
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    fails_with(&o, &err, "oavm-pack", "changed while it was being read");
    assert!(err.contains("dragon.ply"), "{err}");
    assert!(!out.exists());
}

// ---------------------------------------------------------------------------------------------
// Outputs

/// An output that is one of the inputs is refused before any work, and the input stays.
#[test]
fn an_output_that_is_an_input_is_refused() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let file = packed_bunny(d, "bunny.oavm");
    let rays = d.join("r.rays");
    oavm::rays::write_rays(&rays, &[Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, 1.0)]).unwrap();
    let before = (fs::read(&file).unwrap(), fs::read(&rays).unwrap());
    for (flag, target) in [("--hits", &file), ("--occluded", &file), ("--hits", &rays)] {
        let (o, err) = go(bin("oavm-trace")
            .arg(&file)
            .arg("--rays")
            .arg(&rays)
            .arg(flag)
            .arg(target));
        fails_with(&o, &err, "oavm-trace", "is the input");
    }
    let (o, err) = go(bin("oavm-trace").arg(&file).arg("-o").arg(&file));
    fails_with(&o, &err, "oavm-trace", "is the input");
    assert_eq!(before, (fs::read(&file).unwrap(), fs::read(&rays).unwrap()));
    // `oavm-pack m.ply m.ply`, and the same file under another name.
    let ply = d.join("m.ply");
    fs::copy(bunny_ply(), &ply).unwrap();
    let alias = d.join("alias.ply");
    fs::hard_link(&ply, &alias).unwrap();
    for out in [&ply, &alias] {
        let (o, err) = go(bin("oavm-pack").arg(&ply).arg(out));
        fails_with(&o, &err, "oavm-pack", "is the input");
    }
    assert_eq!(fs::read(&ply).unwrap(), fs::read(bunny_ply()).unwrap());
}

/// A symlink given as the output is written through (the link stays, its target changes);
/// a FIFO, a device or a directory is never replaced nor written into.
#[test]
fn symlinks_are_written_through_and_special_files_never_replaced() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let file = packed_bunny(d, "bunny.oavm");
    // Pack and render through symlinks.
    let target = d.join("real.oavm");
    let link = d.join("link.oavm");
    std::os::unix::fs::symlink("real.oavm", &link).unwrap();
    pack(&bunny_ply(), &link, &["--max-depth", "4"]);
    assert!(fs::symlink_metadata(&link).unwrap().is_symlink());
    assert!(Scene::open(&target).is_ok());
    // A FIFO and a device node of our own (never a real device).
    let fifo = d.join("fifo");
    assert!(
        Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let node = d.join("null-node");
    let mknod = Command::new("mknod")
        .arg(&node)
        .args(["c", "1", "3"])
        .status()
        .unwrap();
    let mut special = vec![(fifo.clone(), "a FIFO"), (d.to_path_buf(), "a directory")];
    if mknod.success() {
        special.push((node.clone(), "a device"));
    }
    let rays = d.join("r.rays");
    oavm::rays::write_rays(&rays, &[Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, 1.0)]).unwrap();
    for (path, kind) in &special {
        let (o, err) = go(bin("oavm-pack").arg(bunny_ply()).arg(path));
        fails_with(&o, &err, "oavm-pack", kind);
        let (o, err) = go(bin("oavm-trace")
            .arg(&file)
            .arg("--rays")
            .arg(&rays)
            .arg("--hits")
            .arg(path));
        fails_with(&o, &err, "oavm-trace", kind);
    }
    assert!(fs::metadata(&fifo).unwrap().file_type().is_fifo());
    if mknod.success() {
        assert!(fs::metadata(&node).unwrap().file_type().is_char_device());
    }
}

/// A bad output path fails before the work: the output is checked before the rays are even
/// read (here the ray file is broken too, and the error is the output's).
#[test]
fn a_bad_output_path_fails_before_the_work() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let file = packed_bunny(d, "bunny.oavm");
    let bad_rays = d.join("bad.rays");
    fs::write(&bad_rays, b"RAYS\x01\0\0\0\xff\xff\xff\xff\0\0\0\0").unwrap();
    let nowhere = d.join("no/such/dir/out.hits");
    let (o, err) = go(bin("oavm-trace")
        .arg(&file)
        .arg("--rays")
        .arg(&bad_rays)
        .arg("--hits")
        .arg(&nowhere));
    fails_with(&o, &err, "oavm-trace", "no/such/dir/out.hits");
    // The pack checks its output before it parses the mesh (a bad mesh, a bad output: the
    // output's error).
    let bad_mesh = d.join("bad.ply");
    fs::write(
        &bad_mesh,
        b"ply\nformat ascii 1.0\nelement vertex 99999\nend_header\n",
    )
    .unwrap();
    let t = Instant::now();
    let (o, err) = go(bin("oavm-pack").arg(&bad_mesh).arg(d.join("no/dir/x.oavm")));
    fails_with(&o, &err, "oavm-pack", "no/dir/x.oavm");
    assert!(t.elapsed() < Duration::from_secs(30));
}

/// A process killed while it writes leaves nothing: the new file has no name until it is
/// complete.
#[test]
fn a_killed_pack_leaves_nothing_behind() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let before = names(d);
    let mut child = bin("oavm-pack")
        .arg(shared_scene("dragon/dragon_vrip.ply"))
        .arg(d.join("dragon.oavm"))
        .args(["--threads", "1"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(700));
    child.kill().unwrap(); // SIGKILL
    let status = child.wait().unwrap();
    assert!(!status.success());
    assert_eq!(names(d), before, "a killed pack left files");
}

/// A write error (here the file size limit, `ulimit -f`) names the output, not only the OS
/// error.
#[test]
fn a_write_error_names_the_output() {
    let dir = TempDir::new().unwrap();
    let out = dir.path().join("big.oavm");
    let script = format!(
        "ulimit -f 64; trap '' XFSZ; exec {} {} {}",
        env!("CARGO_BIN_EXE_oavm-pack"),
        bunny_ply().display(),
        out.display()
    );
    let (o, err) = go(Command::new("sh").arg("-c").arg(&script));
    fails_with(&o, &err, "oavm-pack", &out.display().to_string());
    assert!(!out.exists());
}

// ---------------------------------------------------------------------------------------------
// Caps on counts and reads

/// Ray counts beyond what memory holds are an error, not a panic or an abort; a flag that does
/// not belong to the mode is refused, not ignored.
#[test]
fn ray_counts_and_mode_flags_are_checked() {
    let dir = TempDir::new().unwrap();
    let file = packed_bunny(dir.path(), "bunny.oavm");
    for n in ["18446744073709551615", "1000000000000"] {
        let (o, err) = go(bin("oavm-trace").arg(&file).args(["--random", n]));
        fails_with(&o, &err, "oavm-trace", "rays: at most");
    }
    // `--hits` without `--rays`: a usage error (exit 2), and no file.
    let hits = dir.path().join("x.hits");
    let (o, err) = go(bin("oavm-trace")
        .arg(&file)
        .args(["--random", "10", "--hits"])
        .arg(&hits));
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("--rays"), "{err}");
    assert!(!hits.exists());
}

/// A ray file whose header claims more rays than memory holds is refused before it is read,
/// whatever its size on disk (a sparse file of 64 GiB here).
#[test]
fn a_huge_ray_file_is_refused_before_it_is_read() {
    let dir = TempDir::new().unwrap();
    let file = packed_bunny(dir.path(), "bunny.oavm");
    let rays = dir.path().join("huge.rays");
    let count: u64 = 2 << 30; // 2^31 rays of 32 bytes: 64 GiB
    let mut head = b"RAYS\x01\0\0\0".to_vec();
    head.extend_from_slice(&count.to_le_bytes());
    fs::write(&rays, &head).unwrap();
    fs::OpenOptions::new()
        .write(true)
        .open(&rays)
        .unwrap()
        .set_len(16 + count * 32)
        .unwrap();
    let t = Instant::now();
    let (o, err) = go(bin("oavm-trace")
        .arg(&file)
        .arg("--rays")
        .arg(&rays)
        .arg("--hits")
        .arg(dir.path().join("x.hits")));
    fails_with(&o, &err, "oavm-trace", "more than the");
    assert!(t.elapsed() < Duration::from_secs(20), "it read the file");
}
