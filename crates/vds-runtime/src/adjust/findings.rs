//! What the threshold pass's first step finds: every active entry tested as the cut stands,
//! and the children of each group whose bound failed read from the store and tested one by
//! one, before anything is acted on (the second step acts on what is found). The tests read
//! the store and write nothing but each entry's own record and what is pending for it, so
//! shares of the list are tested on several threads.

use super::{AdjustStats, Adjuster, LOOKAHEAD, PREFETCH_RATIO, Pass};
use crate::criteria::Decision;
use crate::cut::{ActiveEntry, Cut, NodeState};
use crate::reuse::Reuse;
use crate::store::{NodeStore, Shape, Tested};

/// [`ActiveEntry::pending`]: its group's bound failed, so its children are to be tested one
/// by one.
pub(super) const GROUP_FAILED: u16 = 1;
/// [`ActiveEntry::pending`]: it has no active child and its test says fold.
pub(super) const MAY_FOLD: u16 = 2;

/// The tests of one active entry for a threshold pass, on the entry alone (its dense
/// record and shape): whether its boundary children's group still holds its record or
/// passes its bound (recording the margin it passed with), and, when it has no active child,
/// whether it may fold. Returns what is pending for it ([`GROUP_FAILED`], [`MAY_FOLD`]).
#[inline]
pub(super) fn test_entry(
    entry: &mut ActiveEntry,
    shape: &Shape,
    pass: &Pass,
    stats: &mut AdjustStats,
) -> u16 {
    let (judge, t) = (pass.sight.judge, pass.sight.t);
    let mut pending = 0;
    if u32::from(entry.active_children) < entry.hot.child_count {
        if pass.now.as_ref().is_some_and(|now| entry.reuse.holds(now)) {
            stats.groups_reused += 1;
        } else {
            stats.visited += 1;
            stats.groups += 1;
            match judge.group_margin(&entry.hot, pass.tight) {
                Some(margin) => {
                    if let Some(now) = &pass.now
                        && margin > 0.0
                    {
                        entry.reuse = Reuse::new(now, judge.group_reach(&entry.hot), margin);
                    }
                }
                None => pending |= GROUP_FAILED,
            }
        }
    }
    if entry.active_children == 0 {
        stats.visited += 1;
        let tested = Tested {
            hot: &entry.hot,
            shape,
        };
        if judge.decide(tested, t) == Decision::Fold {
            pending |= MAY_FOLD;
        }
    }
    pending
}

/// The fewest entries a thread is given to test: about 360 KB of entries and shapes and a few
/// tens of microseconds of tests, beside which starting the thread costs little.
const MIN_SHARE: usize = 4096;

/// What the tests of a threshold pass found, for the pass to act on ([`Adjuster::full_pass`]):
/// the entries with something pending, by index ascending, and for each one whose group's
/// bound failed, its children's tests.
#[derive(Debug, Default)]
pub(super) struct Findings {
    /// The tests made, added to the adjust's figures once the findings are complete.
    pub(super) stats: AdjustStats,
    /// Indices of the entries with something pending, ascending.
    pub(super) marked: Vec<u32>,
    /// Beside each marked entry: its children's tests when its group's bound failed.
    pub(super) groups: Vec<Option<GroupFindings>>,
    /// The children that need unfolding, of every group in `groups`.
    pub(super) unfold: Vec<u32>,
    /// The children near their threshold, whose pages are to be fetched ahead of need, and
    /// their share of it (background loading only).
    pub(super) near: Vec<(u32, f32)>,
}

/// The children of one group whose bound failed, tested one by one.
#[derive(Debug, Clone, Copy)]
pub(super) struct GroupFindings {
    /// The node whose children were tested: a fold moves another entry into a folded one's
    /// place, where findings made for the folded one do not apply.
    pub(super) id: u32,
    /// The node's count of active children when they were tested: a fold since, which puts
    /// a child back on the boundary, makes the tests stale.
    pub(super) active_children: u16,
    /// The least margin the children passed with; zero when one needs unfolding.
    pub(super) least: f32,
    /// Its children that need unfolding: a range of [`Findings::unfold`].
    pub(super) unfold: (u32, u32),
    /// Its children near their threshold: a range of [`Findings::near`].
    pub(super) near: (u32, u32),
}

impl Findings {
    /// Empties the findings, keeping their memory for the next pass.
    pub(super) fn clear(&mut self) {
        self.stats = AdjustStats::default();
        self.marked.clear();
        self.groups.clear();
        self.unfold.clear();
        self.near.clear();
    }

    /// Appends `other` (the findings of the entries after this one's).
    fn append(&mut self, mut other: Findings) {
        let (unfold, near) = (self.unfold.len() as u32, self.near.len() as u32);
        self.stats.add(&other.stats);
        self.marked.append(&mut other.marked);
        self.groups.extend(other.groups.into_iter().map(|group| {
            group.map(|g| GroupFindings {
                unfold: (g.unfold.0 + unfold, g.unfold.1 + unfold),
                near: (g.near.0 + near, g.near.1 + near),
                ..g
            })
        }));
        self.unfold.append(&mut other.unfold);
        self.near.append(&mut other.near);
    }
}

