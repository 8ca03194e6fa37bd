//! The merge: the shards' subtrees joined under the top tree and written as the file, one part
//! in memory at a time.
//!
//! The file is laid out in regions (`vds_format::region_leaves`): its top, then each region
//! root's subtree in leaf order, and no page mixes two regions. Every region lies under one
//! shard root (the plan splits no node that a region could hold), so its pages depend on one
//! part alone. The merge therefore takes each part twice, in shard order: its head (a
//! [`PartHead`]: what the top needs, which [`super::read_part_head`] reads from a file while
//! it seeks over the pages and leaves), then the whole part:
//!
//! 1. *The top.* From each part, the root's record and sums, the nodes of the file's top that
//!    lie under the root (those with more leaves than a region, and their children) with
//!    their subtris, and the corners of triangles across roots. Then the top nodes of the
//!    plan get their proxies from the roots' sums, as the in-memory build's levels above its
//!    parallel frontier get theirs; the cross corners are joined into triangles and placed
//!    with their owners; and the top is laid out, which numbers its nodes.
//! 2. *The regions.* Each part's regions are numbered after everything before them and
//!    their pages spilled to a temporary file: the pages a shard sealed are copied (a
//!    region's first one with its first parent rewritten, `vds_format::attach_region`), an
//!    open page is encoded with the triangles across shards that its nodes own. The part's leaves
//!    widen the error radii of the plan's top nodes above them (an exact farthest-leaf scan,
//!    as every node's radius is).
//!
//! Last, the plan's top nodes get their bounds, the top pages are encoded, and the file is
//! written: header, metadata and directory, the top's pages, the spilled pages. What is held
//! is the top, the triangles across roots, a page's directory entry each, and one part, whose
//! pages are made side by side and spilled in order once all are made.

use std::collections::VecDeque;
use std::io::{BufWriter, Seek, Write};
use std::path::Path;

use rayon::prelude::*;
use vds_format::{
    BuildInfo, EncodedPage, EncodedPageSummary, FileFigures, InputInfo, Metadata, NO_NODE,
    NodeRecord, PageLayout, TriangleRecord, WriteReport, attach_region, attached_id, detached_id,
    encode_page_frame, encode_pages, file_head, in_top_with_children,
};
use xxhash_rust::xxh3::Xxh3;
use zerocopy::IntoBytes;
use zerocopy::little_endian::U32;

use super::part::{CrossCorner, OpenPage, RegionPage, RootPart, ShardPart};
use super::plan::TopNode;
use super::seal::{children, leaf_count, subtris};
use super::{Plan, ShardError};
use crate::build::{
    Accumulator, Sphere, absorb_on, inner_bounds, inner_proxy, leaf_distance_squared,
};
use crate::isa::Isa;
use crate::tree::Node;
use crate::vdt::{PartCounts, leading_smallest, node_record};

/// Joins the parts of every shard of `plan` (any order, each once) into the bytes of the
/// `.vdt` file the in-memory build of the same input writes. The parts must come from
/// [`super::build_shard`] or its siblings, or from [`super::read_part`], which checks a file's:
/// the merge trusts their links and ranges.
pub fn merge(plan: &Plan, parts: Vec<ShardPart>) -> Result<Vec<u8>, ShardError> {
    let mut by_index: Vec<Option<ShardPart>> = vec![None; plan.shard_count() as usize];
    for part in parts {
        if part.plan_id != plan.id {
            return Err(set(format!(
                "shard {} was built for another plan",
                part.index
            )));
        }
        match by_index.get_mut(part.index as usize) {
            Some(slot @ None) => *slot = Some(part),
            Some(Some(_)) => return Err(set(format!("shard {} is given twice", part.index))),
            None => return Err(set(format!("shard {} is not in the plan", part.index))),
        }
    }
    if let Some(missing) = by_index.iter().position(Option::is_none) {
        return Err(set(format!(
            "shard {missing} of {} is missing",
            plan.shard_count()
        )));
    }
    let mut out = Vec::new();
    // The first pass gets each part's head, the second the part itself.
    let by_index = std::cell::RefCell::new(by_index);
    merge_to(
        plan,
        |k| {
            let parts = by_index.borrow();
            let part = parts[k as usize].as_ref();
            Ok(PartHead::of(part.expect("every shard is present")))
        },
        |k| {
            let part = by_index.borrow_mut()[k as usize].take();
            Ok(part.expect("every shard is present, once").into())
        },
        &mut out,
        &std::env::temp_dir(),
    )?;
    Ok(out)
}

fn set(reason: String) -> ShardError {
    ShardError::PartSet(reason)
}

/// A part as [`merge_to`] is handed it, with what tells the merge's two reads of it apart: the
/// verified body checksum of the file it was read from ([`super::read_part_checked`]), so that
/// it is not hashed again, or, for a part made in memory (`From<ShardPart>`), a hash of the
/// whole part. A part read from a file in one pass and made in memory in the other is refused.
#[derive(Debug, Clone)]
pub struct PartRead {
    part: ShardPart,
    checksum: Option<u64>,
}

