//! What one zenoh message carries: an iceoryx2 sample's bytes, in the documented `#[repr(C)]`
//! layout of `docs/ipc.md`, behind a small frame that names the layout.
//!
//! ```text
//! offset  size  field
//!      0     4  magic "SNBR"
//!      4     1  frame version (1)
//!      5     1  codec of the slice: 0 raw, 1 LZ4 block (the grid's cells)
//!      6     1  length n of the type tag
//!      7     1  reserved, 0
//!      8     4  header length h (u32, little endian)
//!     12     4  slice length s in bytes before compression (u32, little endian)
//!     16     n  type tag, ASCII: the iceoryx2 type name, e.g. `sonar::GridHeaderV1[u8]`
//!   16+n     h  the header: a fixed-size payload (`sonar::ReadingV1`) or a slice's user header
//! 16+n+h     …  the slice's bytes (none for a fixed-size payload), LZ4-compressed under codec 1
//! ```
//!
//! The type tag carries the layout version (every type name ends in it), so a receiver built for
//! another layout refuses the message instead of misreading it. Bytes are in the sender's native
//! order, as in shared memory: both ends are little-endian machines (x86-64, AArch64), which the
//! frame's own fields assume too.

use iceoryx2::prelude::ZeroCopySend;
use sonar_common::ipc::{
    DriverStatus, FeatureRecord, FeaturesHeader, FusionCommand, FusionStatus, GridHeader,
    LocalizedPose, Pose2D, Radar, Reading, ScanCommand,
};

const MAGIC: &[u8; 4] = b"SNBR";
/// Version of the frame itself (not of the payloads, which the type tag names).
pub const FRAME_VERSION: u8 = 1;
const FIXED_LEN: usize = 16;

/// How the slice travels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Codec {
    Raw = 0,
    /// An LZ4 block: a grid of mostly unknown or free cells shrinks 10–50 times.
    Lz4 = 1,
}

/// A message this build cannot take.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error("not a sonar-bridge frame ({0} bytes, no SNBR magic)")]
    NotAFrame(usize),
    #[error("frame version {0}, this build reads {FRAME_VERSION}")]
    FrameVersion(u8),
    #[error("carries {got:?}, expected {expected:?} (another layout version)")]
    TypeMismatch { got: String, expected: String },
    #[error("header of {got} bytes, the layout has {expected}")]
    HeaderLength { got: usize, expected: usize },
    #[error("slice of {len} bytes is not a whole number of {element}-byte elements")]
    SliceLength { len: usize, element: usize },
    #[error("truncated: {0}")]
    Truncated(&'static str),
    #[error("unknown codec {0}")]
    Codec(u8),
    #[error("decompression failed: {0}")]
    Decompress(String),
}

impl FrameError {
    /// True when the sender speaks another layout (counted apart from damaged messages).
    pub fn is_version_mismatch(&self) -> bool {
        matches!(
            self,
            Self::FrameVersion(_) | Self::TypeMismatch { .. } | Self::HeaderLength { .. }
        )
    }
}

/// A payload type whose bytes can be sent as they are in shared memory.
///
/// # Safety
/// The type is `#[repr(C)]`, has no implicit padding (every byte belongs to a field, so reading
/// them reads no uninitialised memory), and every bit pattern of its fields is a valid value
/// (integers, floats and arrays of them; no `bool`, enum or pointer).
pub unsafe trait Plain: Copy + ZeroCopySend + 'static {
    /// The type name, which ends in the layout version.
    fn tag() -> &'static str {
        // SAFETY: only reads the name set with `#[type_name]`; the layout promise it refers to is
        // the one `common::ipc` makes for every payload type.
        unsafe { <Self as ZeroCopySend>::type_name() }
    }
}

// SAFETY: each is `#[repr(C)]` of integers and floats with explicit padding fields; the size checks
// in `common::ipc` and the offsets in `docs/ipc.md` account for every byte.
unsafe impl Plain for Reading {}
unsafe impl Plain for DriverStatus {}
unsafe impl Plain for Radar {}
unsafe impl Plain for Pose2D {}
unsafe impl Plain for LocalizedPose {}
unsafe impl Plain for FusionStatus {}
unsafe impl Plain for ScanCommand {}
unsafe impl Plain for FusionCommand {}
unsafe impl Plain for GridHeader {}
unsafe impl Plain for FeaturesHeader {}
unsafe impl Plain for FeatureRecord {}
// SAFETY: a byte.
unsafe impl Plain for u8 {}

