//! `oavm-update FILE.oavm MESH`: brings a packed file to new geometry in place, rebuilding only
//! what changed, as a new generation of the file (format-spec §2.1).

mod cli;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use oavm::pack::update::{CompactReport, UpdateOptions, UpdateReport, Updater, compact};

/// Updates an .oavm file packed with `oavm-pack --updatable` to the triangles of MESH (the same
/// primitive-id space: triangle i of the mesh is primitive i; a BART scene posed at --time),
/// touching only the subtrees whose triangles changed. The update is written as a new
/// generation: a crash at any moment leaves the previous or the new one, and readers that
/// opened the previous one keep reading it.
#[derive(Parser, Debug)]
#[command(name = "oavm-update", version)]
struct Args {
    /// The .oavm file to update (packed with --updatable).
    file: PathBuf,
    /// The new geometry: .ply, .obj, or .aff (posed at --time). Optional with --compact.
    #[arg(required_unless_present = "compact")]
    mesh: Option<PathBuf>,
    /// Rewrite the file without what older generations left (after the update, if MESH is
    /// given): a file of generation 1 replaces it atomically; readers of the old one keep it.
    #[arg(long)]
    compact: bool,
    /// Pose an animated .aff scene at this time.
    #[arg(long)]
    time: Option<f64>,
    /// Target raw size of the blocks the update writes, bytes.
    #[arg(long, default_value_t = oavm::physical::DEFAULT_BLOCK_SIZE)]
    block_size: u64,
    /// Store new blocks zstd-compressed at this level [default: level 3 if the file has
    /// compressed blocks, else raw].
    #[arg(long)]
    compress: Option<i32>,
    /// Store new blocks raw, whatever the file holds.
    #[arg(long, conflicts_with = "compress")]
    raw: bool,
    /// Print the report as one JSON object.
    #[arg(long)]
    json: bool,
    /// Worker threads (0: one per core). The file written is the same for any count.
    #[arg(long, default_value_t = 0)]
    threads: usize,
}

fn main() -> ExitCode {
    let args = Args::parse();
    cli::main_with("oavm-update", || {
        let opts = UpdateOptions {
            block_size: args.block_size,
            compress: if args.raw {
                Some(None)
            } else {
                args.compress.map(Some)
            },
        };
        opts.validate()?;
        let report = cli::with_threads(args.threads, || {
            let update = match &args.mesh {
                Some(mesh_path) => {
                    let mut u = Updater::open(&args.file)?;
                    let mesh = oavm::mesh::load_at(mesh_path, args.time)?;
                    u.set_mesh(&mesh)?;
                    drop(mesh);
                    Some(u.commit(&opts)?)
                }
                None => None,
            };
            let compacted = match args.compact {
                true => Some(compact(&args.file, &args.file)?),
                false => None,
            };
            Ok(Report { update, compacted })
        })?;
        if args.json {
            cli::print_json(&report)
        } else {
            let mut t = report.update.as_ref().map(human).unwrap_or_default();
            if let Some(c) = &report.compacted {
                t += &human_compact(c);
            }
            cli::print_text(&t)
        }
    })
}

/// What `oavm-update` did.
#[derive(serde::Serialize)]
struct Report {
    #[serde(skip_serializing_if = "Option::is_none")]
    update: Option<UpdateReport>,
    #[serde(skip_serializing_if = "Option::is_none")]
    compacted: Option<CompactReport>,
}

fn human_compact(c: &CompactReport) -> String {
    format!(
        "{:<22} {} (generation {} -> 1): {} -> {} bytes, {} blocks, {} free entries dropped, {:.3} s\n",
        "compacted",
        c.file,
        c.generation,
        c.bytes_before,
        c.bytes_after,
        c.blocks,
        c.free_entries,
        c.seconds
    )
}

fn human(r: &UpdateReport) -> String {
    let mut t = String::new();
    let mut line = |k: &str, v: String| t.push_str(&format!("{k:<22} {v}\n"));
    line(
        "file",
        format!(
            "{} (generation {} -> {}, {} bytes)",
            r.file, r.previous_generation, r.generation, r.file_bytes
        ),
    );
    line(
        "primitives",
        format!(
            "{} moved, {} inserted, {} removed",
            r.moved, r.inserted, r.removed
        ),
    );
    line(
        "blocks",
        format!(
            "{} of {} rebuilt, {} written, {} after",
            r.blocks_rebuilt, r.blocks_before, r.blocks_written, r.blocks_after
        ),
    );
    line(
        "subtrees",
        format!(
            "{} rebuilt ({} empty top-tree leaves filled); leaves {} -> {}, {} volumes",
            r.subtrees_rebuilt,
            r.empty_leaves_filled,
            r.leaves_before,
            r.leaves_after,
            r.volumes_after
        ),
    );
    line(
        "top tree",
        format!(
            "{} -> {} empty leaves, merged again",
            r.top_empty_before, r.top_empty_after
        ),
    );
    line(
        "written",
        format!(
            "{} bytes ({} primitive chunks)",
            r.bytes_written, r.prim_chunks_written
        ),
    );
    line(
        "time",
        format!(
            "diff {:.3} s, build {:.3} s, write {:.3} s; total {:.3} s",
            r.diff_seconds, r.build_seconds, r.write_seconds, r.total_seconds
        ),
    );
    t
}
