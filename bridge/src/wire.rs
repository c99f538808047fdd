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
//! another layout refuses the message instead of misreading it. A frame comes from the network:
//! [`decode`] checks every length it declares (the whole frame's, the header's, the slice's, the
//! size LZ4 promises) against what the receiving payload type can hold ([`Expect`]) before it
//! allocates anything, so a lying frame costs its own bytes and no more. Bytes are in the sender's native
//! order, as in shared memory: both ends are little-endian machines (x86-64, AArch64), which the
//! frame's own fields assume too.

use iceoryx2::prelude::ZeroCopySend;
use sonar_common::ipc::{
    DriverStatus, FeatureRecord, FeaturesHeader, FusionCommand, FusionStatus, GridHeader,
    LocalizedPose, Pose2D, Radar, Reading, ScanCommand, SweepEnd,
};

const MAGIC: &[u8; 4] = b"SNBR";
/// Version of the frame itself (not of the payloads, which the type tag names).
pub const FRAME_VERSION: u8 = 1;
const FIXED_LEN: usize = 16;
/// The most bytes an LZ4 block can expand to per compressed byte: a match token of 1 byte plus a
/// 2-byte offset yields at most 255 bytes per extra length byte, so any declared size above
/// 255 × the block's length is a lie, refused before the output buffer is allocated.
const LZ4_MAX_RATIO: usize = 255;

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
    #[error("frame of {len} bytes, more than the {cap} this payload can take")]
    FrameTooLong { len: usize, cap: usize },
    #[error("declares a slice of {declared} bytes, more than the {cap} this payload can take")]
    SliceTooLong { declared: usize, cap: usize },
    #[error("its header says {said} elements, the slice carries {carried}")]
    HeaderDisagrees { said: usize, carried: usize },
    #[error("declares {declared} bytes from {compressed} compressed, beyond LZ4's ratio")]
    Lz4Ratio { declared: usize, compressed: usize },
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

/// What a receiver takes: the layout its payload type has and the most elements its slice holds.
/// Every length a frame declares is checked against it before anything is allocated.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Expect {
    /// The type tag, as [`tag`] makes it.
    pub tag: String,
    /// The fixed-size payload's or the slice's user header's size.
    pub header_len: usize,
    /// Bytes of one slice element (1 for a fixed-size payload, whose slice must be empty).
    pub element_len: usize,
    /// The most elements the slice may have (0: a fixed-size payload).
    pub max_elements: usize,
}

impl Expect {
    /// A fixed-size payload `T`.
    pub fn fixed<T: Plain>() -> Self {
        Self {
            tag: tag::<T>(None),
            header_len: size_of::<T>(),
            element_len: 1,
            max_elements: 0,
        }
    }

    /// A slice of at most `max_elements` `E` with user header `H`.
    pub fn slice<H: Plain, E: Plain>(max_elements: usize) -> Self {
        Self {
            tag: tag::<H>(Some(E::tag())),
            header_len: size_of::<H>(),
            element_len: size_of::<E>(),
            max_elements,
        }
    }

    /// The most slice bytes (uncompressed) a frame may declare.
    pub fn max_slice_len(&self) -> usize {
        self.max_elements.saturating_mul(self.element_len)
    }