impl From<ShardPart> for PartRead {
    fn from(part: ShardPart) -> PartRead {
        PartRead {
            part,
            checksum: None,
        }
    }
}

/// What must be the same in both passes (see [`PartRead`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stamp {
    File(u64),
    Digest(u64),
}

impl PartRead {
    /// A part read from a file whose body checksum, `checksum`, was verified.
    pub(crate) fn from_file(part: ShardPart, checksum: u64) -> PartRead {
        PartRead {
            part,
            checksum: Some(checksum),
        }
    }

    /// The part, taken.
    pub fn into_part(self) -> ShardPart {
        self.part
    }

    fn stamp(&self) -> Stamp {
        match self.checksum {
            Some(checksum) => Stamp::File(checksum),
            None => Stamp::Digest(digest(&self.part)),
        }
    }
}

/// What the merge's first pass takes of a part: its roots' heads and tops and its cross
/// corners ([`super::read_part_head`] reads them from a file, seeking over its pages and
/// leaves), with what the second pass's read of the whole part must match (as a
/// [`PartRead`]'s: the checksum the file states, or a hash of a part made in memory).
#[derive(Debug, Clone, PartialEq)]
pub struct PartHead {
    pub(crate) head: ShardHead,
    stamp: Stamp,
}

/// A part without its pages and leaves ([`PartHead`]).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ShardHead {
    pub(crate) plan_id: u64,
    pub(crate) index: u32,
    pub(crate) roots: Vec<RootHead>,
    pub(crate) cross: Vec<CrossCorner>,
}

/// A root's part without its pages and leaves: what the top is gathered from.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct RootHead {
    pub(crate) root: u32,
    pub(crate) top_ids: Vec<u32>,
    pub(crate) top_nodes: Vec<NodeRecord>,
    pub(crate) top_triangles: Vec<TriangleRecord>,
    pub(crate) sums: Accumulator,
    pub(crate) sphere: Sphere,
    /// Its regions' roots (ids in its subtree), in leaf order.
    pub(crate) region_roots: Vec<u32>,
    /// The triangles its regions' pages hold.
    pub(crate) region_triangles: u64,
    /// Its leaf count.
    pub(crate) leaves: u64,
}

impl RootHead {
    fn of(root: &RootPart) -> RootHead {
        RootHead {
            root: root.root,
            top_ids: root.top_ids.clone(),
            top_nodes: root.top_nodes.clone(),
            top_triangles: root.top_triangles.clone(),
            sums: root.sums,
            sphere: root.sphere,
            region_roots: root.regions.iter().map(|g| g.root).collect(),
            region_triangles: root
                .regions
                .iter()
                .flat_map(|g| &g.pages)
                .map(RegionPage::triangle_count)
                .sum(),
            leaves: root.leaves.len() as u64,
        }
    }
}

impl ShardHead {
    fn of(part: &ShardPart) -> ShardHead {
        ShardHead {
            plan_id: part.plan_id,
            index: part.index,
            roots: part.roots.iter().map(RootHead::of).collect(),
            cross: part.cross.clone(),
        }
    }
}

impl PartHead {
    /// Whether `other` holds the same head, however either was read (their stamps aside).
    pub fn same_head(&self, other: &PartHead) -> bool {
        self.head == other.head
    }

    /// The head read from a file whose trailer states body checksum `checksum`.
    pub(crate) fn from_file(head: ShardHead, checksum: u64) -> PartHead {
        PartHead {
            head,
            stamp: Stamp::File(checksum),
        }
    }

    /// The head of a part made in memory (stamped with a hash of the whole part).
    pub fn of(part: &ShardPart) -> PartHead {
        PartHead {
            head: ShardHead::of(part),
            stamp: Stamp::Digest(digest(part)),
        }
    }
}

impl PartRead {
    /// The part's head, stamped as the part is.
    pub fn head(&self) -> PartHead {
        PartHead {
            head: ShardHead::of(&self.part),
            stamp: self.stamp(),
        }
    }
}

/// [`merge`], writing the file to `out`: the first pass asks `head` for each shard's head,
/// the second `part` for its whole part, each in index order (the two passes of the module
/// doc), so that one part is held at a time; a part that differs from its head (another
/// stamp: it changed between the passes) is refused. The regions' pages wait in an unnamed
/// temporary file in `spill_folder` (about the size of the output) until the top's are
/// encoded.
pub fn merge_to(
    plan: &Plan,
    mut head: impl FnMut(u32) -> Result<PartHead, ShardError>,
    mut part: impl FnMut(u32) -> Result<PartRead, ShardError>,
    out: &mut impl Write,
    spill_folder: &Path,
) -> Result<WriteReport, ShardError> {
    let mut top = Top::new(plan);
    let mut stamps = Vec::with_capacity(plan.shard_count() as usize);
    for k in 0..plan.shard_count() {
        let PartHead { head, stamp } = head(k)?;
        check_part(
            plan,
            head.plan_id,
            head.index,
            head.roots.iter().map(|r| r.root),
            k,
        )?;
        stamps.push((stamp, head_digest(&head)));
        top.gather(&head)?;
    }
    let top = top.finish()?;
    let mut regions = RegionWriter::new(plan, &top, spill_folder)?;
    for k in 0..plan.shard_count() {
        let read = part(k)?;
        let shard = &read.part;
        check_part(
            plan,
            shard.plan_id,
            shard.index,
            shard.roots.iter().map(|r| r.root),
            k,
        )?;
        // The part is the one whose head the first pass read: the same stamp (a file not
        // rewritten since), and the same head (what a file's skim read, unverified, is the
        // verified part's).
        if (read.stamp(), head_digest(&ShardHead::of(shard))) != stamps[k as usize] {
            return Err(set(format!(
                "shard {k}: its part changed between the merge's two passes"
            )));
        }
        regions.write_part(&top, read.part)?;
    }
    regions.finish(top, out)
}

