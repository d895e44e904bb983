//! `oavm-inspect FILE.oavm`: shows what a packed file holds (header, sections, the top tree's
//! levels, a file of clusters' wide nodes, the block directory; with `--blocks` every block,
//! with `--levels` the whole tree's nodes per level and the blocks' wide nodes) and, with
//! `--verify`, checks every byte of it. Glue over
//! `oavm::physical::inspect`.

mod cli;

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use oavm::physical::{InspectOptions, Inspection, inspect};
use oavm::{Error, Scene};

/// Shows the structure of an .oavm file (format-spec.md): header, sections, top tree, block
/// directory; opening reads no block unless --levels or --verify asks.
#[derive(Parser, Debug)]
#[command(name = "oavm-inspect", version)]
struct Args {
    /// The .oavm file.
    file: PathBuf,
    /// List every block's directory entry.
    #[arg(long)]
    blocks: bool,
    /// Count the whole tree's nodes per level, and the blocks' wide nodes (reads and decodes
    /// every block).
    #[arg(long)]
    levels: bool,
    /// Also check every section, checksum and invariant; exit non-zero on any defect.
    #[arg(long)]
    verify: bool,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    cli::main_with("oavm-inspect", || run(&args))
}

fn run(args: &Args) -> Result<(), Error> {
    let scene = Scene::open(&args.file)?;
    let inspection = inspect(
        scene.file(),
        InspectOptions {
            blocks: args.blocks,
            levels: args.levels,
        },
    );
    let verify = match args.verify {
        true => Some(scene.verify()?),
        false => None,
    };
    scene.check_unchanged()?;
    if args.json {
        #[derive(serde::Serialize)]
        struct Out<'a> {
            file: &'a std::path::Path,
            #[serde(flatten)]
            inspection: &'a Inspection,
            #[serde(skip_serializing_if = "Option::is_none")]
            verify: Option<&'a oavm::logical::VerifyReport>,
        }
        cli::print_json(&Out {
            file: &args.file,
            inspection: &inspection,
            verify: verify.as_ref(),
        })?;
    } else {
        cli::print_text(&text(args, &inspection))?;
    }
    match verify {
        Some(r) if !r.is_ok() => {
            for d in &r.defects {
                eprintln!("oavm-inspect: {}: {d}", args.file.display());
            }
            Err(Error::Invalid(format!(
                "{}: verification failed ({} defects)",
                args.file.display(),
                r.defects.len()
            )))
        }
        Some(_) if !args.json => {
            cli::print_text("verify: ok (every checksum and invariant holds)\n")
        }
        _ => Ok(()),
    }
}

/// The human-readable report: the header, the sections, the top tree, the blocks and, with
/// --levels, the whole tree.
fn text(args: &Args, i: &Inspection) -> String {
    let mut t = String::new();
    header(&mut t, args, i);
    sections(&mut t, i);
    top_tree(&mut t, i);
    wide(&mut t, i);
    geometries(&mut t, i);
    blocks(&mut t, i);
    whole_tree(&mut t, i);
    t
}

/// Whether the file holds clusters: a block's `triangles` then count group lanes, not triangle
/// records (spec §8.2).
fn clusters(i: &Inspection) -> bool {
    i.header.flags & oavm::physical::format::FLAG_CLUSTERS != 0
}

/// The header: the file, its format, the root cube, the mesh, the tree.
fn header(t: &mut String, args: &Args, i: &Inspection) {
    let h = &i.header;
    let mut line = |k: &str, v: String| {
        let _ = writeln!(t, "{k:<20} {v}");
    };
    line(
        "file",
        format!("{} ({} bytes)", args.file.display(), h.file_size),
    );
    line(
        "format",
        format!(
            "version {}, flags {:#x} [{}]",
            h.version,
            h.flags,
            i.flags.join(", ")
        ),
    );
    line(
        "root cube",
        format!("min {:?}, edge {}", h.root_min, h.root_size),
    );
    line(
        "mesh bounds",
        format!("{:?} .. {:?}", h.mesh_min, h.mesh_max),
    );
    line(
        "triangles",
        format!(
            "{} input, {} stored, {} {} in blocks",
            h.input_triangles,
            h.stored_triangles,
            h.block_triangles,
            if clusters(i) {
                "group lanes"
            } else {
                "records"
            }
        ),
    );
    line(
        "tree",
        format!(
            "{} levels (max depth {}, leaf size {}), {} solid and {} empty leaves",
            h.level_count, h.max_depth, h.leaf_size, h.solid_leaves, h.empty_leaves
        ),
    );
}

/// Every section's place, size and checksum.
fn sections(t: &mut String, i: &Inspection) {
    let _ = writeln!(t, "\nsections:");
    for s in &i.sections {
        let e = &s.entry;
        let _ = writeln!(
            t,
            "  {:<16} offset {:>12}  {:>12} bytes  {:>10} records  xxh3 {:#018x}",
            s.name, e.offset, e.length, e.count, e.checksum
        );
    }
}