    /// The longest frame this receiver takes: the raw slice, or its LZ4 block if that is longer
    /// (incompressible input grows by 1/255 plus a few bytes).
    pub fn max_frame_len(&self) -> usize {
        let slice = self.max_slice_len();
        let lz4_worst = slice + slice / LZ4_MAX_RATIO + 16;
        FIXED_LEN + self.tag.len() + self.header_len + lz4_worst
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
unsafe impl Plain for SweepEnd {}
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

/// Takes a frame apart, refusing one that does not carry `expect`'s layout or declares more than
/// it can hold. Nothing is allocated before every declared length has been checked: an LZ4 slice
/// is decompressed into a buffer of its declared size only when that size is within the cap and
/// within what the compressed bytes can expand to.
pub fn decode<'a>(frame: &'a [u8], expect: &Expect) -> Result<Decoded<'a>, FrameError> {
    if frame.len() < FIXED_LEN || &frame[..4] != MAGIC {
        return Err(FrameError::NotAFrame(frame.len()));
    }
    if frame[4] != FRAME_VERSION {
        return Err(FrameError::FrameVersion(frame[4]));
    }
    let cap = expect.max_frame_len();
    if frame.len() > cap {
        return Err(FrameError::FrameTooLong {
            len: frame.len(),
            cap,
        });
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
    if tag != expect.tag.as_bytes() {
        return Err(FrameError::TypeMismatch {
            got: String::from_utf8_lossy(tag).into_owned(),
            expected: expect.tag.clone(),
        });
    }
    if got_header_len != expect.header_len {
        return Err(FrameError::HeaderLength {
            got: got_header_len,
            expected: expect.header_len,
        });
    }
    let rest = &rest[tag_len..];
    let header = rest
        .get(..expect.header_len)
        .ok_or(FrameError::Truncated("header"))?;
    let body = &rest[expect.header_len..];
    if expect.element_len == 0 || slice_len % expect.element_len != 0 {
        return Err(FrameError::SliceLength {
            len: slice_len,
            element: expect.element_len,
        });
    }
    if slice_len > expect.max_slice_len() {
        return Err(FrameError::SliceTooLong {
            declared: slice_len,
            cap: expect.max_slice_len(),
        });
    }
    let slice = match codec {
        0 if body.len() == slice_len => std::borrow::Cow::Borrowed(body),
        0 => return Err(FrameError::Truncated("slice")),
        1 if slice_len > body.len().saturating_mul(LZ4_MAX_RATIO) => {
            return Err(FrameError::Lz4Ratio {
                declared: slice_len,
                compressed: body.len(),
            });
        }
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

    /// A grid of at most 400² cells, as a test receiver.
    fn grid() -> Expect {
        Expect::slice::<GridHeader, u8>(400 * 400)
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
        let frame = encode(&grid().tag, bytes_of(&header), &cells, Codec::Lz4);
        assert!(frame.len() < cells.len() / 2, "{} bytes", frame.len());
        let got = decode(&frame, &grid()).unwrap();
        assert_eq!(read_plain::<GridHeader>(got.header), Some(header));
        assert_eq!(&*got.slice, &cells[..]);
    }

    #[test]
    fn the_most_compressible_and_the_least_compressible_grids_fit_the_caps() {
        // All cells alike compress the most: the declared size must stay within LZ4's ratio.
        let expect = Expect::slice::<GridHeader, u8>(1024 * 1024);
        let uniform = vec![127u8; expect.max_elements];
        let frame = encode(&expect.tag, &[0; 88], &uniform, Codec::Lz4);
        assert_eq!(decode(&frame, &expect).unwrap().slice.len(), uniform.len());
        // Noise does not compress: the block is longer than the cells, and still within the cap.
        let mut x = 0x9E37_79B9u32;
        let noise: Vec<u8> = (0..expect.max_elements)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                x as u8
            })
            .collect();
        let frame = encode(&expect.tag, &[0; 88], &noise, Codec::Lz4);
        assert!(frame.len() > noise.len());
        assert_eq!(&*decode(&frame, &expect).unwrap().slice, &noise[..]);
    }

    #[test]
    fn a_fixed_payload_round_trips_raw() {
        let cmd = ScanCommand::new(sonar_common::ipc::ScanCommandKind::LocalScan, -30.0, 30.0);
        let expect = Expect::fixed::<ScanCommand>();
        assert_eq!(expect.tag, "sonar::ScanCommandV1");
        let frame = encode(&expect.tag, bytes_of(&cmd), &[], Codec::Raw);
        let got = decode(&frame, &expect).unwrap();
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
        let err = decode(&frame, &Expect::fixed::<DriverStatus>()).unwrap_err();
        assert!(err.is_version_mismatch(), "{err}");
        let mut future = encode(&grid().tag, &[0; 88], &[], Codec::Raw);
        future[4] = FRAME_VERSION + 1;
        assert!(decode(&future, &grid()).unwrap_err().is_version_mismatch());
    }