/// A digest of everything in a part, to tell that both passes read the same one.
fn digest(shard: &ShardPart) -> u64 {
    let mut hasher = Xxh3::new();
    for root in &shard.roots {
        hasher.update(&root.root.to_le_bytes());
        hasher.update(root.top_ids.as_bytes());
        hasher.update(root.top_nodes.as_bytes());
        hasher.update(root.top_triangles.as_bytes());
        hasher.update(root.leaves.as_bytes());
        for region in &root.regions {
            hasher.update(&region.root.to_le_bytes());
            for page in &region.pages {
                match page {
                    RegionPage::Sealed(page) => {
                        for n in [page.raw_length, page.node_count, page.triangle_count] {
                            hasher.update(&n.to_le_bytes());
                        }
                        hasher.update(&page.frame);
                    }
                    RegionPage::Open(page) => {
                        hasher.update(&page.first.to_le_bytes());
                        hasher.update(page.ids.as_bytes());
                        hasher.update(page.nodes.as_bytes());
                        hasher.update(page.triangles.as_bytes());
                    }
                }
            }
            hasher.update(region.degree_histogram.as_bytes());
            hasher.update(&region.max_depth.to_le_bytes());
            for (part, count) in &region.part_triangles {
                hasher.update(&part.to_le_bytes());
                hasher.update(&count.to_le_bytes());
            }
        }
        hash_sums(&mut hasher, &root.sums, &root.sphere);
    }
    hash_cross(&mut hasher, &shard.cross);
    hasher.digest()
}

/// A digest of everything in a part's head: the merge's second pass checks that the whole
/// part it reads has the head its first pass gathered the top from (a head skimmed from a
/// file is not checked against the file's checksum, [`super::read_part_head`]).
fn head_digest(head: &ShardHead) -> u64 {
    let mut hasher = Xxh3::new();
    for root in &head.roots {
        hasher.update(&root.root.to_le_bytes());
        hasher.update(root.top_ids.as_bytes());
        hasher.update(root.top_nodes.as_bytes());
        hasher.update(root.top_triangles.as_bytes());
        hasher.update(root.region_roots.as_bytes());
        hasher.update(&root.region_triangles.to_le_bytes());
        hasher.update(&root.leaves.to_le_bytes());
        hash_sums(&mut hasher, &root.sums, &root.sphere);
    }
    hash_cross(&mut hasher, &head.cross);
    hasher.digest()
}

/// Adds a root's sums and sphere to a digest.
fn hash_sums(hasher: &mut Xxh3, sums: &Accumulator, sphere: &Sphere) {
    let floats = sums
        .quadric
        .a
        .iter()
        .chain(&sums.quadric.b)
        .chain([&sums.quadric.c])
        .chain(&sums.position_sum)
        .chain(&sums.cone.axis)
        .chain([&sums.cone.half_angle]);
    for x in floats {
        hasher.update(&x.to_le_bytes());
    }
    for x in sums
        .vertex_box
        .min
        .iter()
        .chain(&sums.vertex_box.max)
        .chain(&sums.triangle_box.min)
        .chain(&sums.triangle_box.max)
        .chain(&sphere.center)
        .chain([&sphere.radius])
    {
        hasher.update(&x.to_le_bytes());
    }
    if let Some(cone) = &sums.two_sided {
        for x in cone.axis.iter().chain([&cone.half_angle]) {
            hasher.update(&x.to_le_bytes());
        }
    }
}

/// Adds cross corners to a digest.
fn hash_cross(hasher: &mut Xxh3, cross: &[CrossCorner]) {
    for c in cross {
        hasher.update(&c.triangle.to_le_bytes());
        hasher.update(&[c.corner]);
        for n in [c.root, c.rank, c.part, c.owner] {
            hasher.update(&n.to_le_bytes());
        }
    }
}

/// The checks that a part (or its head) of plan `plan_id`, shard `index`, holding `roots`,
/// is the plan's shard `k`, holding the plan's roots.
fn check_part(
    plan: &Plan,
    plan_id: u64,
    index: u32,
    roots: impl ExactSizeIterator<Item = u32>,
    k: u32,
) -> Result<(), ShardError> {
    let expected = plan.shard_roots(k);
    if plan_id != plan.id
        || index != k
        || roots.len() != expected.len()
        || roots.zip(expected).any(|(p, r)| p != r)
    {
        return Err(set(format!("shard {k} does not hold the plan's roots")));
    }
    Ok(())
}

