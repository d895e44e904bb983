//! glTF 2.0, as `.gltf` (JSON, its buffers in `.bin` files beside it or in `data:` URIs) or
//! `.glb` (one binary file). The `gltf` crate's JSON types (`gltf::json`, serde) read the
//! document; everything else is done here with every index and range checked: its document
//! wrapper and validation index arrays unchecked (gltf-json 1.4.1 panics on a POSITION accessor
//! index past the accessors, and its GLB reader subtracts before checking a length), so they
//! are not used. Every accessor is checked against the bytes it reads before any is read, so a
//! count or an offset cannot make us read past a buffer or allocate beyond what the file backs.
//!
//! **What is read.** The default scene (else the first; a file without scenes: every node that
//! is no node's child), its nodes depth first, children in order, each node's mesh with the
//! node's world transform (its `matrix`, or translation, rotation and scale, times its
//! parents') baked into the positions, in f64 then rounded to f32. Of each mesh, its primitives
//! in order: `TRIANGLES`, `TRIANGLE_STRIP` and `TRIANGLE_FAN` (the spec's vertex order for
//! each), with or without indices; points and lines yield no triangle. Primitive ids number the
//! triangles in that order; a mesh placed by two nodes is there twice. Positions must be float
//! `VEC3`; sparse accessors, quantized positions and Draco compression are refused with a
//! message saying so. Textures, materials, animations and skins are not read.

use std::path::Path;

use gltf::json::Root;
use gltf::json::accessor::{ComponentType, Type};
use gltf::json::mesh::{Mode, Primitive, Semantic};
use gltf::json::validation::Checked;

use super::{Mesh, MeshError, Place, check_sizes};

/// A problem at an item of the document (`what` and its index).
fn bad(file: &str, what: &'static str, index: usize, detail: impl Into<String>) -> MeshError {
    MeshError::Format {
        file: file.to_owned(),
        at: Place::Item(what, index as u64),
        format: "glTF",
        detail: detail.into(),
    }
}

/// A problem at a byte of the file (the GLB container, the JSON).
fn bad_at(file: &str, byte: u64, detail: impl Into<String>) -> MeshError {
    MeshError::Format {
        file: file.to_owned(),
        at: Place::Byte(byte),
        format: "glTF",
        detail: detail.into(),
    }
}

/// Whether `bytes` starts as a binary glTF (the magic `glTF`).
pub(super) fn is_glb(bytes: &[u8]) -> bool {
    bytes.starts_with(b"glTF")
}

/// The JSON chunk and the binary chunk (if any) of a GLB file.
fn glb_chunks<'b>(bytes: &'b [u8], name: &str) -> Result<(&'b [u8], Option<&'b [u8]>), MeshError> {
    let word = |at: usize| {
        bytes
            .get(at..at + 4)
            .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
    };
    let (Some(version), Some(length)) = (word(4), word(8)) else {
        return Err(bad_at(name, bytes.len() as u64, "a GLB header is 12 bytes"));
    };
    if version != 2 {
        return Err(bad_at(
            name,
            4,
            format!("GLB version {version}; this reads glTF 2.0"),
        ));
    }
    if length as usize != bytes.len() {
        return Err(bad_at(
            name,
            8,
            format!(
                "the header says {length} bytes, the file has {}",
                bytes.len()
            ),
        ));
    }
    let mut chunks = Vec::new();
    let mut at = 12usize;
    while at < bytes.len() {
        let (Some(len), Some(kind)) = (word(at), word(at + 4)) else {
            return Err(bad_at(name, at as u64, "a chunk header is 8 bytes"));
        };
        let start = at + 8;
        let Some(body) = start
            .checked_add(len as usize)
            .and_then(|end| bytes.get(start..end))
        else {
            return Err(bad_at(
                name,
                at as u64,
                format!("a chunk of {len} bytes runs past the end of the file"),
            ));
        };
        chunks.push((kind, body));
        at = start + len as usize;
    }
    match chunks.as_slice() {
        [(0x4E4F_534A, json), rest @ ..] => {
            let bin = rest.first().filter(|c| c.0 == 0x004E_4942).map(|c| c.1);
            Ok((json, bin))
        }
        _ => Err(bad_at(
            name,
            12,
            "the first chunk of a GLB must be its JSON",
        )),
    }
}