/// The bytes of `value`, as they are in shared memory.
pub fn bytes_of<T: Plain>(value: &T) -> &[u8] {
    // SAFETY: `Plain` promises every byte of `T` is an initialised field byte.
    unsafe { std::slice::from_raw_parts((value as *const T).cast::<u8>(), size_of::<T>()) }
}

/// The bytes of a slice of `T`.
pub fn slice_bytes<T: Plain>(values: &[T]) -> &[u8] {
    // SAFETY: as in `bytes_of`, element by element; arrays of `T` have no padding between elements.
    unsafe { std::slice::from_raw_parts(values.as_ptr().cast::<u8>(), size_of_val(values)) }
}

/// A `T` read from its bytes (`bytes.len()` must be `size_of::<T>()`).
pub fn read_plain<T: Plain>(bytes: &[u8]) -> Option<T> {
    (bytes.len() == size_of::<T>()).then(|| {
        // SAFETY: the length is checked, `read_unaligned` copes with any alignment, and `Plain`
        // promises every bit pattern is a valid `T`.
        unsafe { std::ptr::read_unaligned(bytes.as_ptr().cast::<T>()) }
    })
}

/// The type tag of a fixed-size payload `T`, or of a slice of `E` with user header `T`.
pub fn tag<T: Plain>(element: Option<&str>) -> String {
    match element {
        None => T::tag().to_owned(),
        Some(e) => format!("{}[{e}]", T::tag()),
    }
}

/// Builds a frame around `header` and `slice` (empty for a fixed-size payload).
pub fn encode(tag: &str, header: &[u8], slice: &[u8], codec: Codec) -> Vec<u8> {
    let tag_len = u8::try_from(tag.len()).unwrap_or(u8::MAX);
    let tag = &tag.as_bytes()[..usize::from(tag_len)];
    let body = match codec {
        Codec::Raw => None,
        Codec::Lz4 => Some(lz4_flex::block::compress(slice)),
    };
    let body_bytes = body.as_deref().unwrap_or(slice);
    let mut frame = Vec::with_capacity(FIXED_LEN + tag.len() + header.len() + body_bytes.len());
    frame.extend_from_slice(MAGIC);
    frame.extend_from_slice(&[FRAME_VERSION, codec as u8, tag_len, 0]);
    frame.extend_from_slice(&len_u32(header.len()).to_le_bytes());
    frame.extend_from_slice(&len_u32(slice.len()).to_le_bytes());
    frame.extend_from_slice(tag);
    frame.extend_from_slice(header);
    frame.extend_from_slice(body_bytes);
    frame
}

fn len_u32(len: usize) -> u32 {
    // Payloads are bounded far below 4 GiB (the largest grid is 4096² = 16 MiB).
    u32::try_from(len).unwrap_or(u32::MAX)
}

/// A frame taken apart: the header's bytes and the slice's, decompressed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Decoded<'a> {
    pub header: &'a [u8],
    pub slice: std::borrow::Cow<'a, [u8]>,
}

