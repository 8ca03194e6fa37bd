//! Rank tracking ([`CornerTracking::Ranks`]): the cut keeps no per-triangle state and reports
//! its changes per node. A renderer's mirror built from those changes alone — a set of active
//! nodes whose subtris it draws, and a leaf rank → node map kept by range fills — must draw
//! exactly the triangles the cut reads out, with the same corners, and the cut must be the
//! one lazy tracking (the same adjust, corners kept per triangle) makes, frame after frame.

mod common;

use std::collections::{HashMap, HashSet};

use common::*;
use vds_runtime::{
    ActiveTriangle, Changes, CornerTracking, Criteria, FrustumMode, Goal, Runtime, Viewpoint,
};

/// What a renderer keeps of a rank-tracked cut.
struct Mirror {
    /// Active nodes and their subtris (first triangle, count).
    active: HashMap<u32, (u32, u32)>,
    /// Current node of every leaf rank (the whole model: this is a test).
    node_of_rank: Vec<u32>,
    /// Active triangles hidden as repeats.
    hidden: HashSet<u32>,
    /// Boundary nodes (the vertices a renderer holds).
    boundary: HashSet<u32>,
}

impl Mirror {
    fn new(vertices: usize) -> Mirror {
        Mirror {
            active: HashMap::new(),
            node_of_rank: vec![0; vertices],
            hidden: HashSet::new(),
            boundary: HashSet::from([0]),
        }
    }

    /// Applies one frame's node changes; returns the triangles it added and removed.
    fn apply(&mut self, frame_changes: &Changes, runtime: &Runtime, what: &str) -> (u32, u32) {
        assert!(
            frame_changes.dirty_slots.is_empty(),
            "{what}: rank tracking has no slots"
        );
        let cut = runtime.cut();
        let (mut added, mut removed) = (0, 0);
        for &id in &frame_changes.folded {
            let (first, count) = self
                .active
                .remove(&id)
                .unwrap_or_else(|| panic!("{what}: node {id} folded but was not active"));
            removed += count;
            // Hidden repeats leave with their node.
            for t in first..first + count {
                self.hidden.remove(&t);
            }
        }
        for &id in &frame_changes.unfolded {
            let node = cut.node(id);
            let before = self
                .active
                .insert(id, (node.subtri_begin, node.subtri_count));
            assert!(before.is_none(), "{what}: node {id} unfolded twice");
            added += node.subtri_count;
        }
        for &id in &frame_changes.left_boundary {
            assert!(
                self.boundary.remove(&id),
                "{what}: node {id} left but was not there"
            );
        }
        for &id in &frame_changes.joined_boundary {
            assert!(self.boundary.insert(id), "{what}: node {id} joined twice");
            let node = cut.node(id);
            self.node_of_rank[node.leaf_begin as usize..node.leaf_end as usize].fill(id);
        }
        let active = |t: u32| self.active.values().any(|&(f, c)| (f..f + c).contains(&t));
        for &(t, owner) in &frame_changes.hidden {
            assert!(active(t), "{what}: triangle {t} hidden but not active");
            let (first, count) = self.active[&owner];
            assert!(
                (first..first + count).contains(&t),
                "{what}: triangle {t} is not a subtri of node {owner}"
            );
        }
        for &(t, _) in &frame_changes.hidden {
            assert!(self.hidden.insert(t), "{what}: triangle {t} hidden twice");
        }
        for &(t, _) in &frame_changes.shown {
            assert!(
                self.hidden.remove(&t),
                "{what}: triangle {t} shown but not hidden"
            );
        }
        assert_eq!(frame_changes.added, added, "{what}: added");
        assert_eq!(frame_changes.removed, removed, "{what}: removed");
        (added, removed)
    }

    /// Asserts that the mirror's active and boundary nodes are the cut's.
    fn assert_nodes_match(&self, runtime: &Runtime, what: &str) {
        let mirrored: HashSet<u32> = self.active.keys().copied().collect();
        let active: HashSet<u32> = runtime
            .cut()
            .active_entries()
            .iter()
            .map(|e| e.id)
            .collect();
        assert!(
            mirrored == active,
            "{what}: the mirror's active nodes differ"
        );
        let boundary: HashSet<u32> = runtime.cut().boundary().into_iter().collect();
        assert!(
            self.boundary == boundary,
            "{what}: the mirror's boundary differs"
        );
    }

