//! The one batching rule: consecutive work items, in the order given (FIFO), are grouped into
//! forward passes of at most `max_scenes` items and `max_objects` objects; an item larger than
//! the object budget runs alone. The server's scheduler takes the first pass of its queue with
//! [`PassBudget::first_pass`]; a caller holding a whole round (the model splitting a large
//! batch, the evaluator, the in-process load tester) uses [`PassBudget::plan`].

use std::ops::Range;

/// Limits of one forward pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PassBudget {
    /// Most items (scenes) per pass; values below 1 count as 1.
    pub max_scenes: usize,
    /// Most objects per pass, summed over its items; values below 1 count as 1. A single item
    /// above the budget still forms a pass of its own.
    pub max_objects: usize,
}

impl PassBudget {
    /// A budget on objects only (no scene cap).
    pub fn objects(max_objects: usize) -> PassBudget {
        PassBudget {
            max_scenes: usize::MAX,
            max_objects,
        }
    }

    /// This budget in whole forwards of a model that computes a pass in forwards of
    /// `forward` objects (RigidFormer: [`crate::rigidformer::DEFAULT_MAX_PASS_OBJECTS`]): the
    /// object budget rounded down to a multiple of it, so that a full pass does not end in a
    /// short forward; unchanged without a forward size or below one forward.
    pub fn in_whole_forwards(self, forward: Option<usize>) -> PassBudget {
        match forward {
            Some(f) if f > 0 && self.max_objects > f => PassBudget {
                max_objects: self.max_objects / f * f,
                ..self
            },
            _ => self,
        }
    }

    /// How many leading items of `objects` (object count per item, in queue order) form the
    /// next pass, and their total object count. `(0, 0)` only when `objects` is empty.
    pub fn first_pass(&self, objects: impl IntoIterator<Item = usize>) -> (usize, usize) {
        let (max_scenes, max_objects) = (self.max_scenes.max(1), self.max_objects.max(1));
        let mut taken = 0;
        let mut total = 0;
        for n in objects {
            if taken >= max_scenes || (taken > 0 && total + n > max_objects) {
                break;
            }
            taken += 1;
            total += n;
        }
        (taken, total)
    }

    /// Splits items with `objects[i]` objects into consecutive passes, in order.
    pub fn plan(&self, objects: &[usize]) -> Vec<Range<usize>> {
        let mut out = Vec::new();
        let mut start = 0;
        while start < objects.len() {
            let (taken, _) = self.first_pass(objects[start..].iter().copied());
            out.push(start..start + taken);
            start += taken;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_budget_in_whole_forwards_rounds_its_objects_down_to_a_multiple() {
        let b = |n| PassBudget::objects(n);
        assert_eq!(b(2048).in_whole_forwards(Some(160)).max_objects, 1920);
        assert_eq!(b(2048).in_whole_forwards(None).max_objects, 2048);
        assert_eq!(b(100).in_whole_forwards(Some(160)).max_objects, 100);
        assert_eq!(b(320).in_whole_forwards(Some(160)).max_objects, 320);
    }

    fn budget(max_scenes: usize, max_objects: usize) -> PassBudget {
        PassBudget {
            max_scenes,
            max_objects,
        }
    }

    #[test]
    fn plans_follow_the_scene_cap_and_object_budget_in_order() {
        assert_eq!(budget(2, 100).plan(&[2; 5]), vec![0..2, 2..4, 4..5]);
        assert_eq!(budget(64, 7).plan(&[3, 3, 3, 3]), vec![0..2, 2..4]);
        // An item above the budget runs alone; order is never changed to fill a pass.
        assert_eq!(budget(64, 10).plan(&[1, 50, 1]), vec![0..1, 1..2, 2..3]);
        assert_eq!(budget(64, 10).plan(&[6, 5, 4]), vec![0..1, 1..3]);
        assert_eq!(budget(64, 2048).plan(&[10; 64]), vec![0..64]);
        assert_eq!(budget(1, 2048).plan(&[10; 3]), vec![0..1, 1..2, 2..3]);
        assert_eq!(
            PassBudget::objects(20).plan(&[10; 5]),
            vec![0..2, 2..4, 4..5]
        );
        assert!(budget(4, 4).plan(&[]).is_empty());
    }

    #[test]
    fn first_pass_counts_items_and_objects() {
        assert_eq!(budget(3, 5).first_pass([2, 2, 2, 2]), (2, 4));
        assert_eq!(budget(3, 5).first_pass([9, 1]), (1, 9));
        assert_eq!(budget(0, 0).first_pass([1, 1]), (1, 1));
        assert_eq!(budget(3, 5).first_pass([]), (0, 0));
    }
}
