//! BART AFF scenes: the three real scenes' counts, animation, and bad input.

use std::path::{Path, PathBuf};

use oavm::mesh::{AffScene, load_aff};

fn bart(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/scenes/bart")
        .join(rel)
}

fn scene(rel: &str, time: Option<f64>) -> Option<AffScene> {
    let p = bart(rel);
    if !p.exists() {
        eprintln!("skipping: {} is not here", p.display());
        return None;
    }
    Some(load_aff(&p, time).unwrap_or_else(|e| panic!("{e}")))
}

#[test]
fn kitchen_counts() {
    let Some(s) = scene("kitchen/kitchen.aff", None) else {
        return;
    };
    eprintln!(
        "{:?} tris {} verts {}",
        s.counts,
        s.mesh.triangles.len(),
        s.mesh.positions.len()
    );
    assert_eq!(s.faces(), 110_561);
}

#[test]
fn robots_counts() {
    let Some(s) = scene("robot/Robot.aff", None) else {
        return;
    };
    eprintln!(
        "{:?} tris {} verts {}",
        s.counts,
        s.mesh.triangles.len(),
        s.mesh.positions.len()
    );
    assert_eq!(s.faces(), 71_708);
}

#[test]
fn museum_counts() {
    let Some(s) = scene("museum/museum5.aff", None) else {
        return;
    };
    eprintln!(
        "{:?} tris {} verts {}",
        s.counts,
        s.mesh.triangles.len(),
        s.mesh.positions.len()
    );
    assert_eq!(s.faces(), 10_143);
    assert_eq!(s.counts.animated_triangles, 1_024);
}