/// [`test_entry`] on a run of entries starting at index `first`, and the children of each
/// whose group's bound failed ([`test_children`]), into `findings`.
fn test_run(
    entries: &mut [ActiveEntry],
    shapes: &[Shape],
    store: &NodeStore,
    first: usize,
    pass: &Pass,
    findings: &mut Findings,
) {
    // A failed group's children are read from the store, a few misses each: they are asked
    // for when the group fails and tested `LOOKAHEAD` failed groups later, so the misses
    // overlap with the tests in between. The ring holds (place in `findings`, entry index).
    let mut waiting = [(0usize, 0usize); LOOKAHEAD];
    let mut waited = 0usize;
    for i in 0..entries.len() {
        let entry = &mut entries[i];
        entry.pending = test_entry(entry, &shapes[i], pass, &mut findings.stats);
        if entry.pending == 0 {
            continue;
        }
        findings.marked.push((first + i) as u32);
        findings.groups.push(None);
        if entry.pending & GROUP_FAILED != 0 {
            store.prefetch_tested(entry.hot.first_child, entry.hot.child_count);
            let slot = &mut waiting[waited % LOOKAHEAD];
            let (k, j) = std::mem::replace(slot, (findings.groups.len() - 1, i));
            if waited >= LOOKAHEAD {
                findings.groups[k] = Some(test_children(&entries[j], store, pass, findings));
            }
            waited += 1;
        }
    }
    // The last ones, oldest first.
    for n in waited.saturating_sub(LOOKAHEAD)..waited {
        let (k, j) = waiting[n % LOOKAHEAD];
        findings.groups[k] = Some(test_children(&entries[j], store, pass, findings));
    }
}

/// Tests one by one the boundary children of the active `entry`, whose group's bound failed.
pub(super) fn test_children(
    entry: &ActiveEntry,
    store: &NodeStore,
    pass: &Pass,
    findings: &mut Findings,
) -> GroupFindings {
    let hot = &entry.hot;
    let (judge, t) = (pass.sight.judge, pass.sight.t);
    let (unfold, near) = (findings.unfold.len() as u32, findings.near.len() as u32);
    let mut least = f32::INFINITY;
    for c in hot.first_child..hot.first_child + hot.child_count {
        let (label, tested) = store.labelled(c);
        if label.state != NodeState::Boundary {
            continue;
        }
        findings.stats.visited += 1;
        let (decision, margin) = judge.decide_with_margin(tested, t);
        if decision == Decision::Unfold {
            least = 0.0;
            findings.unfold.push(c);
        } else {
            least = least.min(margin);
            // Near its threshold: its children's pages are fetched ahead of need, the
            // nearest first. Cheap test first: most nodes are far from it.
            if pass.prefetching {
                let now = pass.sight.now(tested.hot);
                if now > PREFETCH_RATIO * 0.5 {
                    findings.near.push((c, now));
                }
            }
        }
    }
    GroupFindings {
        id: entry.id,
        active_children: entry.active_children,
        least,
        unfold: (unfold, findings.unfold.len() as u32),
        near: (near, findings.near.len() as u32),
    }
}

impl Adjuster {
    /// The first step of [`Adjuster::full_pass`]: every active entry tested, what is pending
    /// marked in it, and the children of the groups whose bound failed tested one by one,
    /// into `self.findings`. The tests read the store and write each entry's own record
    /// alone, so shares of the entries are tested on several threads when the adjuster has
    /// them ([`Adjuster::set_threads`]); the findings are the same.
    pub(super) fn test_entries(&mut self, cut: &mut Cut, pass: &Pass) {
        let mut findings = std::mem::take(&mut self.findings);
        findings.clear();
        let (entries, shapes, store) = cut.active_entries_mut();
        let threads = self.threads.min(entries.len() / MIN_SHARE).max(1);
        if threads == 1 {
            test_run(entries, shapes, store, 0, pass, &mut findings);
        } else {
            // Equal shares, one per thread, the calling thread taking the first. Threads are
            // started for each pass: handed to a rayon pool instead, the 20 M fly-through's
            // tests took 8.0 ms a frame on two threads against 8.4 on one (5.1 ms this way),
            // its workers barely running on the 2-core VM.
            let share = entries.len().div_ceil(threads);
            let mut parts = entries.chunks_mut(share).zip(shapes.chunks(share));
            let (first_entries, first_shapes) = parts.next().expect("entries to test");
            let others = std::thread::scope(|scope| {
                let others: Vec<_> = parts
                    .enumerate()
                    .map(|(k, (entries, shapes))| {
                        scope.spawn(move || {
                            let mut findings = Findings::default();
                            let first = (k + 1) * share;
                            test_run(entries, shapes, store, first, pass, &mut findings);
                            findings
                        })
                    })
                    .collect();
                test_run(first_entries, first_shapes, store, 0, pass, &mut findings);
                others
                    .into_iter()
                    .map(|h| h.join().expect("a test run does not panic"))
                    .collect::<Vec<_>>()
            });
            for other in others {
                findings.append(other);
            }
        }
        self.stats.add(&findings.stats);
        self.findings = findings;
    }
}
