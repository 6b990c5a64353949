//! The artifact file format: a small uncompressed header, then one zstd frame holding the
//! postcard encoding of the artifact.
//!
//! ```text
//! magic "OSMSART\0" | format version u16 LE | schema version u16 LE | tag length u8 | tag | zstd(postcard)
//! ```
//!
//! The header is readable without decompressing, so `osms show` and `osms verify` can name the
//! type of any object, and a foreign or newer file is refused before any decoding starts.

use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::{Error, Result};

pub const MAGIC: &[u8; 8] = b"OSMSART\0";
/// Bumped when the header layout or the payload encoding changes.
pub const FORMAT_VERSION: u16 = 1;
/// Fixed: changing it changes every content hash, so it is part of the format.
const ZSTD_LEVEL: i32 = 3;
const MAX_TAG_LEN: usize = 64;

/// A value that can be stored. The tag names the type in headers and `osms show`; the schema
/// version is bumped whenever the serialized shape of the type changes.
pub trait Artifact: Serialize + DeserializeOwned {
    const TYPE_TAG: &'static str;
    const SCHEMA_VERSION: u16;
}

/// The decoded header of an artifact file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Header {
    pub format_version: u16,
    pub schema_version: u16,
    pub type_tag: String,
    /// Byte offset of the zstd payload.
    pub payload_offset: usize,
}

pub fn encode<A: Artifact>(artifact: &A) -> Result<Vec<u8>> {
    encode_as(A::TYPE_TAG, A::SCHEMA_VERSION, artifact)
}

/// Encodes `value` under the header of type `tag`: for values that are written through a
/// borrowed view of an [`Artifact`] (which [`decode`] then reads as the owned type).
pub fn encode_as<T: Serialize + ?Sized>(
    tag: &str,
    schema_version: u16,
    value: &T,
) -> Result<Vec<u8>> {
    assert!(
        !tag.is_empty() && tag.len() <= MAX_TAG_LEN && tag.is_ascii(),
        "artifact type tag `{tag}` must be 1..={MAX_TAG_LEN} ASCII bytes"
    );
    let raw = postcard::to_stdvec(value).map_err(|source| Error::Encode {
        tag: tag.to_string(),
        source,
    })?;
    let packed = zstd::bulk::compress(&raw, ZSTD_LEVEL).map_err(|e| Error::Decode {
        tag: tag.to_string(),
        reason: format!("zstd compression failed: {e}"),
    })?;
    let mut out = Vec::with_capacity(MAGIC.len() + 5 + tag.len() + packed.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&schema_version.to_le_bytes());
    out.push(tag.len() as u8);
    out.extend_from_slice(tag.as_bytes());
    out.extend_from_slice(&packed);
    Ok(out)
}

pub fn read_header(bytes: &[u8]) -> Result<Header> {
    let foreign = |reason: &str| Error::Foreign {
        reason: reason.to_string(),
    };
    if bytes.len() < MAGIC.len() || &bytes[..MAGIC.len()] != MAGIC {
        return Err(foreign(
            "the file does not start with the osms artifact magic",
        ));
    }
    let rest = &bytes[MAGIC.len()..];
    if rest.len() < 5 {
        return Err(foreign("the header is truncated"));
    }
    let format_version = u16::from_le_bytes([rest[0], rest[1]]);
    if format_version > FORMAT_VERSION {
        return Err(Error::NewerFormat {
            found: format_version,
            supported: FORMAT_VERSION,
        });
    }
    let schema_version = u16::from_le_bytes([rest[2], rest[3]]);
    let tag_len = rest[4] as usize;
    let tag_end = 5 + tag_len;
    if tag_len == 0 || rest.len() < tag_end {
        return Err(foreign("the type tag is truncated"));
    }
    let type_tag = std::str::from_utf8(&rest[5..tag_end])
        .map_err(|_| foreign("the type tag is not text"))?
        .to_string();
    Ok(Header {
        format_version,
        schema_version,
        type_tag,
        payload_offset: MAGIC.len() + tag_end,
    })
}

