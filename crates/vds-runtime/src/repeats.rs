//! Same-winding repeats: active triangles whose three current corners are another active
//! triangle's, in the same cyclic order.
//!
//! A cut can hold them whatever the tree: two triangles of a thin tube, of a CAD face and its
//! coincident copy, or of a stack of folded layers can land on the same three boundary nodes.
//! Each is drawn over the other and adds nothing to the picture, so a cut shows one triangle
//! of each *class* (active triangles with the same corners up to rotation) and counts it once
//! against a triangle budget. The one shown is the class member with the smallest triangle
//! index, so what is drawn depends on the cut alone, not on the order of the changes that
//! made it (the two corner-tracking strategies agree).
//!
//! This module owns the classes: a map from each class's key (its corners rotated to start at
//! the smallest node id, which keeps the winding) to its member count and shown slot. The cut
//! ([`crate::cut`]) keeps it current as corners change, and marks each slot shown or hidden.

use std::collections::hash_map::Entry;

use rustc_hash::FxHashMap;

use crate::cut::NIL;

/// A class's key: `corners` rotated to start at the smallest node id (the winding is kept, so
/// a triangle and its reverse are different classes).
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

/// One class of active triangles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Class {
    /// Active triangles in the class.
    pub count: u32,
    /// The slot of the member shown, or [`NIL`] while it is being chosen again (its shown
    /// member left during a fold or unfold).
    pub shown: u32,
}

/// Whether a slot's triangle is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub(crate) enum Visibility {
    /// In no class: a free slot, or a triangle whose corners are being rewritten (or, with
    /// lazy tracking, placed since the last refresh).
    Detached = 0,
    /// The member of its class that is drawn and counted.
    Shown = 1,
    /// Another member of a class: kept in the cut, not drawn, not counted.
    Hidden = 2,
}

/// The classes of the active triangles, and the bookkeeping of one fold or unfold.
#[derive(Debug, Default)]
pub(crate) struct Repeats {
    /// Every class, by key.
    pub classes: FxHashMap<[u32; 3], Class>,
    /// Slots marked [`Visibility::Hidden`].
    pub hidden: u32,
    /// Slots detached while their corners are rewritten, to attach again once they are done.
    pub detached: Vec<u32>,
    /// Keys of classes whose shown member left; their member to show is chosen once the fold
    /// or unfold is done (the incidence lists are consistent only then).
    pub orphans: Vec<[u32; 3]>,
}

impl Repeats {
    /// A new class for a first member in `slot`, or the class `key` grown by one. Returns
    /// the slot shown before (or [`NIL`]) when the class already existed.
    pub fn join(&mut self, key: [u32; 3], slot: u32) -> Option<u32> {
        // One look-up either way (the entry API): most classes are born and die single.
        match self.classes.entry(key) {
            Entry::Occupied(mut class) => {
                let class = class.get_mut();
                class.count += 1;
                Some(class.shown)
            }
            Entry::Vacant(vacant) => {
                vacant.insert(Class {
                    count: 1,
                    shown: slot,
                });
                None
            }
        }
    }

    /// Removes a member in `slot` from class `key`: the class goes when it empties, and is
    /// orphaned when `slot` was its shown member.
    pub fn leave(&mut self, key: [u32; 3], slot: u32) {
        let Entry::Occupied(mut entry) = self.classes.entry(key) else {
            unreachable!("an attached slot's class exists");
        };
        let class = entry.get_mut();
        class.count -= 1;
        if class.count == 0 {
            entry.remove();
        } else if class.shown == slot {
            class.shown = NIL;
            self.orphans.push(key);
        }
    }

    /// Bytes held (by capacity; the map by entries and control bytes).
    pub fn bytes(&self) -> u64 {
        let map = self.classes.capacity() * (size_of::<([u32; 3], Class)>() + 1);
        let lists = self.detached.capacity() * size_of::<u32>()
            + self.orphans.capacity() * size_of::<[u32; 3]>();
        (map + lists) as u64
    }
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
}
