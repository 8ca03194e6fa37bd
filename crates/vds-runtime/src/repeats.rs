//! Same-winding repeats: active triangles whose three current corners are another active
//! triangle's, in the same cyclic order.
//!
//! A cut can hold them whatever the tree: two triangles of a thin tube, of a CAD face and its
//! coincident copy, or of a stack of folded layers can land on the same three boundary nodes.
//! Each is drawn over the other and adds nothing to the picture, so a cut draws one triangle
//! of each *class* (active triangles with the same corners up to rotation) and counts it once
//! against a triangle budget. The one drawn is the member with the smallest triangle index,
//! so what is drawn depends on the cut alone, not on the changes that made it.
//!
//! ## Which triangles can repeat
//! Two facts keep the search small.
//! - **Repeats are subtris of one node.** A triangle's node is the deepest of its corners'
//!   pairwise lowest common ancestors, and while it is active the common ancestor of two
//!   original corners is the common ancestor of the boundary nodes above them. So the node
//!   depends on the current corners alone, and two triangles with the same current corners
//!   are subtris of the same node `S`.
//! - **Repeats stay repeats in coarser cuts.** Folding moves both triangles' corners to the
//!   same ancestors. The coarsest cut in which the subtris of `S` are active unfolds exactly
//!   `S` and its ancestors; call it `S`'s own cut. Two subtris of `S` that differ there differ
//!   in every cut.
//!
//! So when `S` unfolds, its subtris' corners in its own cut are worked out (a corner under
//! `S` is the child of `S` holding it; another is the child holding it of the deepest
//! ancestor of `S` that supports it) and the subtris are sorted into *groups* of equal
//! corners there. Almost every group is a single triangle, which can never repeat and is
//! never looked at again. The few groups of two or more are kept with `S` while it stays
//! unfolded, and when a member's corners move, its group's members are compared again: a
//! member is hidden when a member with a smaller triangle index has the same corners now.
//! A frame pays for repeats only where they can happen. With rank tracking a member's corners
//! are kept from one comparison to the next with the leaf ranks they stand for, and only the
//! corners whose rank a fold or unfold moved are brought up to date, from where they were.

use rustc_hash::FxHashMap;

use crate::store::Node;

/// What a subtri's corners are in its node's own cut, as far as that is cheap to find: a
/// corner under the node is the child holding it, one under the node's parent the sibling
/// holding it (from the children's and siblings' first leaf ranks, read once per node), and
/// one further out stands as [`crate::cut::NIL`], which never equals an exact corner. Two
/// subtris whose [`OwnCut::signature`]s differ therefore differ in the own cut, and cannot
/// repeat.
///
/// The node and its parent must be checked (`NodeStore::check_and_bound`): their children
/// then partition their leaf ranges, so `children[0]` and `siblings[0]` are the node's and
/// the parent's first leaf ranks, and every rank looked up has a child at or below it.
pub(crate) struct OwnCut<'a> {
    /// The node whose subtris these are.
    pub(crate) node: &'a Node,
    /// The first leaf ranks of its children, in order.
    pub(crate) children: &'a [u32],
    /// Its parent's leaf range (empty for the root).
    pub(crate) parent_ranks: std::ops::Range<u32>,
    /// Its parent's first child.
    pub(crate) parent_first: u32,
    /// The first leaf ranks of its parent's children, in order.
    pub(crate) siblings: &'a [u32],
}

impl OwnCut<'_> {
    /// The child of the node that holds `rank`, which the node must support.
    #[inline]
    pub(crate) fn child_of(&self, rank: u32) -> u32 {
        self.node.first_child + self.children.partition_point(|&b| b <= rank) as u32 - 1
    }

    /// A subtri's corners (leaf ranks) as far as they are known in the own cut, sorted.
    #[inline]
    pub(crate) fn signature(&self, leaves: [u32; 3]) -> [u32; 3] {
        let mut signature = leaves.map(|r| {
            if self.node.supports_rank(r) {
                self.child_of(r)
            } else if self.parent_ranks.contains(&r) {
                self.parent_first + self.siblings.partition_point(|&b| b <= r) as u32 - 1
            } else {
                crate::cut::NIL
            }
        });
        signature.sort_unstable();
        signature
    }

    /// The groups ([`groups_of`]) of the node's subtris `corners`, subtri `k` being triangle
    /// `first + k`: each subtri's [`OwnCut::signature`] first, then, for those that share
    /// one, their exact corners, a corner outside the node given by `outside(rank)`. `None`
    /// when `outside` does not know a corner. `signatures` and `candidates` are scratch.
    pub(crate) fn groups(
        &self,
        first: u32,
        corners: &[[u32; 3]],
        mut outside: impl FnMut(u32) -> Option<u32>,
        signatures: &mut Vec<([u32; 3], u32)>,
        candidates: &mut Vec<([u32; 3], u32)>,
    ) -> Option<Vec<Vec<u32>>> {
        signatures.clear();
        signatures.extend(
            (0..)
                .zip(corners)
                .map(|(k, &leaves)| (self.signature(leaves), k)),
        );
        signatures.sort_unstable();
        candidates.clear();
        for shared in signatures
            .chunk_by(|a, b| a.0 == b.0)
            .filter(|s| s.len() > 1)
        {
            for &(_, k) in shared {
                let mut exact = [0; 3];
                for (e, &r) in exact.iter_mut().zip(&corners[k as usize]) {
                    *e = if self.node.supports_rank(r) {
                        self.child_of(r)
                    } else {
                        outside(r)?
                    };
                }
                candidates.push((exact, first + k));
            }
        }
        Some(groups_of(candidates))
    }
}