pub fn decode<A: Artifact>(bytes: &[u8]) -> Result<A> {
    let header = read_header(bytes)?;
    if header.type_tag != A::TYPE_TAG {
        return Err(Error::WrongType {
            expected: A::TYPE_TAG.to_string(),
            found: header.type_tag,
        });
    }
    if header.schema_version != A::SCHEMA_VERSION {
        return Err(Error::SchemaMismatch {
            tag: header.type_tag,
            found: header.schema_version,
            expected: A::SCHEMA_VERSION,
        });
    }
    let fail = |reason: String| Error::Decode {
        tag: A::TYPE_TAG.to_string(),
        reason,
    };
    let raw = zstd::decode_all(&bytes[header.payload_offset..])
        .map_err(|e| fail(format!("zstd payload is corrupt: {e}")))?;
    let (value, rest) = postcard::take_from_bytes::<A>(&raw).map_err(|e| fail(e.to_string()))?;
    if !rest.is_empty() {
        return Err(fail(format!(
            "{} trailing bytes after the value",
            rest.len()
        )));
    }
    Ok(value)
}

#[cfg(test)]
mod tests {
    use serde::Deserialize;

    use super::*;

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Numbers {
        values: Vec<f64>,
        label: String,
    }
    impl Artifact for Numbers {
        const TYPE_TAG: &'static str = "test-numbers";
        const SCHEMA_VERSION: u16 = 3;
    }

    #[derive(Debug, Serialize, Deserialize)]
    struct Other(u32);
    impl Artifact for Other {
        const TYPE_TAG: &'static str = "test-other";
        const SCHEMA_VERSION: u16 = 1;
    }

    fn sample() -> Numbers {
        Numbers {
            values: (0..1000).map(|i| f64::from(i) * 0.5).collect(),
            label: "x".into(),
        }
    }

    #[test]
    fn round_trip_and_header() {
        let bytes = encode(&sample()).expect("encode");
        let header = read_header(&bytes).expect("header");
        assert_eq!(header.type_tag, "test-numbers");
        assert_eq!(header.schema_version, 3);
        assert_eq!(header.format_version, FORMAT_VERSION);
        assert_eq!(decode::<Numbers>(&bytes).expect("decode"), sample());
    }

    /// Set in the child process of [`encoding_is_deterministic`]: where it writes its bytes.
    const CHILD_OUT: &str = "OSMS_CODEC_TEST_CHILD_OUT";

    /// Encoding is a function of the value alone: the same bytes twice in one process and in
    /// another process (its own allocator state, address layout and hash seeds), which this
    /// test starts by running itself.
    #[test]
    fn encoding_is_deterministic() {
        let bytes = encode(&sample()).expect("encode");
        assert_eq!(encode(&sample()).expect("encode"), bytes);
        if let Some(out) = std::env::var_os(CHILD_OUT) {
            std::fs::write(out, &bytes).expect("write the child's bytes");
            return;
        }
        let out = std::env::temp_dir().join(format!("osms-codec-{}", std::process::id()));
        let status = std::process::Command::new(std::env::current_exe().expect("test binary"))
            .args([
                "--exact",
                "codec::tests::encoding_is_deterministic",
                "--quiet",
            ])
            .env(CHILD_OUT, &out)
            .status()
            .expect("run the child");
        assert!(status.success(), "the child process failed");
        let theirs = std::fs::read(&out).expect("the child's bytes");
        let _ = std::fs::remove_file(&out);
        assert_eq!(theirs, bytes, "another process encoded other bytes");
    }

    #[test]
    fn foreign_newer_wrong_type_and_truncated_are_refused() {
        assert!(matches!(
            read_header(b"PK\x03\x04 a zip file"),
            Err(Error::Foreign { .. })
        ));
        let mut bytes = encode(&sample()).expect("encode");
        assert!(matches!(
            decode::<Other>(&bytes),
            Err(Error::WrongType { .. })
        ));
        let truncated = &bytes[..bytes.len() - 10];
        assert!(matches!(
            decode::<Numbers>(truncated),
            Err(Error::Decode { .. })
        ));
        bytes[8] = 0xff;
        assert!(matches!(
            read_header(&bytes),
            Err(Error::NewerFormat { .. })
        ));
    }

    #[test]
    fn schema_bump_is_refused() {
        #[derive(Serialize, Deserialize)]
        struct NumbersV4 {
            values: Vec<f64>,
            label: String,
        }
        impl Artifact for NumbersV4 {
            const TYPE_TAG: &'static str = "test-numbers";
            const SCHEMA_VERSION: u16 = 4;
        }
        let bytes = encode(&sample()).expect("encode");
        assert!(matches!(
            decode::<NumbersV4>(&bytes),
            Err(Error::SchemaMismatch { .. })
        ));
    }
}
