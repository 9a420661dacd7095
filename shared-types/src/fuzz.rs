//! Fuzzing the readers of user files on stable Rust (feature `fuzz`, for tests): a
//! proptest strategy of damaged files grown from a valid one, and an allocator that
//! remembers the largest single allocation, so a test can tell a length field taken on
//! trust (a reader that reserves what a header claims) from a bounded one.
//!
//! A fuzz test feeds [`damaged`] bytes to a reader inside [`within_budget`] and asserts
//! nothing else: an `Err` or an `Ok` both pass, a panic, an abort or an allocation over
//! the budget fail. The number of cases is proptest's (`PROPTEST_CASES`, 256 by default);
//! README "Fuzzing" gives the longer run.

use proptest::prelude::*;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

/// Numerals that break careless number handling, written over a number of a text file.
const NASTY_NUMBERS: [&str; 12] = [
    "nan",
    "-nan",
    "inf",
    "-inf",
    "1e309",
    "-1",
    "0",
    "-0",
    "4294967296",
    "18446744073709551616",
    "99999999999999999999999",
    "1.7976931348623157e308",
];

/// The proptest settings of a fuzz test: proptest's case count (`PROPTEST_CASES`, 256 by
/// default) times `scale`, and no regression files written beside the sources.
pub fn config(scale: u32) -> ProptestConfig {
    let default = ProptestConfig::default();
    ProptestConfig {
        cases: default.cases * scale,
        failure_persistence: None,
        ..default
    }
}

/// One change to a file.
#[derive(Clone, Debug)]
pub enum Mutation {
    /// Set the byte at this fraction of the length.
    Byte(f64, u8),
    /// Cut the file at this fraction of its length.
    Truncate(f64),
    /// Insert bytes at this fraction.
    Insert(f64, Vec<u8>),
    /// Overwrite `width` bytes at this fraction with an extreme little- or big-endian
    /// integer (all ones, the sign bit, the largest positive, a huge count).
    Extreme(f64, usize, u8),
    /// Replace the run of digits nearest this fraction with a nasty numeral.
    Number(f64, usize),
    /// Copy a slice (start, length as fractions) to another position.
    Splice(f64, f64, f64),
}

impl Mutation {
    fn at(fraction: f64, len: usize) -> usize {
        ((fraction * len as f64) as usize).min(len)
    }

    /// `bytes` with this change made.
    pub fn apply(&self, bytes: &mut Vec<u8>) {
        let len = bytes.len();
        match self {
            Self::Byte(f, v) => {
                if len > 0 {
                    let i = Self::at(*f, len - 1);
                    bytes[i] = *v;
                }
            }
            Self::Truncate(f) => bytes.truncate(Self::at(*f, len)),
            Self::Insert(f, new) => {
                let i = Self::at(*f, len);
                bytes.splice(i..i, new.iter().copied());
            }
            Self::Extreme(f, width, kind) => {
                let value: u64 = match kind % 5 {
                    0 => u64::MAX,
                    1 => 1 << 63,
                    2 => i64::MAX as u64,
                    3 => 0x8000_0000,
                    _ => 0x7FFF_FFFF,
                };
                let le = value.to_le_bytes();
                let width = (*width).clamp(1, 8).min(len);
                let i = Self::at(*f, len - width);
                let source = if kind % 2 == 0 {
                    le
                } else {
                    value.to_be_bytes()
                };
                bytes[i..i + width].copy_from_slice(&source[..width]);
            }
            Self::Number(f, which) => {
                let i = Self::at(*f, len);
                let Some(start) = (i..len)
                    .chain((0..i).rev())
                    .find(|&k| bytes[k].is_ascii_digit())
                else {
                    return;
                };
                let mut a = start;
                while a > 0 && (bytes[a - 1].is_ascii_digit() || b".-+eE".contains(&bytes[a - 1])) {
                    a -= 1;
                }
                let mut b = start;
                while b < len && (bytes[b].is_ascii_digit() || b".-+eE".contains(&bytes[b])) {
                    b += 1;
                }
                let nasty = NASTY_NUMBERS[which % NASTY_NUMBERS.len()].as_bytes();
                bytes.splice(a..b, nasty.iter().copied());
            }
            Self::Splice(from, length, to) => {
                let a = Self::at(*from, len);
                let b = (a + Self::at(*length, len - a)).min(a + 4096);
                let chunk = bytes[a..b].to_vec();
                let t = Self::at(*to, len);
                bytes.splice(t..t, chunk);
            }
        }
    }
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let f = 0.0..1.0f64;
    prop_oneof![
        3 => (f.clone(), any::<u8>()).prop_map(|(f, v)| Mutation::Byte(f, v)),
        1 => f.clone().prop_map(Mutation::Truncate),
        1 => (f.clone(), prop::collection::vec(any::<u8>(), 1..16))
            .prop_map(|(f, v)| Mutation::Insert(f, v)),
        3 => (f.clone(), prop_oneof![Just(1usize), Just(2), Just(4), Just(8)], any::<u8>())
            .prop_map(|(f, w, k)| Mutation::Extreme(f, w, k)),
        2 => (f.clone(), any::<usize>()).prop_map(|(f, k)| Mutation::Number(f, k)),
        1 => (f.clone(), f.clone(), f).prop_map(|(a, l, t)| Mutation::Splice(a, l, t)),
    ]
}

