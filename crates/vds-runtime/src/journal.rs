//! Rank tracking's journal of node changes: which nodes changed state since the cut's last
//! change report ([`crate::Cut::take_changes`]), with their states then and now.
//!
//! A renderer that mirrors a rank-tracked cut needs, per report, the nodes that became active
//! or left it and those that joined or left the boundary. A node can change several times
//! between reports (unfolded, then folded again), so the report compares its state at the
//! last report with its state now, and a node back where it was is no change.

use crate::cut::NodeState;
use crate::store::NodeLabel;

/// One entry of the [`Journal`]: a node, its state at the last change report and now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct JournalEntry {
    pub(crate) id: u32,
    pub(crate) before: NodeState,
    pub(crate) now: NodeState,
    /// The node's subtri count, once it was noted going to or from active (0 before): what
    /// the report counts as triangles added or removed if it is active now and was not then,
    /// or the reverse.
    pub(crate) subtris: u32,
}

/// Rank tracking: the nodes whose state changed since the last change report, each with its
/// state then and now.
///
/// A node's label holds the index of its entry ([`NodeLabel::head`]), so a change updates the
/// entry in place and the report reads the entries alone: it never goes back to the labels,
/// a look-up at random per changed node. An index is the node's only while the entry at it
/// names the node: the journal empties at each report, so nothing need be cleared.
#[derive(Debug, Default)]
pub(crate) struct Journal {
    entries: Vec<JournalEntry>,
    /// The store's eviction count at the last report: a node whose page was evicted (all its
    /// nodes inactive, which the journal saw) and loaded again since starts a second entry
    /// with a fresh label.
    evictions_at_take: u64,
}

impl Journal {
    /// Records node `id` going from `was` to `now`; `label` is its label, and `subtris` its
    /// subtri count when it goes to or from active (else 0).
    #[inline]
    pub(crate) fn note(
        &mut self,
        id: u32,
        label: &mut NodeLabel,
        was: NodeState,
        now: NodeState,
        subtris: u32,
    ) {
        match self.entries.get_mut(label.head as usize) {
            Some(entry) if entry.id == id => {
                entry.now = now;
                entry.subtris = entry.subtris.max(subtris);
            }
            _ => {
                label.head = self.entries.len() as u32;
                self.entries.push(JournalEntry {
                    id,
                    before: was,
                    now,
                    subtris,
                });
            }
        }
    }

    /// Bytes the journal holds, by capacity.
    pub(crate) fn held_bytes(&self) -> usize {
        self.entries.capacity() * size_of::<JournalEntry>()
    }

    /// The entries since the last report, in the order recorded.
    pub(crate) fn entries(&self) -> &[JournalEntry] {
        &self.entries
    }

    /// Takes back the vector [`Journal::take`] handed out, emptied, for its memory.
    pub(crate) fn recycle(&mut self, entries: Vec<JournalEntry>) {
        debug_assert!(entries.is_empty(), "recycled entries were not emptied");
        debug_assert!(self.entries.is_empty(), "the journal was not taken");
        self.entries = entries;
    }

    /// The entries since the last report, one per node (`evictions`: the store's eviction
    /// count now), leaving the journal empty.
    pub(crate) fn take(&mut self, evictions: u64) -> Vec<JournalEntry> {
        let mut entries = std::mem::take(&mut self.entries);
        if evictions != std::mem::replace(&mut self.evictions_at_take, evictions) {
            // A node listed twice: its state before is its first entry's, now its last's.
            let mut merged_at: rustc_hash::FxHashMap<u32, usize> = Default::default();
            let mut merged: Vec<JournalEntry> = Vec::with_capacity(entries.len());
            for entry in entries.drain(..) {
                match merged_at.entry(entry.id) {
                    std::collections::hash_map::Entry::Occupied(at) => {
                        let first = &mut merged[*at.get()];
                        first.now = entry.now;
                        first.subtris = first.subtris.max(entry.subtris);
                    }
                    std::collections::hash_map::Entry::Vacant(slot) => {
                        slot.insert(merged.len());
                        merged.push(entry);
                    }
                }
            }
            entries = merged;
        }
        entries
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use NodeState::{Active, Boundary, Inactive};

    fn label() -> NodeLabel {
        NodeLabel::INACTIVE
    }

    fn entry(id: u32, before: NodeState, now: NodeState, subtris: u32) -> JournalEntry {
        JournalEntry {
            id,
            before,
            now,
            subtris,
        }
    }

    #[test]
    fn a_node_changed_twice_is_one_entry_from_its_first_state_to_its_last() {
        let mut journal = Journal::default();
        let (mut a, mut b) = (label(), label());
        journal.note(7, &mut a, Boundary, Active, 4);
        journal.note(9, &mut b, Inactive, Boundary, 0);
        journal.note(7, &mut a, Active, Boundary, 4);
        assert_eq!(
            journal.take(0),
            vec![
                entry(7, Boundary, Boundary, 4),
                entry(9, Inactive, Boundary, 0)
            ]
        );
        // The labels still hold their old indices, which name no entry after the report.
        journal.note(9, &mut b, Boundary, Inactive, 0);
        assert_eq!(journal.take(0), vec![entry(9, Boundary, Inactive, 0)]);
    }

    #[test]
    fn a_stale_index_naming_another_node_starts_a_new_entry() {
        let mut journal = Journal::default();
        let (mut a, mut b) = (label(), label());
        journal.note(1, &mut a, Inactive, Boundary, 0);
        let _ = journal.take(0);
        // `a` still holds index 0; node 2 now owns entry 0.
        journal.note(2, &mut b, Inactive, Boundary, 0);
        journal.note(1, &mut a, Boundary, Active, 3);
        assert_eq!(
            journal.take(0),
            vec![
                entry(2, Inactive, Boundary, 0),
                entry(1, Boundary, Active, 3)
            ]
        );
    }

    #[test]
    fn a_node_whose_page_was_evicted_between_reports_is_reported_once() {
        let mut journal = Journal::default();
        let mut a = label();
        journal.note(5, &mut a, Active, Boundary, 6);
        journal.note(5, &mut a, Boundary, Inactive, 0);
        // Its page is evicted and read again: a fresh label, a second entry.
        let mut fresh = label();
        journal.note(5, &mut fresh, Inactive, Boundary, 0);
        journal.note(5, &mut fresh, Boundary, Active, 6);
        assert_eq!(journal.take(1), vec![entry(5, Active, Active, 6)]);
        // Without an eviction since the last report, entries are taken as they are.
        journal.note(5, &mut label(), Active, Boundary, 6);
        assert_eq!(journal.take(1), vec![entry(5, Active, Boundary, 6)]);
    }
}