/// Reads a glTF or GLB file held in `bytes`; `name` names it in errors; `dir` is where the
/// buffers its URIs name are (`None`: only the GLB's own buffer and `data:` URIs are read), each
/// at most `limit` bytes, and the mesh made at most `limit` bytes (12 a position and a
/// triangle: instancing can place a mesh many times).
pub fn parse_gltf(
    bytes: &[u8],
    name: &str,
    dir: Option<&Path>,
    limit: u64,
) -> Result<Mesh, MeshError> {
    let (json, bin) = if is_glb(bytes) {
        glb_chunks(bytes, name)?
    } else {
        (bytes, None)
    };
    let root: Root = serde_json::from_slice(json)
        .map_err(|e| bad_at(name, 0, format!("the JSON is not a glTF document: {e}")))?;
    let buffers = (0..root.buffers.len())
        .map(|i| buffer(&root, i, bin, name, dir, limit))
        .collect::<Result<Vec<_>, _>>()?;
    let placed = placements(&root, name)?;
    // What the placements will make, before anything is allocated.
    let mut total = 0u64;
    for (_, mesh, _) in &placed {
        for p in &root.meshes[*mesh].primitives {
            let (v, t) = primitive_size(&root, p);
            total = total
                .saturating_add(v.saturating_mul(12))
                .saturating_add(t.saturating_mul(12));
        }
    }
    if total > limit {
        return Err(MeshError::TooLarge {
            file: name.to_owned(),
            detail: format!(
                "its scene places {total} bytes of vertices and triangles (meshes times the \
                 nodes that place them), more than the {limit} this run reads"
            ),
        });
    }
    // One geometry (format-spec §8.8) per placement: the node, its mesh, its world transform.
    let mut out = Mesh::default();
    for (node, mesh, world) in &placed {
        let first = out.triangles.len() as u64;
        for (pi, p) in root.meshes[*mesh].primitives.iter().enumerate() {
            add_primitive(&mut out, &root, p, world, &buffers, name, (*mesh, pi))?;
        }
        let label = root.nodes[*node]
            .name
            .clone()
            .or_else(|| root.meshes[*mesh].name.clone())
            .unwrap_or_else(|| format!("node {node}"));
        out.geometries.push(super::Geometry {
            name: label,
            first_primitive: first,
            primitive_count: out.triangles.len() as u64 - first,
            // Column-major m[c][r] to row-major 3x4.
            transform: std::array::from_fn(|r| std::array::from_fn(|c| world[c][r])),
        });
    }
    check_sizes(&out, name)?;
    Ok(out)
}

/// The bytes of buffer `i`: the GLB's binary chunk, a `data:` URI, or a file in `dir`.
fn buffer(
    root: &Root,
    i: usize,
    bin: Option<&[u8]>,
    name: &str,
    dir: Option<&Path>,
    limit: u64,
) -> Result<Vec<u8>, MeshError> {
    let b = &root.buffers[i];
    let data = match b.uri.as_deref() {
        None => bin.map(<[u8]>::to_vec).ok_or_else(|| {
            bad(
                name,
                "buffer",
                i,
                "has no URI and the file has no GLB binary chunk",
            )
        })?,
        Some(uri) if uri.starts_with("data:") => {
            let Some((_, payload)) = uri.split_once(";base64,") else {
                return Err(bad(name, "buffer", i, "a data: URI that is not base64"));
            };
            use base64::Engine;
            base64::engine::general_purpose::STANDARD
                .decode(payload)
                .map_err(|e| bad(name, "buffer", i, format!("its data: URI: {e}")))?
        }
        Some(uri) => {
            let Some(dir) = dir else {
                return Err(bad(
                    name,
                    "buffer",
                    i,
                    format!("names a file ({uri}) and the glTF was given without its directory"),
                ));
            };
            let path = dir.join(percent_decoded(uri));
            super::read::read_file(&path, limit).map_err(|e| {
                bad(
                    name,
                    "buffer",
                    i,
                    format!("cannot read {}: {e}", path.display()),
                )
            })?
        }
    };
    if (data.len() as u64) < b.byte_length.0 {
        return Err(bad(
            name,
            "buffer",
            i,
            format!(
                "declares {} bytes and holds {}",
                b.byte_length.0,
                data.len()
            ),
        ));
    }
    Ok(data)
}