/// Files grown from the valid file `seed`: one [`Mutation`] of it (most likely to keep
/// the file readable, so the reader's checks of values are reached; three cases in
/// eight), several, numbers only, or (one case in eight) random bytes.
pub fn damaged(seed: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    let apply = move |changes: Vec<Mutation>| {
        let mut bytes = seed.clone();
        for m in &changes {
            m.apply(&mut bytes);
        }
        bytes
    };
    let numbers = prop::collection::vec(
        (0.0..1.0f64, any::<usize>()).prop_map(|(f, k)| Mutation::Number(f, k)),
        1..4,
    );
    prop_oneof![
        3 => prop::collection::vec(mutation(), 1..2).prop_map(apply.clone()),
        2 => prop::collection::vec(mutation(), 2..7).prop_map(apply.clone()),
        2 => numbers.prop_map(apply),
        1 => prop::collection::vec(any::<u8>(), 0..512),
    ]
}

/// Values that break careless handling of a JSON field, put in place of one.
fn nasty_value() -> impl Strategy<Value = serde_json::Value> {
    use serde_json::{Value, json};
    prop_oneof![
        Just(json!(1e18)),
        Just(json!(1e9)),
        Just(json!(-1)),
        Just(json!(0)),
        Just(json!(-0.0)),
        Just(json!(u64::MAX)),
        Just(json!(i64::MIN)),
        Just(json!(4_294_967_296u64)),
        Just(json!(1e300)),
        Just(json!(-1e300)),
        Just(json!(1e-300)),
        Just(json!(0.5)),
        Just(Value::Null),
        Just(json!("")),
        Just(json!("\u{0}../../etc/passwd")),
        Just(json!([])),
        Just(json!({})),
        Just(json!(true)),
    ]
}

/// One change to a JSON tree: `change` made at the node with index `at` in pre-order,
/// counting every node or (`members_only`) only the members of objects, so that a
/// field is not drowned out by the elements of a long array.
#[derive(Clone, Debug)]
pub struct JsonMutation {
    pub at: usize,
    pub members_only: bool,
    pub change: JsonChange,
}

/// What a [`JsonMutation`] does to its node.
#[derive(Clone, Debug)]
pub enum JsonChange {
    /// Replace the node with a nasty value.
    Replace(serde_json::Value),
    /// Remove the node from its object or array.
    Remove,
    /// Repeat the node (an array element) this many more times.
    Repeat(usize),
}

impl JsonMutation {
    /// `value` with this change made (a change that does not fit its node does nothing).
    pub fn apply(&self, value: &mut serde_json::Value) {
        let count = count_nodes(value, self.members_only);
        if count == 0 {
            if let JsonChange::Replace(v) = &self.change {
                *value = v.clone();
            }
            return;
        }
        let mut seen = 0;
        self.edit_child(value, 1 + self.at % count, &mut seen);
    }