/// A region root: a top node with at most a region's leaves, and children.
#[derive(Debug, Clone, Copy)]
struct Region {
    /// Its id in the top.
    top: u32,
    /// Its shard root (plan index) and its id in that root's subtree.
    root: u32,
    local: u32,
    /// Its first leaf rank: regions follow each other in the file in leaf order.
    leaf_begin: u32,
}

/// Pass 1: the file's top gathered from the plan and the parts.
struct Top<'p> {
    plan: &'p Plan,
    /// The top's nodes: the plan's top nodes under their plan ids, then the top nodes under
    /// the shard roots, each sibling group contiguous. Links are top ids; a region root's
    /// first child is `nodes.len() + ` its index in `regions` once the top is finished.
    nodes: Vec<NodeRecord>,
    /// The sums and sphere each of the plan's top nodes passes up.
    up: Vec<(Accumulator, Sphere)>,
    /// Each shard root's top nodes: (id in its subtree, top id), sorted by the former.
    under_root: Vec<Vec<(u32, u32)>>,
    regions: Vec<Region>,
    /// Subtris of top nodes, by top id.
    triangles: Vec<(u32, TriangleRecord)>,
    /// Subtris of the parts' nodes that lie in regions.
    region_triangles: u64,
    cross: Vec<CrossCorner>,
}

/// The finished top (after pass 1).
struct FinishedTop {
    /// As in [`Top`], with subtri ranges into `triangles` and each region root's first child
    /// a placeholder id: `nodes.len() +` its region's index.
    nodes: Vec<NodeRecord>,
    triangles: Vec<TriangleRecord>,
    layout: PageLayout,
    /// Top id → file id.
    file_id: Vec<u32>,
    /// The plan's top nodes' sums (their spheres are made once the radii are known), and
    /// proxies.
    up: Vec<(Accumulator, Sphere)>,
    proxies: Vec<[f32; 3]>,
    regions: Vec<Region>,
    /// Triangles across roots owned by region nodes: (shard root, id under it, triangle),
    /// sorted as the file stores each node's.
    region_cross: Vec<(u32, u32, TriangleRecord)>,
}

