//! What the binaries share: running `main` with errors printed once with their whole chain, the
//! progress bar, the thread pool, argument groups and value parsers. Only the binaries use
//! clap; the library parses no arguments, and draws only through `oavm::pack::bar` (feature
//! `progress`), which the binaries and the Python bindings share.

// Each binary includes this module and uses part of it.
#![allow(dead_code)]

use oavm::Error;
use oavm::logical::{IO_THREADS_PER_CORE, Order, SceneOptions};
use oavm::render::ShotSpec;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

/// Runs `run`, printing an error (and its sources) prefixed by the program name; exit status 1
/// on an error. A broken pipe on stdout is not an error.
pub fn main_with(program: &str, run: impl FnOnce() -> Result<(), Error>) -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(Error::Io { source, .. }) if source.kind() == std::io::ErrorKind::BrokenPipe => {
            ExitCode::SUCCESS
        }
        Err(e) => {
            let mut msg = format!("{program}: error: {e}");
            for cause in e.causes() {
                msg.push_str(&format!("\n  caused by: {cause}"));
            }
            eprintln!("{msg}");
            ExitCode::FAILURE
        }
    }
}

/// Prints `text` to stdout.
pub fn print_text(text: &str) -> Result<(), Error> {
    std::io::stdout()
        .lock()
        .write_all(text.as_bytes())
        .map_err(|e| Error::io("stdout", e))
}

/// Prints `value` as pretty JSON, one object.
pub fn print_json(value: &impl serde::Serialize) -> Result<(), Error> {
    let text = serde_json::to_string_pretty(value)
        .map_err(|e| Error::Invalid(format!("cannot write the report as JSON: {e}")))?;
    print_text(&(text + "\n"))
}

/// Runs `f` on a rayon pool of `threads` threads (0: one per core).
pub fn with_threads<T: Send>(
    threads: usize,
    f: impl FnOnce() -> Result<T, Error> + Send,
) -> Result<T, Error> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::Invalid(format!("cannot start {threads} threads: {e}")))?;
    pool.install(f)
}

/// The progress bar of long runs, drawn on stderr when it is a terminal.
pub fn progress_bar() -> oavm::progress::Bar {
    oavm::progress::Bar::new(std::io::IsTerminal::is_terminal(&std::io::stderr()))
}

/// The cores of this machine.
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// How a file is traced: memory, threads, order, checks. Shared by every mode of `oavm-trace`.
#[derive(clap::Args, Debug)]
pub struct TraceArgs {
    /// Bytes of decoded blocks kept in memory (e.g. 512M, 1.5G). Default: half of the memory
    /// available at start (MemAvailable, or what the memory cgroup has left). The decoded
    /// blocks held never exceed it, and it is never raised: a budget that cannot hold two of
    /// the file's largest blocks per thread and one more lowers the threads, and one that
    /// cannot hold three is an error that says what the file needs.
    #[arg(long, value_name = "SIZE", value_parser = parse_bytes)]
    pub mem_budget: Option<u64>,
    /// Do not check a raw block's checksum when it is paged in: only the pages a walk touches
    /// are read (far less from the disk when rays pass through blocks), but a damaged block is
    /// no longer caught by its checksum (reads stay bounds-checked: wrong answers, never a
    /// crash). `--verify` checks everything regardless.
    #[arg(long)]
    pub no_block_checks: bool,
    /// How blocks are read under a budget smaller than the file: `read` (into the tracer's
    /// own memory, one direct read a block past the page cache: far less time in the kernel,
    /// nothing left in the page cache), `map` (through the file's memory map: pages faulted
    /// in and dropped on eviction, the page cache keeps what it can for the next run) or
    /// `auto` (read when the file is larger than the memory available, else map).
    #[arg(long, value_enum, default_value_t = BlockReadsArg::Auto)]
    pub block_reads: BlockReadsArg,
    /// Which walk traces the rays: `wide` (one loop over the 8-wide nodes from the root to
    /// the triangle groups, format-spec §8.7; files of clusters), `topdown` (the octree's
    /// records and the clusters, nearest child first with a stack), `neighbours` (the OAVM paper's walk, leaf to leaf across
    /// merged volumes, each next leaf found from its cell's Morton code), `ropes` (the same,
    /// each next leaf found from the rope of the face left; a file packed with `--ropes`) or
    /// `auto` (wide for a file of clusters, else neighbours). The answers are the same.
    #[arg(long, value_enum, default_value_t = WalkArg::Auto)]
    pub walk: WalkArg,
    /// Under a budget smaller than the file's blocks, read a file that stores its groups in
    /// chunks (format 7) head by head and chunk by chunk: the pager holds the blocks' heads
    /// (their wide nodes), and only the chunks of groups rays reach are read (in stream order,
    /// the default, the chunks rays wait for are read together). Off by default: it reads
    /// a half to a quarter of the bytes of whole blocks, but on the disks measured takes as
    /// long.
    #[arg(long)]
    pub chunks: bool,
    /// Order of tracing: stream (each ray walked while its blocks are resident, and parked at
    /// every block it needs that is not, resumed when that block is served with all the walks
    /// parked there; blocks read ahead in file order; a frame's shadow rays in the same stream;
    /// under a budget that holds the file, none), morton (rays that enter the model near
    /// each other, in the same direction octant, together; image tiles in Morton order),
    /// blocks (rays binned by the first block they need, found in the top tree, then as
    /// morton) or none (as given; image tiles row by row). The answers are the same; the
    /// blocks read again under a small budget are not. Default: stream when the budget is
    /// smaller than the file's decoded blocks, none otherwise (in memory, a stream or a sort
    /// costs more than it buys).
    #[arg(long, value_parser = parse_order)]
    pub order: Option<Order>,
    /// Worker threads. Default: one per core, or eight per core when the budget is smaller
    /// than the file's decoded blocks (some threads trace while others wait for the disk), as
    /// long as the block each thread reads takes at most a quarter of the budget; lowered to
    /// what the budget holds.
    #[arg(long)]
    pub threads: Option<usize>,
}