    /// Finds the child numbered `target` (from 1, in pre-order) below `parent` and
    /// changes it there; returns true when found.
    fn edit_child(&self, parent: &mut serde_json::Value, target: usize, seen: &mut usize) -> bool {
        use serde_json::Value;
        let (keys, counted): (Vec<String>, bool) = match parent {
            Value::Object(o) => (o.keys().cloned().collect(), true),
            Value::Array(a) => (
                (0..a.len()).map(|i| i.to_string()).collect(),
                !self.members_only,
            ),
            _ => return false,
        };
        for (slot, key) in keys.iter().enumerate() {
            if counted {
                *seen += 1;
                if *seen == target {
                    match (parent, &self.change) {
                        (Value::Object(o), JsonChange::Replace(v)) => {
                            o.insert(key.clone(), v.clone());
                        }
                        (Value::Object(o), JsonChange::Remove) => {
                            o.remove(key);
                        }
                        (Value::Array(a), JsonChange::Replace(v)) => a[slot] = v.clone(),
                        (Value::Array(a), JsonChange::Remove) => {
                            a.remove(slot);
                        }
                        (Value::Array(a), JsonChange::Repeat(n)) => {
                            let item = a[slot].clone();
                            for _ in 0..(*n).min(64) {
                                a.insert(slot, item.clone());
                            }
                        }
                        _ => {}
                    }
                    return true;
                }
            }
            let child = match parent {
                Value::Object(o) => o.get_mut(key),
                Value::Array(a) => a.get_mut(slot),
                _ => None,
            };
            if let Some(child) = child
                && self.edit_child(child, target, seen)
            {
                return true;
            }
        }
        false
    }
}

/// Nodes below `v` (not `v` itself): every one, or only objects' members.
fn count_nodes(v: &serde_json::Value, members_only: bool) -> usize {
    match v {
        serde_json::Value::Array(a) => a
            .iter()
            .map(|c| usize::from(!members_only) + count_nodes(c, members_only))
            .sum(),
        serde_json::Value::Object(o) => o.values().map(|c| 1 + count_nodes(c, members_only)).sum(),
        _ => 0,
    }
}

/// JSON files grown from the valid value `seed` by changing fields, not bytes: one to
/// three [`JsonMutation`]s (a field set to a nasty value, removed, an array element
/// repeated; two in three aimed at objects' members), so the file still parses and the
/// reader's checks of values are what is tried; and (one case in four) byte-[`damaged`]
/// text.
pub fn damaged_json(seed: serde_json::Value) -> impl Strategy<Value = Vec<u8>> {
    let text = serde_json::to_vec_pretty(&seed).expect("a JSON value serialises");
    let change = prop_oneof![
        3 => nasty_value().prop_map(JsonChange::Replace),
        1 => Just(JsonChange::Remove),
        1 => (1..64usize).prop_map(JsonChange::Repeat),
    ];
    let change = (any::<usize>(), prop::bool::weighted(0.67), change).prop_map(
        |(at, members_only, change)| JsonMutation {
            at,
            members_only,
            change,
        },
    );
    prop_oneof![
        3 => prop::collection::vec(change, 1..4).prop_map(move |changes| {
            let mut v = seed.clone();
            for c in &changes {
                c.apply(&mut v);
            }
            serde_json::to_vec_pretty(&v).expect("a JSON value serialises")
        }),
        1 => damaged(text),
    ]
}

/// The global allocator of a fuzz test binary: the system's, remembering the largest
/// single request of each thread (so tests running beside each other in one process do
/// not see each other's). Install with `#[global_allocator] static A: PeakAlloc = PeakAlloc;`.
pub struct PeakAlloc;

