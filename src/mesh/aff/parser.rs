//! The parser: the scene under construction ([`Parser`]), one file's statements dispatched to
//! their handlers (the geometry in [`super::geometry`] and [`super::tessellate`], keyframes in
//! [`super::keyframes`], the view in [`super::view`], materials and lights in
//! [`super::material`]), transforms and includes.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::rc::Rc;

use glam::DVec3;

use super::kb::{Quat, Reach};
use super::keyframes::Animation;
use super::material::Materials;
use super::tokens::{Src, Tokens, show};
use super::transform::{Affine, trs};
use super::view::parse_view;
use super::{
    AffCounts, AffView, INCLUDE_COST, MAX_INCLUDE_DEPTH, ReadInclude, check_budget, normalize,
    read_error,
};
use crate::mesh::MeshError;

pub(super) enum NodeKind {
    Root,
    Static(Affine),
    /// An `x name`: the id of `name` (see [`Parser::animation_id`]).
    Animated(usize),
}

pub(super) struct Node {
    pub(super) parent: usize,
    pub(super) kind: NodeKind,
}

/// The vertices from `first` to the next run's `first` belong to one statement, under `node`.
pub(super) struct Run {
    pub(super) first: u32,
    pub(super) node: usize,
    pub(super) file: usize,
    pub(super) line: u64,
}

/// A `tpa`: its keys `(time, corners)` as in the file.
pub(super) struct AnimTri {
    /// First of the three vertex slots reserved for it.
    pub(super) slot: u32,
    pub(super) keys: Vec<(f64, [DVec3; 3])>,
    /// The [`Reach`] of the key times from the second key on.
    pub(super) reach: Reach,
}

pub(super) struct Parser<'r> {
    pub(super) read: &'r mut ReadInclude<'r>,
    pub(super) cache: HashMap<PathBuf, Rc<Vec<u8>>>,
    /// Include stack, normalised paths, top file first.
    pub(super) stack: Vec<PathBuf>,
    /// Bytes parsed so far, against `budget` (see [`super::MAX_PARSED_BYTES`]).
    pub(super) parsed: u64,
    pub(super) budget: u64,
    pub(super) detail: i64,
    pub(super) files: Vec<String>,
    pub(super) file_ids: HashMap<String, usize>,

    pub(super) nodes: Vec<Node>,
    pub(super) current: usize,
    pub(super) positions: Vec<DVec3>,
    pub(super) triangles: Vec<[u32; 3]>,
    pub(super) runs: Vec<Run>,
    pub(super) anim_tris: Vec<AnimTri>,
    /// Point lights: node, local position and colour.
    pub(super) lights: Vec<(usize, DVec3, [f32; 3])>,
    /// The materials and the material of each triangle of `triangles`.
    pub(super) materials: Materials,
    /// `b r g b`, the last one read (black without one).
    pub(super) background: [f32; 3],
    /// `am r g b`, the last one read (white without one, as BART's parser says).
    pub(super) ambient: [f32; 3],
    /// The id of each name an `x` or a `k` gave, in the order first seen.
    pub(super) animation_ids: HashMap<Vec<u8>, usize>,
    /// By id: the last `k` block of that name, if any.
    pub(super) animations: Vec<Option<Animation>>,
    pub(super) view: Option<AffView>,
    pub(super) animation: Option<(f64, f64, u64)>,
    pub(super) counts: AffCounts,
}