    /// What the mirror draws: every subtri of its active nodes but those it was told are
    /// hidden, with corners from the rank map; and what it should draw by a recomputation of
    /// repeats from all of them (each class of same-winding repeats once, by its smallest
    /// triangle index).
    fn drawn(&self, runtime: &Runtime) -> (Vec<ActiveTriangle>, Vec<ActiveTriangle>) {
        let store = runtime.cut().store();
        let mut by_class: HashMap<[u32; 3], u32> = HashMap::new();
        let mut all = Vec::new();
        for &(first, count) in self.active.values() {
            for t in first..first + count {
                let corners = store
                    .triangle_corners(t)
                    .map(|rank| self.node_of_rank[rank as usize]);
                let lead = (0..3).min_by_key(|&k| corners[k]).unwrap();
                let class = [0, 1, 2].map(|k| corners[(lead + k) % 3]);
                let smallest = by_class.entry(class).or_insert(t);
                *smallest = (*smallest).min(t);
                all.push((
                    class,
                    ActiveTriangle {
                        triangle: t,
                        corners,
                    },
                ));
            }
        }
        let mut told: Vec<_> = all
            .iter()
            .filter(|(_, t)| !self.hidden.contains(&t.triangle))
            .map(|&(_, t)| t)
            .collect();
        let mut recomputed: Vec<_> = all
            .into_iter()
            .filter(|(class, t)| by_class[class] == t.triangle)
            .map(|(_, t)| t)
            .collect();
        told.sort_unstable();
        recomputed.sort_unstable();
        (told, recomputed)
    }
}

#[test]
fn node_changes_alone_let_a_renderer_draw_the_cut_and_it_is_lazy_trackings_cut() {
    let mut hidden = 0u64;
    for (name, scene, bytes) in built_by_each(&["bunny.obj", "as1_assembly.obj", "airplane.obj"]) {
        let (center, radius) = bounds(&scene.positions);
        let mut ranks = runtime(&bytes, CornerTracking::Ranks);
        let mut lazy = runtime(&bytes, CornerTracking::Lazy);
        let vertices = ranks.leaf_positions().unwrap().len();
        let mut mirror = Mirror::new(vertices);
        let mut rng = Rng(23);
        let mut camera = random_camera(&mut rng, center, radius);
        let mut changed_frames = 0;
        for step in 0..60u32 {
            next_camera(&mut rng, &mut camera, (step, 12), (center, radius), 0.06);
            let (viewpoint, goal) = match step % 5 {
                0 | 1 => (Viewpoint::Camera(camera), Goal::Threshold(1.0)),
                2 => (Viewpoint::Camera(camera), Goal::Threshold(6.0)),
                3 => (Viewpoint::Camera(camera), Goal::Budget(500 + 150 * step)),
                _ => (Viewpoint::Independent, Goal::Budget(300 + 80 * step)),
            };
            let criteria = Criteria {
                frustum: [FrustumMode::Fold, FrustumMode::Ignore][step as usize % 2],
                ..Criteria::default()
            };
            let what = format!("{name} step {step}");
            let frame = ranks.adjust(&viewpoint, &criteria, goal).unwrap();
            lazy.adjust(&viewpoint, &criteria, goal).unwrap();
            let (added, removed) = mirror.apply(&frame.changes, &ranks, &what);
            changed_frames += u32::from(added + removed > 0);
            ranks.cut_mut().check().unwrap();

            mirror.assert_nodes_match(&ranks, &what);
            let drawn = ranks.cut_mut().active_triangles();
            let (told, recomputed) = mirror.drawn(&ranks);
            assert!(
                recomputed == drawn,
                "{what}: the cut draws other triangles than its node changes give"
            );
            assert!(
                told == drawn,
                "{what}: the repeats the cut reported hidden and shown are not its repeats"
            );
            let mut lazily = lazy.cut_mut().active_triangles();
            lazily.sort_unstable();
            assert!(drawn == lazily, "{what}: rank and lazy tracking disagree");
            let cut = ranks.cut();
            assert_eq!(cut.active_triangle_count() as usize, drawn.len(), "{what}");
            assert_eq!(
                cut.active_triangle_count_with_repeats(),
                lazy.cut().active_triangle_count_with_repeats(),
                "{what}"
            );
            if let Goal::Budget(budget) = goal {
                assert!(cut.active_triangle_count_with_repeats() <= budget, "{what}");
            }
            hidden += u64::from(cut.active_triangle_count_with_repeats())
                - u64::from(cut.active_triangle_count());
        }
        assert!(changed_frames > 30, "{name}: the path changed too little");
    }
    assert!(hidden > 0, "no repeat was ever hidden");
}