impl<'p> Top<'p> {
    fn new(plan: &'p Plan) -> Top<'p> {
        let nodes = plan
            .top
            .iter()
            .map(|t| node_record(&plan_node(t), None, [0.0; 3]))
            .collect();
        Top {
            plan,
            nodes,
            up: vec![(Accumulator::EMPTY, Sphere::default()); plan.top.len()],
            under_root: vec![Vec::new(); plan.roots.len()],
            regions: Vec::new(),
            triangles: Vec::new(),
            region_triangles: 0,
            cross: Vec::new(),
        }
    }

    /// True when a node's children belong to the top (`PageLayout::top`'s rule).
    fn expands(&self, n: &NodeRecord) -> bool {
        in_top_with_children(
            leaf_count(n),
            self.plan.vertices,
            self.plan.metadata.page_bytes,
        )
    }

    /// Takes what the top needs from one part.
    fn gather(&mut self, shard: &ShardHead) -> Result<(), ShardError> {
        self.cross.extend_from_slice(&shard.cross);
        for root in &shard.roots {
            self.gather_root(root)?;
        }
        Ok(())
    }

    fn gather_root(&mut self, root: &RootHead) -> Result<(), ShardError> {
        let r = root.root;
        let id = self.plan.roots[r as usize];
        let plan_node = &self.plan.top[id as usize];
        self.up[id as usize] = (root.sums, root.sphere);
        let missing = |local: u32| {
            set(format!(
                "shard root {r}: node {local} of its top is missing"
            ))
        };
        let record_of = |local: u32| -> Result<NodeRecord, ShardError> {
            let k = root
                .top_ids
                .binary_search(&local)
                .map_err(|_| missing(local))?;
            Ok(root.top_nodes[k])
        };
        let mut record = record_of(0)?;
        record.parent = U32::new(plan_node.parent);
        self.nodes[id as usize] = record;
        let mut mine = vec![(0u32, id)];
        let mut regions = Vec::new();
        let mut queue = VecDeque::from([(0u32, id)]);
        while let Some((local, at)) = queue.pop_front() {
            let n = record_of(local)?;
            for t in &root.top_triangles[subtris(&n)] {
                self.triangles.push((at, *t));
            }
            if n.child_count == 0 {
                continue;
            }
            if !self.expands(&n) {
                regions.push(Region {
                    top: at,
                    root: r,
                    local,
                    leaf_begin: n.leaf_begin.get(),
                });
                continue;
            }
            let first = self.nodes.len() as u32;
            self.nodes[at as usize].first_child = U32::new(first);
            for c in children(&n) {
                // Children after their parent, each reached once: the walk ends.
                if c <= local || mine.len() >= root.top_ids.len() {
                    return Err(set(format!("shard root {r}: its top is not a tree")));
                }
                let mut child = record_of(c)?;
                child.parent = U32::new(at);
                let child_at = self.nodes.len() as u32;
                self.nodes.push(child);
                mine.push((c, child_at));
                queue.push_back((c, child_at));
            }
        }
        regions.sort_unstable_by_key(|g| g.leaf_begin);
        if regions.len() != root.region_roots.len()
            || regions
                .iter()
                .zip(&root.region_roots)
                .any(|(g, &p)| g.local != p)
        {
            return Err(set(format!(
                "shard root {r}: its regions are not the ones below its top"
            )));
        }
        self.regions.extend(regions);
        mine.sort_unstable();
        self.under_root[r as usize] = mine;
        self.region_triangles += root.region_triangles;
        Ok(())
    }

    /// After every part: the cross triangles joined and placed, the top's subtris grouped, the
    /// plan's top nodes' proxies, and the top's layout.
    fn finish(mut self) -> Result<FinishedTop, ShardError> {
        let plan = self.plan;
        let regions_start = self.nodes.len() as u32;
        self.regions.sort_unstable_by_key(|g| g.leaf_begin);
        for (i, g) in self.regions.iter().enumerate() {
            self.nodes[g.top as usize].first_child = U32::new(regions_start + i as u32);
        }

        let mut cross = std::mem::take(&mut self.cross);
        cross.par_sort_unstable();
        let mut region_cross = Vec::new();
        for corners in cross.chunk_by(|a, b| a.triangle == b.triangle) {
            let t = corners[0].triangle;
            let complete = corners.len() == 3
                && corners
                    .iter()
                    .enumerate()
                    .all(|(k, c)| usize::from(c.corner) == k);
            if !complete || corners.iter().any(|c| c.part != corners[0].part) {
                return Err(set(format!(
                    "triangle {t}: its corners' shards disagree (a part from another build?)"
                )));
            }
            let ranks: [u32; 3] = std::array::from_fn(|k| {
                plan.root_node(corners[k].root).leaf_begin + corners[k].rank
            });
            let triangle = TriangleRecord {
                corners: leading_smallest(ranks).map(U32::new),
                part: U32::new(corners[0].part),
            };
            match corners.iter().find(|c| c.owner != u32::MAX) {
                Some(c) => match top_id_under(&self.under_root, c.root, c.owner) {
                    Some(at) => self.triangles.push((at, triangle)),
                    None => region_cross.push((c.root, c.owner, triangle)),
                },
                None => self.triangles.push((top_owner(plan, ranks), triangle)),
            }
        }
        drop(cross);
        let placed =
            self.triangles.len() as u64 + region_cross.len() as u64 + self.region_triangles;
        if placed != plan.triangles {
            return Err(set(format!(
                "{placed} triangles, the plan has {}",
                plan.triangles
            )));
        }
        region_cross.par_sort_unstable_by_key(|(root, local, t)| {
            (*root, *local, t.corners.map(|c| c.get()), t.part.get())
        });

        // Grouped by node, and within a node in the order the file stores them.
        self.triangles.par_sort_unstable_by_key(|(node, t)| {
            (*node, t.corners.map(|c| c.get()), t.part.get())
        });
        let mut at = 0usize;
        for (id, n) in self.nodes.iter_mut().enumerate() {
            let begin = at;
            while at < self.triangles.len() && self.triangles[at].0 == id as u32 {
                at += 1;
            }
            n.subtri_begin = U32::new(begin as u32);
            n.subtri_count = U32::new((at - begin) as u32);
        }
        let triangles: Vec<TriangleRecord> = self.triangles.into_iter().map(|(_, t)| t).collect();

        // The plan's top nodes' sums and proxies, children (later ids) first.
        let isa = Isa::detect();
        let mut proxies = vec![[0.0f32; 3]; plan.top.len()];
        for (id, t, family) in inner_plan_nodes(plan) {
            let mut sum = self.up[family.start].0;
            for child in family.start + 1..family.end {
                let (child_sum, _) = self.up[child];
                absorb_on(isa, &mut sum, &child_sum);
            }
            proxies[id] = inner_proxy(&plan_node(t), &sum);
            self.up[id].0 = sum;
        }

        let layout = PageLayout::top(&self.nodes, plan.metadata.page_bytes);
        let mut file_id = vec![NO_NODE; self.nodes.len()];
        for (k, id) in layout.nodes().enumerate() {
            file_id[id as usize] = k as u32;
        }
        if layout.node_count() != self.nodes.len() || file_id.contains(&NO_NODE) {
            return Err(set(
                "the parts' top nodes do not form the top of a tree".into()
            ));
        }
        Ok(FinishedTop {
            nodes: self.nodes,
            triangles,
            layout,
            file_id,
            up: self.up,
            proxies,
            regions: self.regions,
            region_cross,
        })
    }
}

/// The top id of the node `local` under shard root `root`, if it is a top node.
fn top_id_under(under_root: &[Vec<(u32, u32)>], root: u32, local: u32) -> Option<u32> {
    let mine = under_root.get(root as usize)?;
    let k = mine.binary_search_by_key(&local, |&(l, _)| l).ok()?;
    Some(mine[k].1)
}

/// The plan's top nodes that are not roots, children first (the plan numbers children after
/// their parents): each id, node and its children's ids.
fn inner_plan_nodes(
    plan: &Plan,
) -> impl Iterator<Item = (usize, &TopNode, std::ops::Range<usize>)> {
    plan.top
        .iter()
        .enumerate()
        .rev()
        .filter(|(_, t)| t.root.is_none())
        .map(|(id, t)| {
            let first = t.first_child as usize;
            (id, t, first..first + usize::from(t.child_count))
        })
}

/// The builder's node for one of the plan's top nodes (links are plan ids, which are top ids).
fn plan_node(t: &TopNode) -> Node {
    Node {
        first_child: t.first_child,
        child_count: t.child_count,
        ..Node::topology(t.leaf_begin, t.leaf_end, t.parent, t.depth)
    }
}

/// Pass 2: each part's regions, copied or encoded, and spilled.
struct RegionWriter<'p> {
    plan: &'p Plan,
    spill: BufWriter<std::fs::File>,
    /// Where the spill lives, for errors.
    spill_folder: std::path::PathBuf,
    /// Directory entries of the spilled pages, in order.
    pages: Vec<EncodedPageSummary>,
    /// File id of the next region node.
    next_node: u64,
    /// File id of each region's first node (its root's first child).
    region_first: Vec<u32>,
    /// Regions written so far (they come in leaf order, so in part order).
    regions_done: usize,
    /// Cross triangles placed so far.
    cross_done: usize,
    /// Squared distance to the farthest leaf, for each of the plan's top nodes.
    farthest: Vec<f64>,
    /// Over the nodes and triangles of the regions: for the metadata and header.
    degree_histogram: [u64; 9],
    max_depth: u32,
    part_counts: PartCounts,
}