/// When the rayon pool a file is traced on is sized, which decides what
/// [`SceneOptions::threads`] means ([`TraceArgs::scene_options`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pool {
    /// After the scene is opened, from what its budget holds (`--threads` lowered to
    /// [`oavm::Scene::threads`], else [`oavm::Scene::default_threads`]), as the tracing modes
    /// (render, batch, benchmark) do. The scene is opened for the most threads that may then
    /// trace, so that the pager keeps a block's room for each: `--threads`, else
    /// [`IO_THREADS_PER_CORE`] per core, the most `default_threads` chooses.
    AfterOpen,
    /// Before any scene is opened, as `--frames` does (the library opens a scene per frame and
    /// renders it on the pool it is given): the pool is `--threads` (at least one), else one
    /// per core, and each scene is opened for as many.
    BeforeOpen,
}

impl TraceArgs {
    /// How the file is opened: the memory budget, block checks, block reads and walk asked for,
    /// and the threads of `pool`'s rule.
    pub fn scene_options(&self, pool: Pool) -> SceneOptions {
        SceneOptions {
            mem_budget: self.mem_budget,
            threads: match pool {
                Pool::AfterOpen => self.threads.unwrap_or(cores() * IO_THREADS_PER_CORE),
                Pool::BeforeOpen => self.threads.unwrap_or_else(cores).max(1),
            },
            check_blocks: !self.no_block_checks,
            block_reads: self.block_reads.into(),
            walk: self.walk.into(),
            chunks: self.chunks,
        }
    }

    /// The pool's threads once `scene` is opened with [`Pool::AfterOpen`]'s options:
    /// `--threads`, lowered to what the budget holds (with a note on stderr, `program` naming
    /// who writes it), else the scene's default for this machine's cores.
    pub fn threads_after_open(&self, scene: &oavm::Scene, program: &str) -> usize {
        match self.threads {
            Some(n) if n > scene.threads() => {
                eprintln!(
                    "{program}: note: --threads {n} lowered to {}: a memory budget of {} bytes \
                     holds two of this file's largest blocks ({} bytes) per thread and one more",
                    scene.threads(),
                    scene.budget(),
                    scene.file().header().max_block_raw_len
                );
                scene.threads()
            }
            Some(n) => n.max(1),
            None => scene.default_threads(cores()),
        }
    }
}

/// `--block-reads`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlockReadsArg {
    Auto,
    Map,
    Read,
}

impl From<BlockReadsArg> for oavm::logical::BlockReads {
    fn from(a: BlockReadsArg) -> Self {
        match a {
            BlockReadsArg::Auto => Self::Auto,
            BlockReadsArg::Map => Self::Map,
            BlockReadsArg::Read => Self::Read,
        }
    }
}

/// `--walk`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum WalkArg {
    Auto,
    Wide,
    Topdown,
    Neighbours,
    Ropes,
}

impl From<WalkArg> for oavm::logical::Walk {
    fn from(a: WalkArg) -> Self {
        match a {
            WalkArg::Auto => Self::Auto,
            WalkArg::Wide => Self::Wide,
            WalkArg::Topdown => Self::TopDown,
            WalkArg::Neighbours => Self::Neighbours,
            WalkArg::Ropes => Self::Ropes,
        }
    }
}