/// `corners` rotated to start at the smallest node id: equal for two triangles with the same
/// corners and winding, different for a triangle and its reverse.
#[inline]
pub(crate) fn key(corners: [u32; 3]) -> [u32; 3] {
    let [a, b, c] = corners;
    if a <= b && a <= c {
        [a, b, c]
    } else if b <= c {
        [b, c, a]
    } else {
        [c, a, b]
    }
}

/// The groups of subtris of the unfolded nodes that have any, and the nodes whose groups must
/// be compared again.
#[derive(Debug, Default)]
pub(crate) struct Repeats {
    /// For each unfolded node with groups, its groups: triangle indices, ascending within a
    /// group, each group of two or more.
    pub groups: FxHashMap<u32, Vec<Vec<u32>>>,
    /// Rank tracking: for each node in `groups` whose groups have been compared, its
    /// members' corners at that comparison, in the order of its groups' members.
    pub corners: FxHashMap<u32, Vec<MemberCorners>>,
    /// Rank tracking: (node, leaf rank) for each corner of a node's grouped subtris whose
    /// current node changed since the last comparison (repeated when it changed again).
    pub moved: Vec<(u32, u32)>,
    /// Nodes whose grouped subtris' corners moved since their groups were last compared.
    pub dirty: Vec<u32>,
    /// Active triangles hidden as repeats.
    pub hidden: u32,
}

impl Repeats {
    /// Bytes held (by capacity; the map by entries and control bytes).
    pub fn bytes(&self) -> u64 {
        let map = self.groups.capacity() * (size_of::<(u32, Vec<Vec<u32>>)>() + 1);
        let groups: usize = self
            .groups
            .values()
            .map(|g| {
                g.capacity() * size_of::<Vec<u32>>()
                    + g.iter().map(|m| m.capacity() * 4).sum::<usize>()
            })
            .sum();
        let corners = self.corners.capacity() * (size_of::<(u32, Vec<MemberCorners>)>() + 1)
            + self
                .corners
                .values()
                .map(|c| c.capacity() * size_of::<MemberCorners>())
                .sum::<usize>();
        let lists = self.dirty.capacity() * 4 + self.moved.capacity() * 8;
        (map + groups + corners + lists) as u64
    }
}

/// Rank tracking: a group member's corners at the last comparison of its group.
#[derive(Debug, Clone, Copy)]
pub(crate) struct MemberCorners {
    /// Its original corners (leaf ranks).
    pub leaves: [u32; 3],
    /// The boundary nodes that stood for them then.
    pub nodes: [u32; 3],
}

/// Sorts subtris, given as (corners in their node's own cut, triangle index) in increasing
/// triangle index, into groups of equal corners; returns the groups of two or more, each in
/// increasing triangle index.
pub(crate) fn groups_of(subtris: &mut [([u32; 3], u32)]) -> Vec<Vec<u32>> {
    for s in subtris.iter_mut() {
        s.0 = key(s.0);
    }
    subtris.sort_unstable();
    subtris
        .chunk_by(|a, b| a.0 == b.0)
        .filter(|group| group.len() > 1)
        .map(|group| group.iter().map(|&(_, t)| t).collect())
        .collect()
}

/// Which members of a group are hidden, given each member's current corners in increasing
/// triangle index: those whose corners an earlier member already has.
pub(crate) fn hidden_members(corners: &[[u32; 3]]) -> impl Iterator<Item = bool> + '_ {
    corners
        .iter()
        .enumerate()
        .map(|(i, &c)| corners[..i].iter().any(|&earlier| key(earlier) == key(c)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_keep_the_winding_and_ignore_the_rotation() {
        assert_eq!(key([5, 2, 9]), [2, 9, 5]);
        assert_eq!(key([9, 5, 2]), [2, 9, 5]);
        assert_eq!(key([2, 9, 5]), [2, 9, 5]);
        assert_ne!(key([2, 5, 9]), key([2, 9, 5]));
    }

    #[test]
    fn groups_hold_two_or_more_equal_rotations() {
        let mut subtris = [
            ([1, 2, 3], 10),
            ([7, 8, 9], 11),
            ([2, 3, 1], 12),
            ([3, 2, 1], 13),
            ([3, 1, 2], 14),
        ];
        assert_eq!(groups_of(&mut subtris), vec![vec![10, 12, 14]]);
    }

    #[test]
    fn later_members_with_earlier_corners_are_hidden() {
        let corners = [[4, 5, 6], [5, 6, 4], [6, 5, 4], [4, 5, 6]];
        let hidden: Vec<bool> = hidden_members(&corners).collect();
        assert_eq!(hidden, [false, true, false, true]);
    }
}