impl<'r> Parser<'r> {
    pub(super) fn new(read: &'r mut ReadInclude<'r>, budget: u64) -> Parser<'r> {
        Parser {
            read,
            budget,
            cache: HashMap::new(),
            stack: Vec::new(),
            parsed: 0,
            detail: 0,
            files: Vec::new(),
            file_ids: HashMap::new(),
            nodes: vec![Node {
                parent: 0,
                kind: NodeKind::Root,
            }],
            current: 0,
            positions: Vec::new(),
            triangles: Vec::new(),
            runs: Vec::new(),
            anim_tris: Vec::new(),
            lights: Vec::new(),
            materials: Materials::new(),
            background: [0.0; 3],
            ambient: [1.0; 3],
            animation_ids: HashMap::new(),
            animations: Vec::new(),
            view: None,
            animation: None,
            counts: AffCounts::default(),
        }
    }

    pub(super) fn file_id(&mut self, name: &str) -> usize {
        if let Some(&id) = self.file_ids.get(name) {
            return id;
        }
        let id = self.files.len();
        self.files.push(name.to_owned());
        self.file_ids.insert(name.to_owned(), id);
        id
    }

    /// Starts the vertices of a new statement.
    pub(super) fn begin(&mut self, file: usize, line: u64) {
        self.runs.push(Run {
            first: self.positions.len() as u32,
            node: self.current,
            file,
            line,
        });
    }

    /// Adds a vertex, returning its index.
    pub(super) fn vertex(&mut self, src: &Src, line: u64, p: DVec3) -> Result<u32, MeshError> {
        let i = self.positions.len();
        if i >= u32::MAX as usize {
            return Err(MeshError::TooLarge {
                file: src.file.to_owned(),
                detail: format!("more than {} vertices at line {line}", u32::MAX),
            });
        }
        self.positions.push(p);
        Ok(i as u32)
    }

    pub(super) fn parse_file(
        &mut self,
        bytes: &[u8],
        name: &str,
        path: &Path,
    ) -> Result<(), MeshError> {
        let mut src = Src {
            tok: Tokens::new(bytes),
            file: name,
        };
        let fid = self.file_id(name);
        // Lines of the `{` opened in this file and not yet closed.
        let mut open: Vec<u64> = Vec::new();
        while let Some((kw, line)) = src.tok.next() {
            match kw {
                b"v" => self.view = Some(parse_view(&mut src, line)?),
                b"b" => self.background = src.colour(&|| "the background colour `b`".into())?,
                b"am" => self.ambient = src.colour(&|| "the ambient light `am`".into())?,
                b"l" => self.light(&mut src)?,
                b"f" => self.nff_material(&mut src, line)?,
                b"fm" => self.bart_material(&mut src, line)?,
                b"p" | b"pp" => self.polygon(&mut src, fid, line, kw == b"pp")?,
                b"tt" | b"ttp" => self.textured_triangle(&mut src, fid, line, kw == b"ttp")?,
                b"tpa" => self.animated_triangle(&mut src, fid, line)?,
                b"m" => self.mesh(&mut src, fid, line)?,
                b"c" => self.cone(&mut src, fid, line)?,
                b"s" => self.sphere(&mut src, fid, line)?,
                b"xs" => {
                    self.static_transform(&mut src)?;
                    open.push(line);
                }
                b"x" => {
                    self.animated_transform(&mut src)?;
                    open.push(line);
                }
                b"{" => return Err(src.aff(line, "`{` without a transform before it".into())),
                b"}" => {
                    if open.pop().is_none() {
                        return Err(
                            src.aff(line, "`}` without a matching `{` in this file".to_owned())
                        );
                    }
                    self.current = self.nodes[self.current].parent;
                }
                b"a" => self.animation_range(&mut src)?,
                b"k" => self.keyframes(&mut src, line)?,
                b"d" => self.detail = src.integer(&|| "the detail level of `d`".into())?.0,
                b"i" => self.include(&mut src, path, line)?,
                _ => {
                    return Err(src.aff(
                        line,
                        format!(
                            "unknown keyword `{}` (this reader knows v b am l f fm p pp tt ttp \
                             tpa m c s xs x k a d i and braces)",
                            show(kw)
                        ),
                    ));
                }
            }
        }
        if let Some(&line) = open.last() {
            return Err(src.aff(
                line,
                format!(
                    "the `{{` opened here is not closed by the end of the file ({} open)",
                    open.len()
                ),
            ));
        }
        Ok(())
    }

    /// `a start end frames`.
    fn animation_range(&mut self, src: &mut Src) -> Result<(), MeshError> {
        let start = src.number(&|| "the start time of `a`".into())?;
        let end = src.number(&|| "the end time of `a`".into())?;
        let frames = src.count(&|| "the number of frames of `a`".into())?;
        self.animation = Some((start, end, frames));
        Ok(())
    }

    /// `xs sx sy sz  rx ry rz deg  tx ty tz {`: opens a static transform.
    fn static_transform(&mut self, src: &mut Src) -> Result<(), MeshError> {
        let what = |w: &'static str| move || format!("the {w} of the static transform `xs`");
        let s = src.vec3(&what("scale"))?;
        let axis = src.vec3(&what("rotation axis"))?;
        let deg = src.number(&what("rotation angle"))?;
        let t = src.vec3(&what("translation"))?;
        src.expect(b"{", &|| "after the static transform `xs`".into())?;
        let r = Quat::from_angle_axis(deg.to_radians(), axis.to_array()).matrix();
        self.push_node(NodeKind::Static(trs(t, r, s)));
        Ok(())
    }

    /// `x name {`: opens an animated transform.
    fn animated_transform(&mut self, src: &mut Src) -> Result<(), MeshError> {
        let (name, _) = src.token(&|| "the name of the transform `x`".into())?;
        let name = name.to_vec();
        src.expect(b"{", &|| format!("after `x {}`", show(&name)))?;
        let id = self.animation_id(&name);
        self.push_node(NodeKind::Animated(id));
        Ok(())
    }

    /// The id of the animation `name`: `k` blocks and `x` transforms may come in either order,
    /// so each name is numbered when first seen, and posing evaluates each number once.
    pub(super) fn animation_id(&mut self, name: &[u8]) -> usize {
        if let Some(&id) = self.animation_ids.get(name) {
            return id;
        }
        let id = self.animations.len();
        self.animations.push(None);
        self.animation_ids.insert(name.to_vec(), id);
        id
    }

    fn push_node(&mut self, kind: NodeKind) {
        self.nodes.push(Node {
            parent: self.current,
            kind,
        });
        self.current = self.nodes.len() - 1;
    }

    pub(super) fn include(
        &mut self,
        src: &mut Src,
        path: &Path,
        line: u64,
    ) -> Result<(), MeshError> {
        let (level, _) = src.integer(&|| "the detail level of the include `i`".into())?;
        let (name, _) = src.token(&|| "the file name of the include `i`".into())?;
        if level > self.detail {
            return Ok(());
        }
        let name = String::from_utf8_lossy(name).into_owned();
        let dir = path.parent().unwrap_or(Path::new(""));
        let target = dir.join(&name);
        let key = normalize(&target);
        if self.stack.contains(&key) {
            let chain: Vec<String> = self
                .stack
                .iter()
                .chain(std::iter::once(&key))
                .map(|p| p.display().to_string())
                .collect();
            return Err(src.aff(line, format!("include cycle: {}", chain.join(" includes "))));
        }
        if self.stack.len() > MAX_INCLUDE_DEPTH {
            return Err(src.aff(
                line,
                format!("includes nest deeper than {MAX_INCLUDE_DEPTH} files"),
            ));
        }
        let wrap = |e: MeshError| MeshError::Included {
            file: src.file.to_owned(),
            line,
            source: Box::new(e),
        };
        let bytes = match self.cache.get(&key) {
            Some(b) => Rc::clone(b),
            None => {
                // What the budget leaves for this file, known before it is read.
                let left = self
                    .budget
                    .saturating_sub(self.parsed)
                    .saturating_sub(INCLUDE_COST);
                let b = (self.read)(&target, left)
                    .map_err(|e| wrap(read_error(e, &target, left, self.budget)))?;
                let b = Rc::new(b);
                self.cache.insert(key.clone(), Rc::clone(&b));
                b
            }
        };
        let inner = target.display().to_string();
        self.parsed = self
            .parsed
            .saturating_add(bytes.len() as u64)
            .saturating_add(INCLUDE_COST);
        check_budget(self.parsed, self.budget, &inner).map_err(wrap)?;
        self.stack.push(key);
        let result = self.parse_file(&bytes, &inner, &target);
        self.stack.pop();
        result.map_err(wrap)
    }
}