impl<'p> RegionWriter<'p> {
    fn new(
        plan: &'p Plan,
        top: &FinishedTop,
        spill_folder: &Path,
    ) -> Result<RegionWriter<'p>, ShardError> {
        let spill = tempfile::tempfile_in(spill_folder).map_err(|source| ShardError::Io {
            path: spill_folder.to_path_buf(),
            source,
        })?;
        Ok(RegionWriter {
            plan,
            spill: BufWriter::new(spill),
            spill_folder: spill_folder.to_path_buf(),
            pages: Vec::new(),
            next_node: top.nodes.len() as u64,
            region_first: vec![0; top.regions.len()],
            regions_done: 0,
            cross_done: 0,
            farthest: vec![0.0; plan.top.len()],
            degree_histogram: [0; 9],
            max_depth: 0,
            part_counts: PartCounts::new(plan.metadata.part_names.len()),
        })
    }

    /// Numbers the regions of one part and spills their pages: sealed pages copied (a
    /// region's first page rebased), open pages encoded with the triangles across shards that
    /// their nodes own. The pages are numbered in order, made side by side, and spilled in
    /// order.
    fn write_part(&mut self, top: &FinishedTop, shard: ShardPart) -> Result<(), ShardError> {
        let level = self.plan.metadata.zstd_level;
        // Each page with what makes it: its shard root, its region's first node and parent,
        // and whether it is its region's first.
        let mut jobs = Vec::new();
        for root in shard.roots {
            let r = root.root;
            self.widen_radii(&top.proxies, self.plan.root_node(r), &root.leaves);
            drop(root.leaves);
            for region in root.regions {
                let changed = || set(format!("shard root {r}: its part changed between passes"));
                let g = *top.regions.get(self.regions_done).ok_or_else(changed)?;
                if (g.root, g.local) != (r, region.root) {
                    return Err(changed());
                }
                let too_many = || set("more nodes than a file holds".into());
                let first_node = u32::try_from(self.next_node).map_err(|_| too_many())?;
                self.region_first[self.regions_done] = first_node;
                let parent = top.file_id[g.top as usize];
                for (k, page) in region.pages.into_iter().enumerate() {
                    let nodes = match &page {
                        RegionPage::Sealed(page) => page.node_count,
                        RegionPage::Open(page) => {
                            let k = (self.next_node - u64::from(first_node)) as usize;
                            if page.first != detached_id(k) {
                                return Err(changed());
                            }
                            page.ids.len() as u32
                        }
                    };
                    self.next_node += u64::from(nodes);
                    if self.next_node > u64::from(u32::MAX) {
                        return Err(too_many());
                    }
                    jobs.push((r, first_node, parent, k == 0, nodes, page));
                }
                for (total, n) in self
                    .degree_histogram
                    .iter_mut()
                    .zip(region.degree_histogram)
                {
                    *total += n;
                }
                self.max_depth = self.max_depth.max(region.max_depth);
                for (part, count) in region.part_triangles {
                    self.part_counts.add(part, count);
                }
                self.regions_done += 1;
            }
        }
        let plan = self.plan;
        let made: Vec<Result<MadePage, ShardError>> = jobs
            .into_par_iter()
            .map(|(r, first_node, parent, first, nodes, page)| {
                let (page, cross_parts) = match page {
                    RegionPage::Sealed(page) if first => {
                        (attach_region(&page, first_node, parent, level)?, Vec::new())
                    }
                    RegionPage::Sealed(page) => (page, Vec::new()),
                    RegionPage::Open(page) => encode_open(plan, top, r, first_node, parent, page)?,
                };
                Ok(MadePage {
                    page,
                    nodes,
                    cross_parts,
                })
            })
            .collect();
        for made in made {
            let MadePage {
                page,
                nodes,
                cross_parts,
            } = made?;
            if page.node_count != nodes {
                return Err(set("a page's node count changed as it was made".into()));
            }
            self.cross_done += cross_parts.len();
            for part in cross_parts {
                self.part_counts.add(part, 1);
            }
            self.spill_page(&page)?;
        }
        Ok(())
    }

    fn spill_page(&mut self, page: &EncodedPage) -> Result<(), ShardError> {
        self.spill
            .write_all(&page.frame)
            .map_err(|source| ShardError::Io {
                path: self.spill_folder.clone(),
                source,
            })?;
        self.pages.push(page.summary());
        Ok(())
    }

    /// Widens the error radii of the plan's top nodes above `plan_node` by its leaves.
    fn widen_radii(&mut self, proxies: &[[f32; 3]], plan_node: &TopNode, leaves: &[[f32; 3]]) {
        let mut above = Vec::new();
        let mut at = plan_node.parent;
        while at != u32::MAX {
            above.push(at as usize);
            at = self.plan.top[at as usize].parent;
        }
        let proxies: Vec<[f32; 3]> = above.iter().map(|&a| proxies[a]).collect();
        let farthest = leaves
            .par_iter()
            .fold(
                || vec![0.0f64; above.len()],
                |mut far, &leaf| {
                    for (f, &p) in far.iter_mut().zip(&proxies) {
                        *f = f.max(leaf_distance_squared(p, leaf));
                    }
                    far
                },
            )
            .reduce(
                || vec![0.0f64; above.len()],
                |a, b| a.iter().zip(&b).map(|(x, y)| x.max(*y)).collect(),
            );
        for (&a, f) in above.iter().zip(farthest) {
            self.farthest[a] = self.farthest[a].max(f);
        }
    }

    /// After every part: the plan's top nodes' bounds, the top's pages, and the file.
    fn finish(mut self, top: FinishedTop, out: &mut impl Write) -> Result<WriteReport, ShardError> {
        let plan = self.plan;
        if self.regions_done != top.regions.len() || self.cross_done != top.region_cross.len() {
            return Err(set("the parts changed between the merge's passes".into()));
        }
        let FinishedTop {
            mut nodes,
            triangles,
            layout,
            file_id,
            mut up,
            proxies,
            ..
        } = top;
        // The plan's top nodes' bounds, children (later ids) first.
        for (id, t, family) in inner_plan_nodes(plan) {
            let spheres: Vec<Sphere> = up[family].iter().map(|&(_, s)| s).collect();
            let (bounds, sphere) = inner_bounds(
                proxies[id],
                self.farthest[id],
                spheres.into_iter(),
                &up[id].0,
            );
            up[id].1 = sphere;
            let (begin, count) = (nodes[id].subtri_begin, nodes[id].subtri_count);
            nodes[id] = node_record(&plan_node(t), Some(&bounds), [0.0; 3]);
            nodes[id].subtri_begin = begin;
            nodes[id].subtri_count = count;
        }
        for n in &nodes {
            self.degree_histogram[usize::from(n.child_count).min(8)] += 1;
            self.max_depth = self.max_depth.max(u32::from(n.depth.get()));
        }
        for t in &triangles {
            self.part_counts.add(t.part.get(), 1);
        }
        let regions_start = nodes.len() as u32;
        let region_first = &self.region_first;
        let top_pages = encode_pages(
            &nodes,
            &triangles,
            &layout,
            &|id| {
                if id < regions_start {
                    file_id[id as usize]
                } else {
                    region_first[(id - regions_start) as usize]
                }
            },
            0,
            &plan.grid(),
            plan.metadata.zstd_level,
        )?;
        let metadata = metadata(plan, &nodes[0], &self.part_counts, self.degree_histogram);
        let mut summaries: Vec<_> = top_pages.iter().map(EncodedPage::summary).collect();
        summaries.append(&mut self.pages);
        let figures = FileFigures {
            vertex_count: u64::from(plan.vertices),
            max_depth: self.max_depth,
            grid: plan.grid(),
            metadata: &metadata,
        };
        let (head, report) = file_head(&summaries, &figures)?;
        let write_error = |source| ShardError::Write(source);
        out.write_all(&head).map_err(write_error)?;
        for page in &top_pages {
            out.write_all(&page.frame).map_err(write_error)?;
        }
        let spill_error = |source| ShardError::Io {
            path: self.spill_folder.clone(),
            source,
        };
        let mut spill = self
            .spill
            .into_inner()
            .map_err(|e| spill_error(e.into_error()))?;
        spill.rewind().map_err(spill_error)?;
        let copied = std::io::copy(&mut spill, out).map_err(write_error)?;
        let spilled: u64 = summaries[top_pages.len()..]
            .iter()
            .map(|p| u64::from(p.compressed_length))
            .sum();
        if copied != spilled {
            return Err(spill_error(std::io::Error::other(
                "the temporary file of pages is shorter than what was written to it",
            )));
        }
        Ok(report)
    }
}

