//! [`SourceMap`]: per-source state looked up by name on every sample.

use std::fmt;

/// A map from source names to values, for the paths every sample takes (clock mapping,
/// lateness, health, per-source filter state, the replay's recorder): a handful of
/// entries looked up by `&str` thousands of times a second.
///
/// A `BTreeMap<String, V>` compares the key with a library call at each entry it passes,
/// and its `entry` wants an owned key (so a lookup that may insert searched twice).
/// Here the entries sit in a `Vec` sorted by name, as a `BTreeMap<String, V>` iterates
/// (sums over sources keep their order, bit for bit), and a lookup scans them comparing
/// lengths first, then bytes inline; a key is allocated only when it is new.
#[derive(Clone, PartialEq)]
pub struct SourceMap<V> {
    entries: Vec<(String, V)>,
}

impl<V> Default for SourceMap<V> {
    fn default() -> Self {
        Self {
            entries: Vec::new(),
        }
    }
}

impl<V: fmt::Debug> fmt::Debug for SourceMap<V> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_map().entries(self.iter()).finish()
    }
}

/// `a == b` for short names without a call to `memcmp` per entry: most names differ in
/// length, and the rest in their first bytes.
#[inline]
fn same(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).all(|(x, y)| x == y)
}

impl<V> SourceMap<V> {
    pub fn new() -> Self {
        Self::default()
    }

    #[inline]
    fn index(&self, key: &str) -> Option<usize> {
        self.entries.iter().position(|(k, _)| same(k, key))
    }

    /// Adds `key`, which is not in the map, where it keeps the entries sorted.
    fn add(&mut self, key: &str, value: V) -> usize {
        let i = self.entries.partition_point(|(k, _)| k.as_str() < key);
        self.entries.insert(i, (key.to_string(), value));
        i
    }

    #[inline]
    pub fn get(&self, key: &str) -> Option<&V> {
        self.index(key).map(|i| &self.entries[i].1)
    }

    #[inline]
    pub fn get_mut(&mut self, key: &str) -> Option<&mut V> {
        self.index(key).map(|i| &mut self.entries[i].1)
    }

    /// `map[key]`, made by `new` on first use: one search, and the key is allocated only
    /// then.
    #[inline]
    pub fn get_or_insert_with(&mut self, key: &str, new: impl FnOnce() -> V) -> &mut V {
        let i = match self.index(key) {
            Some(i) => i,
            None => self.add(key, new()),
        };
        &mut self.entries[i].1
    }

    /// `map[key] = value`, returning the value it replaces; the key is allocated only
    /// when it is new (per-source state is put back with every sample).
    pub fn put(&mut self, key: &str, value: V) -> Option<V> {
        match self.get_mut(key) {
            Some(slot) => Some(std::mem::replace(slot, value)),
            None => {
                self.add(key, value);
                None
            }
        }
    }

    pub fn retain(&mut self, mut keep: impl FnMut(&String, &mut V) -> bool) {
        self.entries.retain_mut(|(k, v)| keep(k, v));
    }

    pub fn clear(&mut self) {
        self.entries.clear();
    }

    /// In name order, as a `BTreeMap<String, V>` iterates.
    pub fn iter(&self) -> impl DoubleEndedIterator<Item = (&String, &V)> + ExactSizeIterator {
        self.entries.iter().map(|(k, v)| (k, v))
    }

    pub fn iter_mut(
        &mut self,
    ) -> impl DoubleEndedIterator<Item = (&String, &mut V)> + ExactSizeIterator {
        self.entries.iter_mut().map(|(k, v)| (&*k, v))
    }

    pub fn values(&self) -> impl DoubleEndedIterator<Item = &V> + ExactSizeIterator {
        self.entries.iter().map(|(_, v)| v)
    }

    pub fn values_mut(&mut self) -> impl DoubleEndedIterator<Item = &mut V> + ExactSizeIterator {
        self.entries.iter_mut().map(|(_, v)| v)
    }
}

impl<'a, V> IntoIterator for &'a SourceMap<V> {
    type Item = (&'a String, &'a V);
    type IntoIter = std::iter::Map<
        std::slice::Iter<'a, (String, V)>,
        fn(&'a (String, V)) -> (&'a String, &'a V),
    >;

    fn into_iter(self) -> Self::IntoIter {
        self.entries.iter().map(|(k, v)| (k, v))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::BTreeMap;

    #[derive(Debug, Clone)]
    enum Op {
        Put(String, u32),
        GetOrInsert(String, u32),
        Add(String, u32),
    }

    fn name() -> impl Strategy<Value = String> {
        // Short names from few letters: many collisions, equal lengths, prefixes, and
        // an empty name.
        "[ab_0]{0,4}"
    }

    fn op() -> impl Strategy<Value = Op> {
        prop_oneof![
            (name(), any::<u32>()).prop_map(|(k, v)| Op::Put(k, v)),
            (name(), any::<u32>()).prop_map(|(k, v)| Op::GetOrInsert(k, v)),
            (name(), any::<u32>()).prop_map(|(k, v)| Op::Add(k, v)),
        ]
    }

    proptest! {
        /// Every operation answers as a `BTreeMap<String, _>` does, and the map iterates
        /// in the same order.
        #[test]
        fn behaves_as_a_btreemap(ops in prop::collection::vec(op(), 0..60), probe in name()) {
            let mut ours = SourceMap::new();
            let mut theirs: BTreeMap<String, u32> = BTreeMap::new();
            for op in ops {
                match op {
                    Op::Put(k, v) => prop_assert_eq!(ours.put(&k, v), theirs.insert(k, v)),
                    Op::GetOrInsert(k, v) => {
                        let a = *ours.get_or_insert_with(&k, || v);
                        let b = *theirs.entry(k).or_insert(v);
                        prop_assert_eq!(a, b);
                    }
                    Op::Add(k, v) => {
                        if let (Some(a), Some(b)) = (ours.get_mut(&k), theirs.get_mut(&k)) {
                            *a = a.wrapping_add(v);
                            *b = b.wrapping_add(v);
                        }
                    }
                }
                prop_assert_eq!(ours.iter().len(), theirs.len());
            }
            prop_assert_eq!(ours.get(&probe), theirs.get(&probe));
            let a: Vec<(&String, &u32)> = ours.iter().collect();
            let b: Vec<(&String, &u32)> = theirs.iter().collect();
            prop_assert_eq!(a, b);
        }
    }

    #[test]
    fn a_key_is_allocated_once_and_iteration_is_by_name() {
        let mut m = SourceMap::new();
        for k in ["t265", "imu", "gps", "imu", "flow_1", "flow", "imu"] {
            *m.get_or_insert_with(k, || 0) += 1;
        }
        let order: Vec<(&str, i32)> = m.iter().map(|(k, v)| (k.as_str(), *v)).collect();
        assert_eq!(
            order,
            [
                ("flow", 1),
                ("flow_1", 1),
                ("gps", 1),
                ("imu", 3),
                ("t265", 1)
            ]
        );
        assert_eq!(
            format!("{m:?}"),
            r#"{"flow": 1, "flow_1": 1, "gps": 1, "imu": 3, "t265": 1}"#
        );
    }
}
