//! The triangle-budget exchange (Luebke & Erikson 1997 §3.3).
//!
//! A max-queue of boundary nodes by priority (screen-space error over the criteria's
//! threshold scale) and a min-queue of *fold candidates* (active nodes whose children are all
//! on the boundary). Starting from the current cut (coherence), the worst boundary node is
//! unfolded while its subtris fit (counted as drawn: repeats once, see `repeats.rs`; an
//! unfold that splits repeats past the budget is undone, and the node does not fit after
//! all); when it does not fit and a fold candidate is cheaper, that
//! candidate is folded to make room. A node's priority is clamped to its parent's, so a fold
//! candidate is never the parent of the node it makes room for. Each exchange replaces lower
//! priorities by a higher one, so the loop terminates; it stops when the worst boundary node
//! does not fit and nothing cheaper can fold: unfolding the next node in the queue would
//! exceed the budget, which is §3.3's stopping rule.

use std::cmp::{Ordering, Reverse};

use vds_format::VdtError;

use super::{AdjustStats, Adjuster};
use crate::criteria::Judge;
use crate::cut::{Cut, NIL};

/// A float with a total order, for the priority queues.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Priority(f32);

impl Eq for Priority {}

impl PartialOrd for Priority {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Priority {
    fn cmp(&self, other: &Self) -> Ordering {
        self.0.total_cmp(&other.0)
    }
}

impl Adjuster {
    /// The priority of unfolding `id` this frame: the judge's priority, clamped to its
    /// parent's (see the module documentation).
    pub fn priority(&mut self, cut: &Cut, judge: &Judge, id: u32) -> f32 {
        // Walk up to the first ancestor already priced this frame, then price down.
        self.stack.clear();
        let mut n = id;
        let mut above = f32::MAX;
        while n != NIL {
            if let Some(&value) = self.priorities.get(&n) {
                above = value;
                break;
            }
            self.stack.push(n);
            n = cut.node(n).parent;
        }
        while let Some(n) = self.stack.pop() {
            self.stats.visited += 1;
            let surface = cut.store().surface_error(n);
            above = judge.priority(cut.store().tested(n), surface).min(above);
            self.priorities.insert(n, above);
        }
        above
    }

    /// Adjusts `cut` to the best cut of at most `budget` triangles under `judge`.
    pub fn adjust_budget(
        &mut self,
        cut: &mut Cut,
        judge: &Judge,
        budget: u32,
        prevent_flips: bool,
    ) -> Result<AdjustStats, VdtError> {
        self.begin();
        self.unfold_queue.clear();
        self.fold_queue.clear();
        self.work.clear();
        self.work.extend(cut.boundary());
        for i in 0..self.work.len() {
            let b = self.work[i];
            self.queue_unfold(cut, judge, b);
            self.queue_fold(cut, judge, cut.node(b).parent);
        }
        // Over budget (the budget shrank): fold the cheapest candidates. The budget is a hard
        // limit, so mesh-fold prevention yields here.
        while cut.counted_triangles() > budget {
            let Some(f) = self.pop_fold(cut) else { break };
            cut.fold_node(f, false);
            self.stats.folds += 1;
            self.after_fold(cut, judge, f);
        }
        self.exchange(cut, judge, budget, prevent_flips)?;
        // Refused folds again (see `retry_refused_folds`): back in the queue after changes
        // that may have removed the triangle they would have flipped. A round that goes on
        // made an exchange, and a frame's exchanges are finite (module documentation), so
        // the rounds end.
        while !self.refused.is_empty() {
            let changes = self.stats.folds + self.stats.unfolds;
            for f in std::mem::take(&mut self.refused) {
                self.queue_fold(cut, judge, f);
            }
            self.exchange(cut, judge, budget, prevent_flips)?;
            if self.stats.folds + self.stats.unfolds == changes {
                break;
            }
        }
        Ok(self.stats)
    }

    /// The budget's exchanges (see the module documentation) until the worst boundary node
    /// does not fit and no cheaper candidate can fold.
    fn exchange(
        &mut self,
        cut: &mut Cut,
        judge: &Judge,
        budget: u32,
        prevent_flips: bool,
    ) -> Result<(), VdtError> {
        while let Some(&(Priority(worst), Reverse(u))) = self.peek_unfold(cut) {
            if worst <= 0.0 {
                break;
            }
            // A node whose children are not resident is passed over (its pages asked for)
            // before anything is folded to make room for it. (With synchronous loading they
            // are read here, and passed over only when they do not fit in the memory budget.)
            if !cut.children_available(u)? {
                self.unfold_queue.pop();
                if cut.request_children(u, worst) {
                    self.stats.deferred_unfolds += 1;
                }
                continue;
            }
            let cost = cut.node(u).subtri_count;
            if u64::from(cut.counted_triangles()) + u64::from(cost) <= u64::from(budget) {
                cut.unfold_node(u)?;
                // An unfold can split classes of repeats that were counted once, and so add
                // more than its subtris: one that goes past the budget is undone, and the node
                // does not fit after all.
                if cut.counted_triangles() > budget {
                    cut.fold_node(u, false);
                } else {
                    self.unfold_queue.pop();
                    self.stats.unfolds += 1;
                    for c in cut.node(u).children() {
                        self.queue_unfold(cut, judge, c);
                    }
                    self.queue_fold(cut, judge, u);
                    continue;
                }
            }
            match self.peek_fold(cut) {
                Some(&Reverse((Priority(cheapest), f))) if cheapest < worst => {
                    self.pop_fold(cut);
                    if cut.fold_node(f, prevent_flips) {
                        self.stats.folds += 1;
                        self.after_fold(cut, judge, f);
                    } else {
                        self.stats.refused_folds += 1;
                        self.refused.push(f);
                    }
                }
                _ => break,
            }
        }
        Ok(())
    }

    fn after_fold(&mut self, cut: &Cut, judge: &Judge, id: u32) {
        self.queue_unfold(cut, judge, id);
        self.queue_fold(cut, judge, cut.node(id).parent);
    }

    fn queue_unfold(&mut self, cut: &Cut, judge: &Judge, id: u32) {
        if cut.can_unfold(id) {
            let p = self.priority(cut, judge, id);
            self.unfold_queue.push((Priority(p), Reverse(id)));
        }
    }

    fn queue_fold(&mut self, cut: &Cut, judge: &Judge, id: u32) {
        if id != NIL && cut.can_fold(id) && self.queued.insert(id) {
            let p = self.priority(cut, judge, id);
            self.fold_queue.push(Reverse((Priority(p), id)));
        }
    }

    fn peek_unfold(&mut self, cut: &Cut) -> Option<&(Priority, Reverse<u32>)> {
        while let Some(&(_, Reverse(u))) = self.unfold_queue.peek() {
            if cut.can_unfold(u) {
                break;
            }
            self.unfold_queue.pop();
        }
        self.unfold_queue.peek()
    }

    fn peek_fold(&mut self, cut: &Cut) -> Option<&Reverse<(Priority, u32)>> {
        while let Some(&Reverse((_, f))) = self.fold_queue.peek() {
            if cut.can_fold(f) {
                break;
            }
            // A node that stops being a candidate may become one again this frame.
            self.queued.remove(&f);
            self.fold_queue.pop();
        }
        self.fold_queue.peek()
    }

    fn pop_fold(&mut self, cut: &Cut) -> Option<u32> {
        let f = self.peek_fold(cut)?.0.1;
        self.fold_queue.pop();
        self.queued.remove(&f);
        Some(f)
    }
}