/// The top tree's nodes per level.
fn top_tree(t: &mut String, i: &Inspection) {
    let _ = writeln!(t, "\ntop tree:");
    for l in &i.top_levels {
        let _ = writeln!(
            t,
            "  level {:>2}: {:>9} nodes ({} internal, {} empty, {} links{})",
            l.level,
            l.nodes,
            l.internal,
            l.empty,
            l.links,
            if l.invalid > 0 {
                format!(", {} invalid", l.invalid)
            } else {
                String::new()
            }
        );
    }
}

/// A file of clusters' wide nodes (format-spec §8.7): the top tree's, and with --levels the
/// blocks', the octree's apart from the clusters'.
fn wide(t: &mut String, i: &Inspection) {
    let Some(w) = &i.wide else { return };
    let _ = writeln!(
        t,
        "\nwide nodes: {} in the top tree, {} wide links",
        w.top_nodes, w.links
    );
    if let Some(b) = &w.blocks {
        let _ = writeln!(
            t,
            "  in blocks: {} of the octree, {} of clusters ({} cluster roots)",
            b.octree_nodes, b.cluster_nodes, b.cluster_roots
        );
    }
}

/// The geometry table (format-spec §8.8): each geometry's primitives, name and placement
/// (the first 64; `--json` has them all).
fn geometries(t: &mut String, i: &Inspection) {
    const SHOWN: usize = 64;
    match &i.geometries {
        None => {}
        Some(Err(e)) => {
            let _ = writeln!(t, "\ngeometries: unreadable: {e}");
        }
        Some(Ok(g)) => {
            let _ = writeln!(t, "\ngeometries: {}", g.len());
            for (id, g) in g.iter().enumerate().take(SHOWN) {
                let m = g.transform;
                let placed = match m == oavm::mesh::Geometry::IDENTITY {
                    true => String::new(),
                    false => format!(", moved by [{}, {}, {}]", m[0][3], m[1][3], m[2][3]),
                };
                let r = g.primitives();
                let _ = writeln!(
                    t,
                    "  {id:>5}  primitives {:>10} .. {:<10} {:?}{placed}",
                    r.start, r.end, g.name
                );
            }
            if g.len() > SHOWN {
                let _ = writeln!(t, "  ... {} more (--json lists them all)", g.len() - SHOWN);
            }
        }
    }
}

/// The block directory's totals, its roots per level and, with --blocks, every block.
fn blocks(t: &mut String, i: &Inspection) {
    let d = &i.directory;
    let _ = writeln!(
        t,
        "\nblocks: {} ({} raw, {} zstd{}), {} bytes stored, {} decoded (largest {}, smallest {}), {} {}",
        d.blocks,
        d.raw_blocks,
        d.zstd_blocks,
        match d.lean_blocks {
            0 => String::new(),
            n => format!(", {n} lean"),
        },
        d.stored_bytes,
        d.decoded_bytes,
        d.largest_decoded,
        d.smallest_decoded,
        d.triangle_records,
        // Spec §8.2: what a block's `triangles` count.
        if clusters(i) {
            "group lanes"
        } else {
            "triangle records"
        }
    );
    if d.chunks > 0 {
        let _ = writeln!(
            t,
            "  heads {} bytes stored, {} decoded; groups in {} chunks of {} groups",
            d.head_stored_bytes, d.head_decoded_bytes, d.chunks, d.chunk_groups
        );
    }
    for (level, n) in &d.root_levels {
        let _ = writeln!(t, "  roots at level {level:>2}: {n} blocks");
    }
    let Some(blocks) = &i.blocks else { return };
    let _ = writeln!(
        t,
        "\n  {:>8} {:>14} {:>10} {:>10} {:>5} {:>5} {:>6} {:>8}",
        "block", "offset", "stored", "decoded", "codec", "level", "roots", "tris"
    );
    for (b, e) in blocks.iter().enumerate() {
        let _ = writeln!(
            t,
            "  {b:>8} {:>14} {:>10} {:>10} {:>5} {:>5} {:>6} {:>8}",
            e.offset,
            e.stored_len,
            e.raw_len,
            match e.codec {
                oavm::physical::format::CODEC_RAW => "raw",
                oavm::physical::format::CODEC_ZSTD => "zstd",
                oavm::physical::format::CODEC_LEAN => "lean",
                _ => "?",
            },
            e.root_level,
            e.root_count,
            e.triangles
        );
    }
}

/// With --levels, the whole tree's nodes per level.
fn whole_tree(t: &mut String, i: &Inspection) {
    let Some(levels) = &i.tree_levels else { return };
    let _ = writeln!(t, "\nwhole tree:");
    for l in levels {
        let _ = writeln!(
            t,
            "  level {:>2}: {:>10} nodes ({} internal, {} solid, {} empty)",
            l.level, l.nodes, l.internal, l.solid, l.empty
        );
    }
}