/// A URI's `%XX` escapes decoded (glTF file names are URI references).
fn percent_decoded(uri: &str) -> String {
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        match (
            b[i],
            b.get(i + 1).copied().and_then(hex),
            b.get(i + 2).copied().and_then(hex),
        ) {
            (b'%', Some(h), Some(l)) => {
                out.push((h * 16 + l) as u8);
                i += 3;
            }
            (c, _, _) => {
                out.push(c);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

type Matrix = [[f64; 4]; 4];

/// Node `n`'s own transform, column-major: its `matrix`, or `T * R * S`.
fn local(node: &gltf::json::Node) -> Matrix {
    if let Some(m) = node.matrix {
        return std::array::from_fn(|c| std::array::from_fn(|r| m[4 * c + r] as f64));
    }
    let t = node.translation.unwrap_or([0.0; 3]).map(f64::from);
    let s = node.scale.unwrap_or([1.0; 3]).map(f64::from);
    let [x, y, z, w] = node
        .rotation
        .as_ref()
        .map_or([0.0, 0.0, 0.0, 1.0], |q| q.0)
        .map(f64::from);
    let r = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y + z * w),
            2.0 * (x * z - y * w),
        ],
        [
            2.0 * (x * y - z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z + x * w),
        ],
        [
            2.0 * (x * z + y * w),
            2.0 * (y * z - x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    std::array::from_fn(|c| match c {
        3 => [t[0], t[1], t[2], 1.0],
        _ => [r[c][0] * s[c], r[c][1] * s[c], r[c][2] * s[c], 0.0],
    })
}

/// Every node that places a mesh, with the mesh's index and the node's world transform, in the
/// order of a depth-first walk.
fn placements(root: &Root, name: &str) -> Result<Vec<(usize, usize, Matrix)>, MeshError> {
    let identity: Matrix = std::array::from_fn(|i| std::array::from_fn(|j| (i == j) as u8 as f64));
    let node_index = |i: usize, from: &'static str, at: usize| {
        if i < root.nodes.len() {
            Ok(i)
        } else {
            Err(bad(
                name,
                from,
                at,
                format!("names node {i}, which does not exist"),
            ))
        }
    };
    let scene = root
        .scene
        .map(|s| s.value())
        .or((!root.scenes.is_empty()).then_some(0));
    let roots: Vec<usize> = match scene {
        Some(s) => {
            let sc = root
                .scenes
                .get(s)
                .ok_or_else(|| bad_at(name, 0, format!("the default scene {s} does not exist")))?;
            sc.nodes
                .iter()
                .map(|n| node_index(n.value(), "scene", s))
                .collect::<Result<_, _>>()?
        }
        None => {
            let mut child = vec![false; root.nodes.len()];
            for n in &root.nodes {
                for c in n.children.iter().flatten() {
                    if let Some(c) = child.get_mut(c.value()) {
                        *c = true;
                    }
                }
            }
            (0..root.nodes.len()).filter(|&i| !child[i]).collect()
        }
    };
    let mut out = Vec::new();
    let mut stack: Vec<(usize, Matrix)> = roots.into_iter().rev().map(|n| (n, identity)).collect();
    // A tree visits each node once; more visits are a cycle or a node with two parents.
    let mut visits = 0usize;
    while let Some((n, parent)) = stack.pop() {
        visits += 1;
        if visits > root.nodes.len() {
            return Err(bad(
                name,
                "node",
                n,
                "the nodes do not form trees (a cycle, or a node with two parents)",
            ));
        }
        let node = &root.nodes[n];
        let local = local(node);
        // Column-major: m[c][r].
        let world: Matrix = std::array::from_fn(|c| {
            std::array::from_fn(|r| (0..4).map(|k| parent[k][r] * local[c][k]).sum())
        });
        if let Some(m) = node.mesh {
            if m.value() >= root.meshes.len() {
                return Err(bad(
                    name,
                    "node",
                    n,
                    format!("names mesh {}, which does not exist", m.value()),
                ));
            }
            out.push((n, m.value(), world));
        }
        for c in node.children.iter().flatten().rev() {
            stack.push((node_index(c.value(), "node", n)?, world));
        }
    }
    Ok(out)
}

/// The POSITION accessor's index of `p`, if it has one.
fn position(p: &Primitive) -> Option<usize> {
    p.attributes
        .get(&Checked::Valid(Semantic::Positions))
        .map(|a| a.value())
}

/// Positions and triangles primitive `p` makes (its accessors' counts; 0 for what does not
/// exist, refused when it is read).
fn primitive_size(root: &Root, p: &Primitive) -> (u64, u64) {
    let count = |i: usize| root.accessors.get(i).map_or(0, |a| a.count.0);
    let v = position(p).map_or(0, count);
    let n = p.indices.map_or(v, |a| count(a.value()));
    let tris = match p.mode {
        Checked::Valid(Mode::Triangles) => n / 3,
        Checked::Valid(Mode::TriangleStrip | Mode::TriangleFan) => n.saturating_sub(2),
        _ => 0,
    };
    (v, tris)
}

/// Accessor `i`'s bytes, checked for every element of `size` bytes before any is read:
/// `(buffer, offset of the first, stride, count)`.
fn layout<'b>(
    root: &Root,
    i: usize,
    size: usize,
    buffers: &'b [Vec<u8>],
    name: &str,
) -> Result<(&'b [u8], usize, usize, usize), MeshError> {
    let a = root
        .accessors
        .get(i)
        .ok_or_else(|| bad(name, "accessor", i, "does not exist"))?;
    if a.sparse.is_some() {
        return Err(bad(name, "accessor", i, "sparse accessors are not read"));
    }
    let Some(vi) = a.buffer_view.map(|v| v.value()) else {
        return Err(bad(
            name,
            "accessor",
            i,
            "has no buffer view (all zeros): not read",
        ));
    };
    let view = root.buffer_views.get(vi).ok_or_else(|| {
        bad(
            name,
            "accessor",
            i,
            format!("names buffer view {vi}, which does not exist"),
        )
    })?;
    let stride = view.byte_stride.map_or(size, |s| s.0);
    if stride < size {
        return Err(bad(
            name,
            "accessor",
            i,
            format!("byte stride {stride} is smaller than its {size}-byte elements"),
        ));
    }
    let buf = buffers.get(view.buffer.value()).ok_or_else(|| {
        bad(
            name,
            "buffer view",
            vi,
            format!("names buffer {}, which does not exist", view.buffer.value()),
        )
    })?;
    let count = a.count.0;
    let start = view
        .byte_offset
        .map_or(0, |o| o.0)
        .saturating_add(a.byte_offset.map_or(0, |o| o.0));
    let view_end = view
        .byte_offset
        .map_or(0, |o| o.0)
        .saturating_add(view.byte_length.0);
    let end = match count {
        0 => start,
        n => (n - 1)
            .saturating_mul(stride as u64)
            .saturating_add(start)
            .saturating_add(size as u64),
    };
    if end > view_end || view_end > buf.len() as u64 {
        return Err(bad(
            name,
            "accessor",
            i,
            format!(
                "{count} elements of {size} bytes every {stride} from byte {start} end at {end}, past its \
             view (ending at {view_end}) or its buffer ({} bytes)",
                buf.len()
            ),
        ));
    }
    Ok((buf, start as usize, stride, count as usize))
}

/// Adds primitive `p` of mesh `at.0` (its `at.1`-th), its positions transformed by `world`.
fn add_primitive(
    out: &mut Mesh,
    root: &Root,
    p: &Primitive,
    world: &Matrix,
    buffers: &[Vec<u8>],
    name: &str,
    (mesh, pi): (usize, usize),
) -> Result<(), MeshError> {
    let mode = match p.mode {
        Checked::Valid(m @ (Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan)) => m,
        Checked::Valid(_) => return Ok(()),
        Checked::Invalid => {
            return Err(bad(
                name,
                "mesh",
                mesh,
                format!("primitive {pi} has an unknown mode"),
            ));
        }
    };
    let Some(pos) = position(p) else {
        return Err(bad(
            name,
            "mesh",
            mesh,
            format!("primitive {pi} has no POSITION"),
        ));
    };
    let a = root.accessors.get(pos).ok_or_else(|| {
        bad(
            name,
            "mesh",
            mesh,
            format!("primitive {pi}'s POSITION names accessor {pos}, which does not exist"),
        )
    })?;
    let float_vec3 = matches!(a.component_type, Checked::Valid(t) if t.0 == ComponentType::F32)
        && matches!(a.type_, Checked::Valid(Type::Vec3))
        && !a.normalized;
    if !float_vec3 {
        return Err(bad(
            name,
            "accessor",
            pos,
            "POSITION is not float VEC3 (quantized positions are not read)",
        ));
    }
    let (buf, start, stride, n) = layout(root, pos, 12, buffers, name)?;
    let base = out.positions.len() as u64;
    for k in 0..n {
        let at = start + k * stride;
        let c: [f64; 3] = std::array::from_fn(|j| {
            let b: [u8; 4] = buf[at + 4 * j..at + 4 * j + 4]
                .try_into()
                .unwrap_or_default();
            f32::from_le_bytes(b) as f64
        });
        let w: [f32; 3] = std::array::from_fn(|r| {
            (world[0][r] * c[0] + world[1][r] * c[1] + world[2][r] * c[2] + world[3][r]) as f32
        });
        if !w.iter().all(|x| x.is_finite()) {
            return Err(bad(
                name,
                "accessor",
                pos,
                format!("position {k} is not finite once placed"),
            ));
        }
        out.positions.push(w);
    }
    let n = n as u64;
    let indices: Vec<u64> = match p.indices.map(|i| i.value()) {
        None => (0..n).collect(),
        Some(ix) => {
            let acc = root.accessors.get(ix).ok_or_else(|| {
                bad(
                    name,
                    "mesh",
                    mesh,
                    format!("primitive {pi}'s indices name accessor {ix}, which does not exist"),
                )
            })?;
            let size = match (acc.component_type, acc.type_) {
                (Checked::Valid(t), Checked::Valid(Type::Scalar)) if t.0 == ComponentType::U8 => 1,
                (Checked::Valid(t), Checked::Valid(Type::Scalar)) if t.0 == ComponentType::U16 => 2,
                (Checked::Valid(t), Checked::Valid(Type::Scalar)) if t.0 == ComponentType::U32 => 4,
                _ => {
                    return Err(bad(
                        name,
                        "accessor",
                        ix,
                        "indices are not unsigned byte, short or int scalars",
                    ));
                }
            };
            let (buf, start, stride, count) = layout(root, ix, size, buffers, name)?;
            (0..count)
                .map(|k| {
                    let at = start + k * stride;
                    let mut b = [0u8; 4];
                    b[..size].copy_from_slice(&buf[at..at + size]);
                    let v = u32::from_le_bytes(b) as u64;
                    if v >= n {
                        Err(bad(
                            name,
                            "accessor",
                            ix,
                            format!("index {k} is {v}, past the {n} positions"),
                        ))
                    } else {
                        Ok(v)
                    }
                })
                .collect::<Result<_, _>>()?
        }
    };
    let corner = |k: usize| (base + indices[k]) as u32;
    let m = indices.len();
    match mode {
        Mode::Triangles => {
            for t in 0..m / 3 {
                out.triangles
                    .push([corner(3 * t), corner(3 * t + 1), corner(3 * t + 2)]);
            }
        }
        Mode::TriangleStrip => {
            for t in 0..m.saturating_sub(2) {
                let odd = t % 2;
                out.triangles
                    .push([corner(t), corner(t + 1 + odd), corner(t + 2 - odd)]);
            }
        }
        _ => {
            for t in 0..m.saturating_sub(2) {
                out.triangles
                    .push([corner(t + 1), corner(t + 2), corner(0)]);
            }
        }
    }
    if out.positions.len() > u32::MAX as usize {
        return Err(MeshError::TooLarge {
            file: name.to_owned(),
            detail: "more than 2^32 vertices".into(),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A GLB of `json` (`BIN` standing for the binary chunk's length) and `bin`.
    fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
        let mut j = json.replace("BIN", &bin.len().to_string()).into_bytes();
        while !j.len().is_multiple_of(4) {
            j.push(b' ');
        }
        let mut b = bin.to_vec();
        while !b.len().is_multiple_of(4) {
            b.push(0);
        }
        let total = 12 + 8 + j.len() + 8 + b.len();
        let mut out = Vec::new();
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(j.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&j);
        out.extend_from_slice(&(b.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&b);
        out
    }

    /// Four corners of a unit square (48 bytes), then u16 indices 0 1 2 0 2 3 (12 bytes).
    fn square_bin() -> Vec<u8> {
        let mut b = Vec::new();
        for p in [[0f32, 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]] {
            for c in p {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        for i in [0u16, 1, 2, 0, 2, 3] {
            b.extend_from_slice(&i.to_le_bytes());
        }
        b
    }

    /// The square's mesh placed by two nodes: one moved by (10, 0, 0) and scaled by 2 (TRS),
    /// one a child of it turned by a matrix (x -> y); a third primitive drawn as a strip
    /// without indices, a fourth as a fan.
    const SCENE: &str = r#"{"asset":{"version":"2.0"},"scene":0,
        "scenes":[{"nodes":[0]}],
        "nodes":[{"name":"floor","mesh":0,"translation":[10,0,0],"scale":[2,2,2],"children":[1]},
                 {"mesh":1,"matrix":[0,1,0,0, -1,0,0,0, 0,0,1,0, 0,0,5,1]}],
        "meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1}]},
                  {"primitives":[{"attributes":{"POSITION":0},"mode":5},
                                 {"attributes":{"POSITION":0},"mode":6},
                                 {"attributes":{"POSITION":0},"mode":1}]}],
        "buffers":[{"byteLength":BIN}],
        "bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":48},
                       {"buffer":0,"byteOffset":48,"byteLength":12}],
        "accessors":[{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3",
                      "min":[0,0,0],"max":[1,1,0]},
                     {"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR"}]}"#;

    #[test]
    fn a_scene_is_baked_node_by_node() {
        let m = parse_gltf(&glb(SCENE, &square_bin()), "s.glb", None, u64::MAX).unwrap();
        // Node 0: the indexed square, scaled by 2 and moved by 10 along x.
        assert_eq!(m.triangle(0), [[10., 0., 0.], [12., 0., 0.], [12., 2., 0.]]);
        assert_eq!(m.triangle(1), [[10., 0., 0.], [12., 2., 0.], [10., 2., 0.]]);
        // Node 1 (its parent's transform, then x -> y and 5 along z): the strip (0 1 2), (1 3 2)
        // and the fan (1 2 0), (2 3 0); the lines make none.
        let place = |p: [f32; 3]| [10.0 - 2.0 * p[1], 2.0 * p[0], 10.0 + 2.0 * p[2]];
        let sq = [[0f32, 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]];
        let want = [[0, 1, 2], [1, 3, 2], [1, 2, 0], [2, 3, 0]].map(|t| t.map(|i| place(sq[i])));
        for (k, w) in want.iter().enumerate() {
            assert_eq!(m.triangle(2 + k), *w, "triangle {}", 2 + k);
        }
        assert_eq!(m.triangles.len(), 6);
        // A geometry per node: its name (the node's, else "node N"), its primitives, its world
        // transform (row-major 3x4), which maps its mesh's corners to what was stored.
        let names: Vec<_> = m.geometries.iter().map(|g| g.name.as_str()).collect();
        assert_eq!(names, ["floor", "node 1"]);
        let runs: Vec<_> = m.geometries.iter().map(|g| g.primitives()).collect();
        assert_eq!(runs, [0..2, 2..6]);
        let t = m.geometries[1].transform;
        for (c, p) in sq.iter().enumerate() {
            let w: [f64; 3] = std::array::from_fn(|r| {
                (0..3).map(|k| t[r][k] * p[k] as f64).sum::<f64>() + t[r][3]
            });
            assert_eq!(w.map(|x| x as f32), place(*p), "corner {c}");
        }
        assert_eq!(m.geometries[0].transform[0], [2.0, 0.0, 0.0, 10.0]);
    }

    #[test]
    fn a_rotation_is_the_matrix_it_stands_for() {
        // 90 degrees about z, as a quaternion (x, y, z, w), against the matrix of node 1.
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let json = SCENE.replace(
            r#""matrix":[0,1,0,0, -1,0,0,0, 0,0,1,0, 0,0,5,1]"#,
            &format!(r#""rotation":[0,0,{h},{h}],"translation":[0,0,5]"#),
        );
        let a = parse_gltf(&glb(&json, &square_bin()), "r.glb", None, u64::MAX).unwrap();
        let b = parse_gltf(&glb(SCENE, &square_bin()), "m.glb", None, u64::MAX).unwrap();
        for (p, q) in a.positions.iter().zip(&b.positions) {
            assert!((0..3).all(|k| (p[k] - q[k]).abs() < 1e-5), "{p:?} {q:?}");
        }
    }

    #[test]
    fn a_gltf_reads_its_buffers_from_data_uris_and_files() {
        use base64::Engine;
        let bin = square_bin();
        let uri = base64::engine::general_purpose::STANDARD.encode(&bin);
        let json = SCENE.replace(
            r#""byteLength":BIN}"#,
            &format!(
                r#""byteLength":{},"uri":"data:application/octet-stream;base64,{uri}"}}"#,
                bin.len()
            ),
        );
        let m = parse_gltf(json.as_bytes(), "s.gltf", None, u64::MAX).unwrap();
        assert_eq!(m.triangles.len(), 6);
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("sq uare.bin"), &bin).unwrap();
        let json = SCENE.replace(
            r#""byteLength":BIN}"#,
            &format!(r#""byteLength":{},"uri":"sq%20uare.bin"}}"#, bin.len()),
        );
        let path = dir.path().join("s.gltf");
        std::fs::write(&path, &json).unwrap();
        assert_eq!(crate::mesh::load(&path).unwrap(), m);
        let e = parse_gltf(json.as_bytes(), "s.gltf", None, u64::MAX)
            .unwrap_err()
            .to_string();
        assert!(e.contains("buffer 0") && e.contains("directory"), "{e}");
        // The GLB read through `load` by its magic, whatever its name.
        let p = dir.path().join("scene.bin3d");
        std::fs::write(&p, glb(SCENE, &bin)).unwrap();
        assert_eq!(crate::mesh::load(&p).unwrap(), m);
    }

    #[test]
    fn malformed_files_are_named_errors() {
        let bin = square_bin();
        let cases: [(&str, &str, &str); 7] = [
            (
                r#""count":4,"type":"VEC3""#,
                r#""count":5,"type":"VEC3""#,
                "accessor 0",
            ),
            (
                r#""count":6,"type":"SCALAR""#,
                r#""count":6,"type":"SCALAR","byteOffset":4"#,
                "accessor 1",
            ),
            (
                r#""componentType":5126,"count":4"#,
                r#""componentType":5123,"count":4"#,
                "accessor 0",
            ),
            (r#""children":[1]"#, r#""children":[1, 0]"#, "node"),
            (
                r#"{"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR"}"#,
                r#"{"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR","sparse":{"count":1,"indices":{"bufferView":1,"componentType":5123},"values":{"bufferView":1}}}"#,
                "sparse",
            ),
            (r#""byteLength":BIN}"#, r#""byteLength":99999}"#, "buffer 0"),
            (r#""mode":5"#, r#""mode":5,"indices":0"#, "accessor 0"),
        ];
        for (from, to, says) in cases {
            let json = SCENE.replace(from, to);
            assert_ne!(json, SCENE, "{from}");
            let e = parse_gltf(&glb(&json, &bin), "s.glb", None, u64::MAX)
                .expect_err(to)
                .to_string();
            assert!(e.starts_with("s.glb: ") && e.contains(says), "{to}: {e}");
        }
        // Indices past the positions; a scene that would place more than the limit.
        let mut b = bin.clone();
        b[48..50].copy_from_slice(&9u16.to_le_bytes());
        let e = parse_gltf(&glb(SCENE, &b), "s.glb", None, u64::MAX)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("accessor 1") && e.contains("index 0 is 9"),
            "{e}"
        );
        let e = parse_gltf(&glb(SCENE, &bin), "s.glb", None, 100)
            .unwrap_err()
            .to_string();
        assert!(e.contains("more than the 100"), "{e}");
        assert!(parse_gltf(b"glTF\x02\0\0\0", "s.glb", None, u64::MAX).is_err());
        assert!(parse_gltf(b"{}", "s.gltf", None, u64::MAX).is_err());
    }

    #[test]
    fn no_prefix_or_changed_byte_panics() {
        let file = glb(SCENE, &square_bin());
        crate::mesh::survives_damage(&file, |b| parse_gltf(b, "s.glb", None, 1 << 20));
        crate::mesh::survives_damage(SCENE.replace("BIN", "60").as_bytes(), |b| {
            parse_gltf(b, "s.gltf", None, 1 << 20)
        });
    }
}
