//! The decoder against frames from an attacker: arbitrary bytes, and valid frames with every
//! declared length and byte mutated. Whatever comes, `decode` returns (no panic, no abort), and
//! the largest allocation it makes is bounded by the receiving type's cap and by 255 × the
//! frame's own length (LZ4's ratio): a frame cannot make the bridge allocate more than it could
//! legitimately carry. A counting allocator measures every allocation of this test binary.
#![allow(clippy::unwrap_used)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use proptest::prelude::*;
use sonar_bridge::channel::Channel;
use sonar_bridge::ports::expect;
use sonar_bridge::wire::{Codec, Expect, decode, encode};

/// Records the largest allocation of the current thread while armed (tests run in parallel).
struct Counting;

thread_local! {
    static ARMED: Cell<bool> = const { Cell::new(false) };
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

// SAFETY: forwards to the system allocator; only records sizes in thread-locals of `Copy` types
// (no allocation inside).
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ARMED.try_with(|armed| {
            if armed.get() {
                let _ = LARGEST.try_with(|l| l.set(l.get().max(layout.size())));
            }
        });
        // SAFETY: the caller's layout goes to the system allocator unchanged.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as allocated by `alloc` above.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Decodes `frame` and returns the largest allocation made meanwhile.
fn largest_allocation_decoding(frame: &[u8], expect: &Expect) -> usize {
    LARGEST.with(|l| l.set(0));
    ARMED.with(|a| a.set(true));
    let result = decode(frame, expect);
    ARMED.with(|a| a.set(false));
    drop(result);
    LARGEST.with(Cell::get)
}

fn check_bounded(frame: &[u8], expect: &Expect) -> Result<(), TestCaseError> {
    let largest = largest_allocation_decoding(frame, expect);
    // The type tag of a mismatch is copied into the error: at most 255 bytes, each invalid UTF-8
    // byte replaced by U+FFFD (3 bytes).
    let bound = expect.max_slice_len().min(frame.len() * 255).max(3 * 255);
    prop_assert!(
        largest <= bound,
        "a {}-byte frame made an allocation of {largest} bytes (bound {bound})",
        frame.len()
    );
    Ok(())
}

/// Every channel a bridge receives on, with the payload type's real limits.
fn receivers() -> Vec<Expect> {
    Channel::ALL.into_iter().map(expect).collect()
}

/// A valid frame of `expect`'s type with `elements` slice elements, raw or compressed.
fn valid_frame(expect: &Expect, elements: usize, lz4: bool, fill: u8) -> Vec<u8> {
    let slice = vec![fill; elements.min(expect.max_elements) * expect.element_len];
    let header = vec![0u8; expect.header_len];
    let codec = if lz4 { Codec::Lz4 } else { Codec::Raw };
    encode(&expect.tag, &header, &slice, codec)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn arbitrary_bytes_are_refused_within_bounds(bytes in proptest::collection::vec(any::<u8>(), 0..4096)) {
        for expect in receivers() {
            check_bounded(&bytes, &expect)?;
        }
    }

    #[test]
    fn mutated_frames_are_refused_or_read_within_bounds(
        receiver in 0..Channel::ALL.len(),
        elements in 0usize..3000,
        lz4 in any::<bool>(),
        fill in any::<u8>(),
        declared_slice in any::<u32>(),
        declared_header in any::<u32>(),
        flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 0..8),
        cut in any::<usize>(),
    ) {
        let expect = expect(Channel::ALL[receiver]);
        let frame = valid_frame(&expect, elements, lz4, fill);
        // The frame as sent decodes.
        prop_assert!(decode(&frame, &expect).is_ok());
        // Lying lengths, flipped bytes and a cut tail: refused or read, never beyond the bounds.
        let mut lying = frame.clone();
        lying[12..16].copy_from_slice(&declared_slice.to_le_bytes());
        check_bounded(&lying, &expect)?;
        lying[8..12].copy_from_slice(&declared_header.to_le_bytes());
        check_bounded(&lying, &expect)?;
        let mut flipped = frame.clone();
        for (at, value) in flips {
            let at = at % flipped.len();
            flipped[at] = value;
        }
        check_bounded(&flipped, &expect)?;
        check_bounded(&frame[..cut % (frame.len() + 1)], &expect)?;
    }
}

#[test]
fn the_bombs_of_the_fault_injection_allocate_nothing_large() {
    // 4 kB claiming a 4 GiB LZ4 slice, and 2 MB claiming 512 MiB, on every channel.
    for expect in receivers() {
        for (len, declared) in [(4096usize, u32::MAX), (2_000_000, 512 << 20)] {
            let mut bomb = valid_frame(&expect, 0, true, 0);
            bomb.resize(len.max(bomb.len()), 0x11);
            bomb[12..16].copy_from_slice(&declared.to_le_bytes());
            let largest = largest_allocation_decoding(&bomb, &expect);
            assert!(decode(&bomb, &expect).is_err(), "{}", expect.tag);
            assert!(largest <= 255, "{}: {largest} bytes allocated", expect.tag);
        }
    }
}