thread_local! {
    // Const-initialised and without a destructor: using it never allocates.
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

fn note(size: usize) {
    let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
}

// SAFETY: every call is forwarded unchanged to the system allocator; the only addition is
// a thread-local maximum, which neither allocates nor unwinds.
unsafe impl GlobalAlloc for PeakAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        // SAFETY: the caller's contract for `alloc` is passed on as is.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        // SAFETY: as for `alloc`.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from this allocator, that is from `System`, with `layout`.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        // SAFETY: as for `dealloc`, with the caller's `new_size` contract passed on.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// The most one allocation may take while reading a fuzzed file of at most a few
/// kilobytes: anything larger was sized by a length field nobody checked.
pub const ALLOCATION_BUDGET: usize = 256 << 20;

/// Runs `read` and fails (as a proptest failure) when one of its allocations on this
/// thread exceeded [`ALLOCATION_BUDGET`]. Meaningful only where [`PeakAlloc`] is the
/// global allocator; the reader's result itself is not judged.
pub fn within_budget<T>(read: impl FnOnce() -> T) -> Result<(), TestCaseError> {
    LARGEST.with(|l| l.set(0));
    let result = read();
    drop(result);
    let largest = LARGEST.with(Cell::get);
    prop_assert!(
        largest <= ALLOCATION_BUDGET,
        "one allocation took {largest} bytes: a length field was trusted"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[global_allocator]
    static ALLOC: PeakAlloc = PeakAlloc;

    #[test]
    fn the_budget_catches_an_allocation_a_header_asked_for() {
        assert!(within_budget(|| Vec::<u8>::with_capacity(1 << 20)).is_ok());
        let err = within_budget(|| Vec::<u8>::with_capacity(ALLOCATION_BUDGET + 1)).unwrap_err();
        assert!(err.to_string().contains("length field"), "{err}");
        // Growing past the budget counts too.
        let mut v = vec![0u8; 16];
        assert!(within_budget(|| v.reserve(ALLOCATION_BUDGET)).is_err());
    }

    #[test]
    fn mutations_change_files_as_described() {
        let mut b = b"count 12 of 3.5\n".to_vec();
        Mutation::Number(0.4, 4).apply(&mut b);
        assert_eq!(b, b"count 1e309 of 3.5\n");
        let mut b = vec![0u8; 8];
        Mutation::Extreme(0.0, 4, 0).apply(&mut b);
        assert_eq!(b, [255, 255, 255, 255, 0, 0, 0, 0]);
        let mut b = vec![1u8, 2, 3, 4];
        Mutation::Truncate(0.5).apply(&mut b);
        assert_eq!(b, [1, 2]);
        Mutation::Insert(1.0, vec![9]).apply(&mut b);
        assert_eq!(b, [1, 2, 9]);
        Mutation::Splice(0.0, 0.34, 0.0).apply(&mut b);
        assert_eq!(b, [1, 1, 2, 9]);
        // JSON changes reach every node, or every object member, and keep valid JSON.
        use serde_json::json;
        let change = |at, members_only, change| {
            let mut v = json!({"a": [1, 2, {"b": 3.5}], "c": "x"});
            JsonMutation {
                at,
                members_only,
                change,
            }
            .apply(&mut v);
            v
        };
        let minus = JsonChange::Replace(json!(-1));
        assert_eq!(
            change(4, false, minus.clone()),
            json!({"a": [1, 2, {"b": -1}], "c": "x"})
        );
        assert_eq!(
            change(1, true, minus),
            json!({"a": [1, 2, {"b": -1}], "c": "x"})
        );
        assert_eq!(
            change(1, false, JsonChange::Remove),
            json!({"a": [2, {"b": 3.5}], "c": "x"})
        );
        assert_eq!(
            change(1, false, JsonChange::Repeat(2)),
            json!({"a": [1, 1, 1, 2, {"b": 3.5}], "c": "x"})
        );
        assert_eq!(
            change(5, false, JsonChange::Remove),
            json!({"a": [1, 2, {"b": 3.5}]})
        );
        assert_eq!(
            change(2, true, JsonChange::Remove),
            json!({"a": [1, 2, {"b": 3.5}]})
        );
        // Every mutation copes with an empty file.
        for m in [
            Mutation::Byte(0.5, 1),
            Mutation::Truncate(0.5),
            Mutation::Extreme(0.5, 8, 1),
            Mutation::Number(0.5, 0),
            Mutation::Splice(0.5, 0.5, 0.5),
        ] {
            m.apply(&mut Vec::new());
        }
    }
}