/// The node changes stay exact while a small memory budget evicts pages all along the path:
/// labels come and go with their pages, and a journal index a label held before its page left
/// must not be taken for an entry of the node once the page is back. (A page evicted and read
/// again between two reports, which gives a node two entries, is the next test's: within one
/// adjust the store evicts no page unpinned in that frame.)
#[test]
fn node_changes_stay_exact_while_pages_come_and_go() {
    let (bytes, center, radius) = generated(60_000);
    let mut full = runtime(&bytes, CornerTracking::Ranks);
    full.set_memory_budget(u64::MAX);
    full.load_every_page().unwrap();
    let budget = full.memory().resident_bytes / 8;
    for path in [
        vds_runtime::CameraPath::fly_through(center, radius, 40, 640, 360),
        vds_runtime::CameraPath::orbit(center, radius, 40, 640, 360),
    ] {
        let mut ranks = runtime(&bytes, CornerTracking::Ranks);
        ranks.set_memory_budget(budget);
        let vertices = ranks.cut().store().vertex_count() as usize;
        let mut mirror = Mirror::new(vertices);
        for (i, camera) in path.cameras.iter().enumerate() {
            let what = format!("frame {i}");
            let frame = ranks
                .adjust(
                    &Viewpoint::Camera(*camera),
                    &Criteria::default(),
                    Goal::Threshold(1.0),
                )
                .unwrap();
            mirror.apply(&frame.changes, &ranks, &what);
            mirror.assert_nodes_match(&ranks, &what);
        }
        assert!(
            ranks.memory().pages_evicted > 0,
            "a budget of an eighth of the model never evicted"
        );
    }
}

/// A direct user of the cut may evict pages between two reports. A chain of nodes active at
/// the last report, folded away with their pages evicted, then read back and unfolded again
/// before the next report, is back where it was: the report lists no change and counts no
/// triangle added or removed.
#[test]
fn nodes_back_where_they_were_after_their_pages_left_are_no_change() {
    let (bytes, _, _) = generated(60_000);
    let mut runtime = runtime(&bytes, CornerTracking::Ranks);
    let cut = runtime.cut_mut();
    let mut chain = vec![0u32];
    loop {
        let id = *chain.last().unwrap();
        cut.unfold_node(id).unwrap();
        let child = cut.node(id).first_child;
        if cut.node(child).child_count == 0 {
            break;
        }
        chain.push(child);
    }
    let _ = cut.take_changes();
    cut.fold_all();
    cut.store_mut().set_memory_budget(0);
    cut.store_mut().evict_to_budget();
    let deepest = *chain.last().unwrap();
    assert!(
        !cut.store().is_resident(deepest),
        "the deepest node's page stayed: the test evicts nothing it needs"
    );
    cut.store_mut().set_memory_budget(u64::MAX);
    for &id in &chain {
        cut.unfold_node(id).unwrap();
    }
    cut.check().unwrap();
    let changes = cut.take_changes();
    assert!(
        changes.unfolded.is_empty()
            && changes.folded.is_empty()
            && changes.joined_boundary.is_empty()
            && changes.left_boundary.is_empty(),
        "nodes back where they were were reported: {changes:?}"
    );
    assert_eq!((changes.added, changes.removed), (0, 0));
}