/// The camera and light of renders and of `--primary`.
#[derive(clap::Args, Debug)]
pub struct CameraArgs {
    /// Take the camera from this BART AFF scene's viewpoint (`v`: from, at, up, and angle as the
    /// vertical field of view) and the light from its first light (`l`), or the viewpoint
    /// without one; the image size is the scene's resolution unless --width/--height are given.
    #[arg(long, value_name = "SCENE.aff", conflicts_with_all = ["eye", "target", "fov", "up"])]
    pub view: Option<PathBuf>,
    /// With --view: take the camera from the scene's animated camera path (`k camera`) at its
    /// first frame instead of its `v` block (BART's own animation frame).
    #[arg(long, requires = "view")]
    pub camera_path: bool,
    /// Camera position (default: in front of the model, framing it).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3)]
    pub eye: Option<[f64; 3]>,
    /// Point the camera looks at (default: the model's centre).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3)]
    pub target: Option<[f64; 3]>,
    /// Camera up vector (default 0,1,0).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3)]
    pub up: Option<[f64; 3]>,
    /// Vertical field of view in degrees (default 40).
    #[arg(long)]
    pub fov: Option<f64>,
    /// Point light position (default: the --view scene's first light, else above, right and
    /// in front of the model).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3)]
    pub light: Option<[f64; 3]>,
}

impl CameraArgs {
    /// The shot these options ask for, the view scene posed at `time`, the image `width` x
    /// `height` (each `None`: the view scene's resolution, or the default).
    pub fn spec(&self, time: Option<f64>, width: Option<u32>, height: Option<u32>) -> ShotSpec {
        ShotSpec {
            view: self.view.clone(),
            time,
            camera_path: self.camera_path,
            eye: self.eye,
            target: self.target,
            up: self.up,
            fov: self.fov,
            light: self.light,
            width,
            height,
        }
    }
}

/// Parses a byte size: a number with an optional binary unit, `K`, `M`, `G` or `T` (powers of
/// 1024; `KiB`, `MB`... are read the same, case-insensitive), e.g. `512M`, `1.5G`, `4096`.
pub fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let value: f64 = num
        .parse()
        .map_err(|_| format!("`{s}` is not a size (examples: 512M, 1.5G, 4096)"))?;
    let unit = unit.trim().to_ascii_lowercase();
    let unit = unit.trim_end_matches("ib").trim_end_matches('b');
    let scale: f64 = match unit {
        "" => 1.0,
        "k" => 1024.0,
        "m" => 1024.0 * 1024.0,
        "g" => 1024.0 * 1024.0 * 1024.0,
        "t" => 1024.0 * 1024.0 * 1024.0 * 1024.0,
        _ => return Err(format!("`{s}`: unknown unit (use K, M, G or T)")),
    };
    let bytes = value * scale;
    if !bytes.is_finite() || bytes < 0.0 || bytes >= u64::MAX as f64 {
        return Err(format!("`{s}` is out of range"));
    }
    Ok(bytes.round() as u64)
}

/// Parses `X,Y,Z` (three finite numbers).
pub fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("{p:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err(format!("expected three finite numbers X,Y,Z, got {s:?}")),
    }
}

/// Parses `WIDTHxHEIGHT`, each 1 to 16384.
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got {s:?}"))?;
    let dim = |v: &str| match v.trim().parse::<u32>() {
        Ok(n) if (1..=16384).contains(&n) => Ok(n),
        _ => Err(format!("{s:?}: sizes are 1 to 16384 pixels")),
    };
    Ok((dim(w)?, dim(h)?))
}

pub fn parse_order(s: &str) -> Result<Order, String> {
    s.parse()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes() {
        assert_eq!(parse_bytes("4096"), Ok(4096));
        assert_eq!(parse_bytes("512M"), Ok(512 << 20));
        assert_eq!(parse_bytes("1.5G"), Ok(3 << 29));
        assert_eq!(parse_bytes("4GiB"), Ok(4 << 30));
        assert_eq!(parse_bytes("256k"), Ok(256 << 10));
        assert!(parse_bytes("12X").is_err());
        assert!(parse_bytes("G").is_err());
        assert!(parse_bytes("-1").is_err());
        assert_eq!(parse_size("640x480"), Ok((640, 480)));
        assert!(parse_size("0x480").is_err());
        assert!(parse_vec3("1,2").is_err());
        assert!(parse_vec3("1,2,inf").is_err());
    }
}

/// `--leaf`: what a solid leaf holds (`oavm::pack::LeafKind`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LeafArg {
    Cluster,
    List,
}

impl LeafArg {
    pub fn kind(self) -> oavm::pack::LeafKind {
        match self {
            LeafArg::Cluster => oavm::pack::LeafKind::Cluster,
            LeafArg::List => oavm::pack::LeafKind::List,
        }
    }
}
