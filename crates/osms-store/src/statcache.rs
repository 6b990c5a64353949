//! Remembers which objects were verified, by their file metadata, so a no-op `osms make` or
//! `osms status` need not re-hash every object (DVC's known slowness).
//!
//! An entry is trusted only while the object's length, inode, mtime and ctime are unchanged; any
//! write changes ctime, which no user tool can set back. File timestamps are coarse, so a write
//! in the same tick as the verification could go unnoticed (git's "racy clean" problem): entries
//! for objects modified less than [`RACY_SECS`] before they were verified are not trusted and
//! are re-hashed next time, which makes them trusted once they are old enough.

use std::collections::BTreeMap;
use std::fs::Metadata;
use std::os::unix::fs::MetadataExt;
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};

use crate::Hash;

const RACY_SECS: i64 = 2;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct Stamp {
    len: u64,
    ino: u64,
    mtime_ns: i128,
    ctime_ns: i128,
}

impl Stamp {
    pub(crate) fn of(meta: &Metadata) -> Self {
        Stamp {
            len: meta.len(),
            ino: meta.ino(),
            mtime_ns: i128::from(meta.mtime()) * 1_000_000_000 + i128::from(meta.mtime_nsec()),
            ctime_ns: i128::from(meta.ctime()) * 1_000_000_000 + i128::from(meta.ctime_nsec()),
        }
    }
}

#[derive(Debug, Default, Serialize, Deserialize)]
pub(crate) struct StatCache {
    pub(crate) entries: BTreeMap<Hash, Stamp>,
    #[serde(skip)]
    dirty: bool,
}

impl StatCache {
    pub(crate) fn from_bytes(bytes: &[u8]) -> Self {
        postcard::from_bytes(bytes).unwrap_or_default()
    }

    pub(crate) fn to_bytes(&self) -> Vec<u8> {
        postcard::to_stdvec(self).expect("the stat cache serialises")
    }

    pub(crate) fn is_dirty(&self) -> bool {
        self.dirty
    }

    pub(crate) fn trusts(&self, hash: &Hash, stamp: &Stamp) -> bool {
        self.entries.get(hash) == Some(stamp)
    }

    /// Records that the object with `stamp` was just verified, unless it is too fresh to trust.
    pub(crate) fn verified(&mut self, hash: Hash, stamp: Stamp) {
        // Wall-clock time only decides whether to skip a re-hash later; it never enters an
        // artifact or a key.
        let now_ns = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_nanos() as i128)
            .unwrap_or(0);
        let newest = stamp.mtime_ns.max(stamp.ctime_ns);
        if now_ns - newest > i128::from(RACY_SECS) * 1_000_000_000 {
            self.dirty |= self.entries.insert(hash, stamp) != Some(stamp);
        } else {
            self.forget(&hash);
        }
    }

    pub(crate) fn forget(&mut self, hash: &Hash) {
        self.dirty |= self.entries.remove(hash).is_some();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn now_ns() -> i128 {
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_nanos() as i128)
            .unwrap_or(0)
    }

    #[test]
    fn trusts_only_unchanged_and_old_enough_stamps() {
        let h = Hash::of(b"x");
        let old = Stamp {
            len: 10,
            ino: 7,
            mtime_ns: now_ns() - 60_000_000_000,
            ctime_ns: now_ns() - 60_000_000_000,
        };
        let mut cache = StatCache::default();
        cache.verified(h, old);
        assert!(cache.trusts(&h, &old));
        assert!(cache.is_dirty());
        let rewritten = Stamp {
            ctime_ns: now_ns(),
            ..old
        };
        assert!(!cache.trusts(&h, &rewritten));
        let resized = Stamp { len: 11, ..old };
        assert!(!cache.trusts(&h, &resized));

        // Verified in the same instant it was written: not trusted (racy), and it replaces the
        // old entry.
        let fresh = Stamp {
            mtime_ns: now_ns(),
            ctime_ns: now_ns(),
            ..old
        };
        cache.verified(h, fresh);
        assert!(!cache.trusts(&h, &fresh));
        assert!(!cache.trusts(&h, &old));

        let restored = StatCache::from_bytes(&{
            let mut c = StatCache::default();
            c.verified(h, old);
            c.to_bytes()
        });
        assert!(restored.trusts(&h, &old));
        assert!(!StatCache::from_bytes(b"garbage").trusts(&h, &old));
    }
}