    #[test]
    fn damaged_frames_are_errors_not_panics() {
        let frame = encode(&grid().tag, &[7; 88], &[1, 2, 3, 4, 5, 6, 7, 8], Codec::Lz4);
        for cut in 0..frame.len() {
            let err = decode(&frame[..cut], &grid()).unwrap_err();
            assert!(!err.is_version_mismatch(), "cut at {cut}: {err}");
        }
        let features = Expect::slice::<FeaturesHeader, FeatureRecord>(4);
        let ragged = encode(&features.tag, &[0; 56], &[0; 73], Codec::Raw);
        assert!(matches!(
            decode(&ragged, &features),
            Err(FrameError::SliceLength { .. })
        ));
        assert!(matches!(
            decode(b"hello, world, not a frame", &grid()),
            Err(FrameError::NotAFrame(_))
        ));
    }

    /// Sets the slice length a frame declares.
    fn declare_slice_len(frame: &mut [u8], len: u32) {
        frame[12..16].copy_from_slice(&len.to_le_bytes());
    }

    #[test]
    fn the_4_kb_bomb_of_the_fault_injection_is_refused_before_it_allocates() {
        // A command frame (the robot's only inbound channel) claiming an LZ4 slice of 4 GiB: it
        // aborted the bridge with "memory allocation of 4294967295 bytes failed".
        let command = Expect::fixed::<ScanCommand>();
        let mut bomb = encode(&command.tag, &[0; 16], &[], Codec::Raw);
        bomb[5] = Codec::Lz4 as u8;
        declare_slice_len(&mut bomb, u32::MAX);
        let mut bomb = bomb[..FIXED_LEN + command.tag.len() + 16].to_vec();
        bomb.resize(bomb.len() + 4000, 0xAB);
        let err = decode(&bomb, &command).unwrap_err();
        assert!(matches!(err, FrameError::FrameTooLong { .. }), "{err}");
        // The same declaration in a frame short enough to pass the frame cap.
        bomb.truncate(FIXED_LEN + command.tag.len() + 16);
        let err = decode(&bomb, &command).unwrap_err();
        assert!(matches!(err, FrameError::SliceTooLong { .. }), "{err}");
    }

    #[test]
    fn each_declared_length_is_held_against_its_cap() {
        let expect = grid();
        let cells = vec![0u8; 1000];
        // Within the cap, but far beyond what 1000 cells' block can expand to.
        let mut frame = encode(&expect.tag, &[0; 88], &cells, Codec::Lz4);
        declare_slice_len(&mut frame, 150_000);
        let err = decode(&frame, &expect).unwrap_err();
        assert!(matches!(err, FrameError::Lz4Ratio { .. }), "{err}");
        // One cell over the cap, raw: refused by the declaration, not by the missing bytes.
        let mut frame = encode(&expect.tag, &[0; 88], &cells, Codec::Raw);
        declare_slice_len(&mut frame, (400 * 400 + 1) as u32);
        let err = decode(&frame, &expect).unwrap_err();
        assert!(matches!(err, FrameError::SliceTooLong { .. }), "{err}");
        // A frame longer than the cap whatever it declares: 2 MB for a 160 kB grid.
        let big = encode(&expect.tag, &[0; 88], &vec![1u8; 2_000_000], Codec::Raw);
        let err = decode(&big, &expect).unwrap_err();
        assert!(matches!(err, FrameError::FrameTooLong { .. }), "{err}");
        assert!(expect.max_frame_len() < 2_000_000);
        // A fixed-size payload takes no slice at all.
        let command = Expect::fixed::<ScanCommand>();
        let frame = encode(&command.tag, &[0; 16], &[9], Codec::Raw);
        let err = decode(&frame, &command).unwrap_err();
        assert!(matches!(err, FrameError::SliceTooLong { .. }), "{err}");
    }
}