/// A page of a region as pass 2 made it, with the node count its numbering gave it and the
/// parts of the triangles across shards it took.
struct MadePage {
    page: EncodedPage,
    nodes: u32,
    cross_parts: Vec<u32>,
}

/// Encodes an open page of the region numbered from `first_node` under the top node `parent`
/// (shard root `r`) of `plan`'s merge, with the triangles across shards that its nodes own;
/// returns it with the parts of those triangles.
fn encode_open(
    plan: &Plan,
    top: &FinishedTop,
    r: u32,
    first_node: u32,
    parent: u32,
    page: OpenPage,
) -> Result<(EncodedPage, Vec<u32>), ShardError> {
    let bad = || {
        set(format!(
            "shard root {r}: an open page's links leave its region"
        ))
    };
    let file_id = |id: u32| attached_id(id, first_node, parent).ok_or_else(bad);
    let n0 = file_id(page.first)?;
    let mut records = Vec::with_capacity(page.nodes.len());
    let mut triangles = Vec::with_capacity(page.triangles.len());
    let mut cross_parts = Vec::new();
    let cross = &top.region_cross;
    for (j, (&id, n)) in page.ids.iter().zip(&page.nodes).enumerate() {
        let at = u64::from(n0) + j as u64;
        let mut m = *n;
        // Parents before their children, children after: the encoder's steps hold.
        let p = file_id(n.parent.get())?;
        if u64::from(p) >= at {
            return Err(bad());
        }
        m.parent = U32::new(p);
        if n.child_count > 0 {
            let c = file_id(n.first_child.get())?;
            if u64::from(c) <= at {
                return Err(bad());
            }
            m.first_child = U32::new(c);
        }
        let begin = triangles.len();
        triangles.extend_from_slice(page.triangles.get(subtris(n)).ok_or_else(bad)?);
        let from = cross.partition_point(|(cr, cl, _)| (*cr, *cl) < (r, id));
        let to = cross.partition_point(|(cr, cl, _)| (*cr, *cl) <= (r, id));
        for (_, _, t) in &cross[from..to] {
            triangles.push(*t);
            cross_parts.push(t.part.get());
        }
        if to > from {
            triangles[begin..].sort_unstable_by_key(|t| (t.corners.map(|c| c.get()), t.part.get()));
        }
        m.subtri_count = U32::new((triangles.len() - begin) as u32);
        records.push(m);
    }
    let page = encode_page_frame(
        &plan.grid(),
        n0,
        &records,
        &triangles,
        plan.metadata.zstd_level,
    )?;
    Ok((page, cross_parts))
}

