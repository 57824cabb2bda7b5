//! The half-patches the cut draws, kept in its drawing order as it changes.

use std::collections::BTreeMap;
use std::sync::Arc;

use cbdam_codec::geometry::DiamondId;

use super::node::Node;
use crate::patch::HalfPatch;

/// The drawn half-patches in [`Cut::drawn_halves`](cbdam_codec::geometry::Cut::drawn_halves)'
/// order: the unrefined roots' halves (by the root's index in the layout, then the half's in
/// `Half::BOTH`), then, per refined diamond in id order (coarse to fine), the halves of its
/// unrefined children in slot order.
///
/// A refined diamond with a drawn child half has one entry: its node (whose `halves` are its
/// children's) and which of them are drawn. Refining a diamond adds its entry and clears a bit
/// in each parent's (an entry goes when its last bit does); coarsening removes its entry and
/// sets those bits again. A refinement costs one insertion and two searches of a map with an
/// entry per refined diamond, where a map of halves took four insertions and two removals
/// (a quarter of applying a refinement on the frame thread, in perf of a paced `low_pass`
/// settling).
#[derive(Default)]
pub(super) struct DrawnList {
    roots: BTreeMap<(usize, usize), Arc<HalfPatch>>,
    children: BTreeMap<u128, Shown>,
    len: usize,
}

/// A refined diamond's node and which of its children's halves are drawn (bit `slot`).
struct Shown {
    node: Arc<Node>,
    slots: u8,
}

impl DrawnList {
    /// Draws half `half` of root `index`.
    pub(super) fn show_root(&mut self, index: usize, half: usize, patch: Arc<HalfPatch>) {
        if self.roots.insert((index, half), patch).is_none() {
            self.len += 1;
        }
    }

    /// Stops drawing half `half` of root `index`.
    pub(super) fn hide_root(&mut self, index: usize, half: usize) {
        if self.roots.remove(&(index, half)).is_some() {
            self.len -= 1;
        }
    }

    /// Draws every child half of `id`, just refined (none of its children is refined).
    pub(super) fn show_children(&mut self, id: DiamondId, node: Arc<Node>) {
        let slots = (0..4)
            .filter(|&s| node.halves[s].is_some())
            .fold(0u8, |m, s| m | 1 << s);
        self.len += slots.count_ones() as usize;
        let old = self.children.insert(packed(id), Shown { node, slots });
        debug_assert!(old.is_none(), "{id} refined twice");
    }

    /// Stops drawing the child halves of `id`, about to be coarsened (none of its children is
    /// refined, so all are drawn).
    pub(super) fn hide_children(&mut self, id: DiamondId) {
        if let Some(shown) = self.children.remove(&packed(id)) {
            self.len -= shown.slots.count_ones() as usize;
        }
    }

    /// Draws the child half in `slot` of refined `parent`, whose node is `node`.
    pub(super) fn show_child(&mut self, parent: DiamondId, slot: usize, node: &Arc<Node>) {
        let shown = self
            .children
            .entry(packed(parent))
            .or_insert_with(|| Shown {
                node: node.clone(),
                slots: 0,
            });
        debug_assert!(Arc::ptr_eq(&shown.node, node), "{parent}'s node replaced");
        debug_assert!(
            node.halves[slot].is_some(),
            "{parent} has no child in {slot}"
        );
        if shown.slots & 1 << slot == 0 {
            shown.slots |= 1 << slot;
            self.len += 1;
        }
    }

    /// Stops drawing the child half in `slot` of refined `parent`.
    pub(super) fn hide_child(&mut self, parent: DiamondId, slot: usize) {
        let key = packed(parent);
        let Some(shown) = self.children.get_mut(&key) else {
            return;
        };
        if shown.slots & 1 << slot != 0 {
            shown.slots &= !(1 << slot);
            self.len -= 1;
        }
        if shown.slots == 0 {
            self.children.remove(&key);
        }
    }

    /// The drawn halves, in the cut's order.
    pub(super) fn iter(&self) -> impl Iterator<Item = &Arc<HalfPatch>> {
        self.roots
            .values()
            .chain(self.children.values().flat_map(|s| {
                s.node
                    .halves
                    .iter()
                    .enumerate()
                    .filter(|&(slot, _)| s.slots & 1 << slot != 0)
                    .map(|(_, h)| h.as_ref().expect("drawn slots hold halves"))
            }))
    }

    /// How many halves are drawn.
    pub(super) fn len(&self) -> usize {
        self.len
    }

    pub(super) fn clear(&mut self) {
        *self = Self::default();
    }
}

/// A diamond's id as one integer in the ids' order (level, face, x, y: 80 bits): the map
/// compares integers, not ids.
fn packed(id: DiamondId) -> u128 {
    u128::from(id.level) << 72
        | u128::from(id.face) << 64
        | u128::from(id.x) << 32
        | u128::from(id.y)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Packed ids sort as the ids do (the drawn list's order is the cut's), over every pair of
    /// ids made of a few values of each field, the extremes among them, so that pairs tie on
    /// the leading fields and each later one decides somewhere.
    #[test]
    fn packed_ids_keep_the_order() {
        let bytes = [0, 1, 2, u8::MAX];
        let coords = [0, 1, 2, u32::MAX - 1, u32::MAX];
        let mut ids = Vec::new();
        for level in bytes {
            for face in bytes {
                for x in coords {
                    for y in coords {
                        ids.push(DiamondId::on_face(face, level, x, y));
                    }
                }
            }
        }
        for a in &ids {
            for b in &ids {
                assert_eq!(packed(*a).cmp(&packed(*b)), a.cmp(b), "{a:?} against {b:?}");
            }
        }
    }
}