/// Takes a frame apart, refusing one that does not carry `expected_tag` with a `header_len`-byte
/// header and a slice of whole `element_len`-byte elements.
pub fn decode<'a>(
    frame: &'a [u8],
    expected_tag: &str,
    header_len: usize,
    element_len: usize,
) -> Result<Decoded<'a>, FrameError> {
    if frame.len() < FIXED_LEN || &frame[..4] != MAGIC {
        return Err(FrameError::NotAFrame(frame.len()));
    }
    if frame[4] != FRAME_VERSION {
        return Err(FrameError::FrameVersion(frame[4]));
    }
    let codec = frame[5];
    let tag_len = usize::from(frame[6]);
    let word = |at: usize| {
        let mut b = [0u8; 4];
        b.copy_from_slice(&frame[at..at + 4]);
        u32::from_le_bytes(b) as usize
    };
    let (got_header_len, slice_len) = (word(8), word(12));
    let rest = &frame[FIXED_LEN..];
    let tag = rest
        .get(..tag_len)
        .ok_or(FrameError::Truncated("type tag"))?;
    if tag != expected_tag.as_bytes() {
        return Err(FrameError::TypeMismatch {
            got: String::from_utf8_lossy(tag).into_owned(),
            expected: expected_tag.to_owned(),
        });
    }
    if got_header_len != header_len {
        return Err(FrameError::HeaderLength {
            got: got_header_len,
            expected: header_len,
        });
    }
    let rest = &rest[tag_len..];
    let header = rest
        .get(..header_len)
        .ok_or(FrameError::Truncated("header"))?;
    let body = &rest[header_len..];
    if element_len == 0 || slice_len % element_len != 0 {
        return Err(FrameError::SliceLength {
            len: slice_len,
            element: element_len,
        });
    }
    let slice = match codec {
        0 if body.len() == slice_len => std::borrow::Cow::Borrowed(body),
        0 => return Err(FrameError::Truncated("slice")),
        1 => std::borrow::Cow::Owned(
            lz4_flex::block::decompress(body, slice_len)
                .map_err(|e| FrameError::Decompress(e.to_string()))?,
        ),
        other => return Err(FrameError::Codec(other)),
    };
    if slice.len() != slice_len {
        return Err(FrameError::Truncated("decompressed slice"));
    }
    Ok(Decoded { header, slice })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn grid_tag() -> String {
        tag::<GridHeader>(Some("u8"))
    }

    #[test]
    fn a_grid_round_trips_compressed_byte_for_byte() {
        let header = GridHeader {
            seq: 42,
            width: 300,
            height: 200,
            resolution_m: 0.02,
            ..Default::default()
        };
        let cells: Vec<u8> = (0..60_000u32)
            .map(|i| if i % 97 < 60 { 255 } else { (i % 254) as u8 })
            .collect();
        let frame = encode(&grid_tag(), bytes_of(&header), &cells, Codec::Lz4);
        assert!(frame.len() < cells.len() / 2, "{} bytes", frame.len());
        let got = decode(&frame, &grid_tag(), size_of::<GridHeader>(), 1).unwrap();
        assert_eq!(read_plain::<GridHeader>(got.header), Some(header));
        assert_eq!(&*got.slice, &cells[..]);
    }

    #[test]
    fn a_fixed_payload_round_trips_raw() {
        let cmd = ScanCommand::new(sonar_common::ipc::ScanCommandKind::LocalScan, -30.0, 30.0);
        let tag = tag::<ScanCommand>(None);
        assert_eq!(tag, "sonar::ScanCommandV1");
        let frame = encode(&tag, bytes_of(&cmd), &[], Codec::Raw);
        let got = decode(&frame, &tag, size_of::<ScanCommand>(), 1).unwrap();
        assert_eq!(read_plain::<ScanCommand>(got.header), Some(cmd));
        assert!(got.slice.is_empty());
    }

    #[test]
    fn another_layout_version_is_refused_as_a_mismatch() {
        let status = DriverStatus::default();
        let frame = encode(
            "sonar::DriverStatusV1",
            &bytes_of(&status)[..64],
            &[],
            Codec::Raw,
        );
        let err = decode(
            &frame,
            &tag::<DriverStatus>(None),
            size_of::<DriverStatus>(),
            1,
        )
        .unwrap_err();
        assert!(err.is_version_mismatch(), "{err}");
        let mut future = encode(&grid_tag(), &[0; 88], &[], Codec::Raw);
        future[4] = FRAME_VERSION + 1;
        assert!(
            decode(&future, &grid_tag(), 88, 1)
                .unwrap_err()
                .is_version_mismatch()
        );
    }

    #[test]
    fn damaged_frames_are_errors_not_panics() {
        let grid = grid_tag();
        let frame = encode(&grid, &[7; 88], &[1, 2, 3, 4, 5, 6, 7, 8], Codec::Lz4);
        for cut in 0..frame.len() {
            let err = decode(&frame[..cut], &grid, 88, 1).unwrap_err();
            assert!(!err.is_version_mismatch(), "cut at {cut}: {err}");
        }
        let features = encode(
            &tag::<FeaturesHeader>(Some("f")),
            &[0; 56],
            &[0; 73],
            Codec::Raw,
        );
        assert!(matches!(
            decode(&features, &tag::<FeaturesHeader>(Some("f")), 56, 72),
            Err(FrameError::SliceLength { .. })
        ));
        assert!(matches!(
            decode(b"hello, world, not a frame", &grid, 88, 1),
            Err(FrameError::NotAFrame(_))
        ));
    }
}