/// The top node a triangle with corners under three roots is a subtri of: the deepest one
/// supporting two of its corners (leaf ranks), found as [`crate::VertexTree::subtri_node`]
/// does, from the middle corner's root.
fn top_owner(plan: &Plan, mut ranks: [u32; 3]) -> u32 {
    ranks.sort_unstable();
    let top = &plan.top;
    let mut node = 0usize;
    while top[node].root.is_none() {
        let t = &top[node];
        let children = t.first_child as usize..t.first_child as usize + usize::from(t.child_count);
        node = children
            .into_iter()
            .find(|&c| top[c].leaf_begin <= ranks[1] && ranks[1] < top[c].leaf_end)
            .expect("children partition their parent's ranks");
    }
    loop {
        let t = &top[node];
        if t.leaf_begin <= ranks[0] || t.leaf_end > ranks[2] {
            return node as u32;
        }
        node = t.parent as usize;
    }
}

/// The metadata `vds-build` writes for an in-memory build of the plan's input, with the
/// root's record and the counts taken over the whole tree.
fn metadata(
    plan: &Plan,
    root: &NodeRecord,
    part_counts: &PartCounts,
    degree_histogram: [u64; 9],
) -> Metadata {
    let m = &plan.metadata;
    let parts = part_counts.records(|i| {
        let (parent, color) = m.parts.get(i).copied().unwrap_or_default();
        (parent, color.map(|c| c.map(f32::from_bits)))
    });
    let (center, radius) = if root.child_count == 0 {
        (root.proxy.map(|c| c.get()), 0.0)
    } else {
        let s = root.sphere.map(|c| c.get());
        ([s[0], s[1], s[2]], s[3])
    };
    Metadata {
        tool: m.tool.clone(),
        build: BuildInfo {
            weld: None,
            zstd_level: m.zstd_level,
            page_bytes: m.page_bytes,
        },
        inputs: m
            .inputs
            .iter()
            .map(|(name, bytes, content_hash)| InputInfo {
                name: name.clone(),
                bytes: *bytes,
                content_hash: *content_hash,
            })
            .collect(),
        part_names: m.part_names.clone(),
        parts,
        bounds_min: [0, 1, 2].map(|k| center[k] - radius),
        bounds_max: [0, 1, 2].map(|k| center[k] + radius),
        input_vertices: m.input_vertices,
        input_triangles: m.input_triangles,
        degree_histogram,
    }
}
