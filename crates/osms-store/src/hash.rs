use std::fmt;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// A blake3 digest: the content hash of an object or the key of a stage.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Hash(pub [u8; 32]);

impl Hash {
    pub fn of(bytes: &[u8]) -> Self {
        Hash(*blake3::hash(bytes).as_bytes())
    }

    pub fn to_hex(&self) -> String {
        blake3::Hash::from_bytes(self.0).to_hex().to_string()
    }

    /// The first 12 hex digits: what humans read in tables.
    pub fn short(&self) -> String {
        self.to_hex()[..12].to_string()
    }
}

impl From<blake3::Hash> for Hash {
    fn from(h: blake3::Hash) -> Self {
        Hash(*h.as_bytes())
    }
}

impl fmt::Display for Hash {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.to_hex())
    }
}

impl fmt::Debug for Hash {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Hash({})", self.short())
    }
}

// Hex in human-readable formats (index records, JSON output), raw bytes otherwise.
impl Serialize for Hash {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        if s.is_human_readable() {
            s.serialize_str(&self.to_hex())
        } else {
            self.0.serialize(s)
        }
    }
}

impl<'de> Deserialize<'de> for Hash {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        if d.is_human_readable() {
            let s = String::deserialize(d)?;
            s.parse().map_err(serde::de::Error::custom)
        } else {
            <[u8; 32]>::deserialize(d).map(Hash)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_round_trip_and_known_digest() {
        // blake3("") from the reference test vectors.
        let h = Hash::of(b"");
        assert_eq!(
            h.to_hex(),
            "af1349b9f5f9a1a6a0404dea36dcc9499bcb25c9adc112b7cc9a93cae41f3262"
        );
        assert_eq!(h.to_hex().parse::<Hash>().ok(), Some(h));
        assert_eq!(h.short(), "af1349b9f5f9");
        assert!("xyz".parse::<Hash>().is_err());
    }

    #[test]
    fn serde_hex_in_json_bytes_in_postcard() {
        let h = Hash::of(b"osms");
        let json = serde_json::to_string(&h).unwrap_or_default();
        assert_eq!(json, format!("\"{}\"", h.to_hex()));
        let bytes = postcard::to_stdvec(&h).unwrap_or_default();
        assert_eq!(bytes.len(), 32);
        assert_eq!(postcard::from_bytes::<Hash>(&bytes).ok(), Some(h));
    }
}
