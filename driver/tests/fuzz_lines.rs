//! The body of the fuzz target `lines` (`fuzz/`, `cargo +nightly fuzz run lines`) on stable, over a
//! fixed corpus: every kind of line in both protocol versions and hobby records, then seeded
//! mutations of them of the kinds a serial line and libFuzzer make (bit flips, same-column double
//! flips, cuts, splices, inserted and deleted bytes, numbers respelt), and the inputs that once
//! broke a promise.

#[path = "../../fuzz/src/lib.rs"]
mod fuzz_body;

use sonar_common::protocol::{
    DeviceMessage, DeviceState, Direction, ErrorCode, HostCommand, Limit, MAX_PINGS_PER_READING,
    ProtocolVersion, WireReading, WireScanMode, encode_command, encode_device,
};

/// Inputs that broke a promise once. Both had a number with a leading zero taken (`-07050` for
/// `-7050`, `000` for `0`), so the line read back differently; the first was found by libFuzzer
/// after 3,682 runs, the second by this test's mutations.
const REGRESSIONS: &[&[u8]] = &[
    b"$RD,1,475,1,+,-07050,4,6989,0,6920,6991*3951\n",
    b"$SCAN,LOCAL,000,3000*4D\n",
];

/// Mutated inputs per run: a few seconds unoptimised.
const MUTANTS: usize = 10_000;

#[test]
fn the_fuzz_body_holds_on_a_fixed_corpus() {
    let seeds = seeds();
    for input in seeds
        .iter()
        .map(Vec::as_slice)
        .chain(REGRESSIONS.iter().copied())
    {
        fuzz_body::lines(input);
    }
    let mut rng = SplitMix64(0x5eed_f00d);
    for _ in 0..MUTANTS {
        fuzz_body::lines(&mutant(&seeds, &mut rng));
    }
}

fn seeds() -> Vec<Vec<u8>> {
    let mut echo_us = [0; MAX_PINGS_PER_READING];
    echo_us[..4].copy_from_slice(&[5800, 5830, 0, 5790]);
    let messages = [
        DeviceMessage::Hello {
            version: 2,
            firmware: "sonar-sim 0.1.0".into(),
            head_id: "3F2A9C0417B6E5D1".into(),
            step_cdeg: 150,
            pings_per_reading: 4,
            min_cdeg: -15000,
            max_cdeg: 15000,
        },
        DeviceMessage::Ack {
            command: "SCAN".into(),
        },
        DeviceMessage::Reading(WireReading {
            seq: 7,
            time_ms: 123_456,
            sweep: 3,
            direction: Direction::Cw,
            angle_cdeg: -14_700,
            ping_count: 4,
            echo_us,
        }),
        DeviceMessage::LimitHit(Limit::Max),
        DeviceMessage::SweepStart {
            sweep: 2,
            direction: Direction::Ccw,
            mode: WireScanMode::Local,
            from_cdeg: -2700,
            to_cdeg: 2700,
        },
        DeviceMessage::SweepEnd { sweep: 2 },
        DeviceMessage::Status {
            state: DeviceState::Homing,
            angle_cdeg: 4425,
            direction: Direction::Cw,
            sweep: 9,
        },
        DeviceMessage::Error {
            code: ErrorCode::Range,
            text: "segment outside the limits".into(),
        },
    ];
    let commands = [
        HostCommand::Hello { version: 2 },
        HostCommand::FullScan,
        HostCommand::LocalScan {
            from_cdeg: -3000,
            to_cdeg: 3000,
        },
        HostCommand::Stop,
        HostCommand::Status,
    ];
    let mut seeds: Vec<Vec<u8>> = Vec::new();
    for version in [ProtocolVersion::V1, ProtocolVersion::V2] {
        seeds.extend(
            messages
                .iter()
                .map(|m| encode_device(m, version).into_bytes()),
        );
        seeds.extend(
            commands
                .iter()
                .map(|c| encode_command(c, version).into_bytes()),
        );
    }
    seeds.push(b"15,118.16,118.17,510#90,0\r\n37;18.".to_vec());
    seeds
}

/// A small, seedable generator, so that the corpus is the same on every machine.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n` > 0), near enough.
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    fn byte(&mut self) -> u8 {
        self.next() as u8
    }
}

fn mutant(seeds: &[Vec<u8>], rng: &mut SplitMix64) -> Vec<u8> {
    let mut out = seeds[rng.below(seeds.len())].clone();
    for _ in 0..=rng.below(3) {
        mutate(&mut out, seeds, rng);
    }
    out
}

fn mutate(out: &mut Vec<u8>, seeds: &[Vec<u8>], rng: &mut SplitMix64) {
    if out.is_empty() {
        out.push(rng.byte());
        return;
    }
    let i = rng.below(out.len());
    match rng.below(9) {
        0 => out[i] ^= 1 << rng.below(8),
        1 => {
            let bit = 1 << rng.below(7);
            let j = rng.below(out.len());
            out[i] ^= bit;
            out[j] ^= bit;
        }
        2 => out.truncate(i),
        3 => out.insert(i, rng.byte()),
        4 => {
            out.remove(i);
        }
        5 => {
            let other = &seeds[rng.below(seeds.len())];
            let cut = rng.below(other.len());
            out.truncate(i);
            out.extend_from_slice(&other[cut..]);
        }
        6 => {
            // A number respelt: a leading zero, a sign, a digit more.
            let respelt: &[u8] = [b"0".as_slice(), b"-", b"-0", b"+", b"9"][rng.below(5)];
            out.splice(i..i, respelt.iter().copied());
        }
        7 => {
            let len = rng.below(200);
            out.extend((0..len).map(|_| rng.byte()));
        }
        _ => {
            let other = &seeds[rng.below(seeds.len())];
            out.extend_from_slice(other);
        }
    }
}
