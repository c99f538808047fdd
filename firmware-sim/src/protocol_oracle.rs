//! The firmware's command parser (`firmware/src/protocol.c`, built for the host by `build.rs`)
//! against the Rust one (`sonar_common::protocol::parse_command`) as its oracle: every line one
//! takes the other takes, with the same meaning, and every line one refuses the other refuses.
//! The lines are the commands of protocol version 2 and seeded mutations of the kinds that broke
//! a parser before: numbers respelt (leading zeros, `+`, `-0`, past 32 bits), bytes flipped,
//! inserted, deleted and fields repeated, each framed with a correct check (a random check would
//! stop both parsers at the CRC) and now and then with a wrong one.

use std::ffi::c_char;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sonar_common::protocol::{HostCommand, ProtocolVersion, parse_command};

/// `proto_cmd` of `protocol.h`.
#[repr(C)]
#[derive(Debug, Default)]
struct ProtoCmd {
    kind: u8,
    version: u32,
    from_cdeg: i32,
    to_cdeg: i32,
}

/// `PROTO_MAX_LINE` and `PROTO_TEXT_MAX` of `protocol.h`: the framer never hands the parser a
/// longer line.
const MAX_LINE: usize = 160;
const TEXT_MAX: usize = 80;

unsafe extern "C" {
    fn proto_parse_command(
        line: *const c_char,
        len: u8,
        cmd: *mut ProtoCmd,
        text: *mut c_char,
    ) -> u8;
}

/// What the firmware makes of `line`: the command, or `None` when it refuses it.
fn firmware_parse(line: &[u8]) -> Option<HostCommand> {
    let len = u8::try_from(line.len()).ok()?;
    let mut cmd = ProtoCmd::default();
    let mut text = [0 as c_char; TEXT_MAX + 1];
    // SAFETY: `line` is valid for `len` bytes, `cmd` and `text` (PROTO_TEXT_MAX + 1 bytes, as
    // protocol.h asks) are valid for writes; the parser keeps no pointer past the call.
    let err =
        unsafe { proto_parse_command(line.as_ptr().cast(), len, &mut cmd, text.as_mut_ptr()) };
    (err == 0).then(|| match cmd.kind {
        0 => HostCommand::Hello {
            version: cmd.version,
        },
        1 => HostCommand::FullScan,
        2 => HostCommand::LocalScan {
            from_cdeg: cmd.from_cdeg,
            to_cdeg: cmd.to_cdeg,
        },
        3 => HostCommand::Stop,
        4 => HostCommand::Status,
        5 => HostCommand::Reset,
        other => panic!("the firmware parsed {line:?} into an unknown kind {other}"),
    })
}

/// `$BODY*CRC` as version 2 frames it.
fn framed(body: &[u8]) -> Vec<u8> {
    let check = format!("{:04X}", ProtocolVersion::V2.check(body));
    [b"$", body, b"*", check.as_bytes()].concat()
}

const BODIES: &[&str] = &[
    "HELLO,2",
    "HELLO,1",
    "SCAN,FULL",
    "SCAN,LOCAL,-3000,3000",
    "SCAN,LOCAL,0,100",
    "SCAN,LOCAL,-15000,15000",
    "STOP",
    "STATUS",
    "RESET",
];

/// Spellings a number may be given in, right or wrong.
const NUMBERS: &[&str] = &[
    "0",
    "-0",
    "+0",
    "00",
    "007",
    "-007",
    "+5",
    "2",
    "-1",
    "2147483647",
    "2147483648",
    "-2147483648",
    "-2147483649",
    "4294967295",
    "4294967296",
    "99999999999",
    "",
    " 1",
    "1 ",
    "0x10",
    "1e3",
    "--1",
];

const ALPHABET: &[u8] = b",-+0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZ*$ abc\t";

fn mutant(rng: &mut ChaCha8Rng) -> Vec<u8> {
    let mut body = BODIES[rng.random_range(0..BODIES.len())]
        .as_bytes()
        .to_vec();
    for _ in 0..rng.random_range(1..=3) {
        match rng.random_range(0..6) {
            // A number field respelt.
            0 => {
                let text = String::from_utf8_lossy(&body).into_owned();
                let mut fields: Vec<String> = text.split(',').map(str::to_owned).collect();
                let i = rng.random_range(0..fields.len());
                fields[i] = NUMBERS[rng.random_range(0..NUMBERS.len())].to_owned();
                body = fields.join(",").into_bytes();
            }
            1 if !body.is_empty() => {
                let i = rng.random_range(0..body.len());
                body[i] ^= 1 << rng.random_range(0..8);
            }
            2 => {
                let i = rng.random_range(0..=body.len());
                body.insert(i, ALPHABET[rng.random_range(0..ALPHABET.len())]);
            }
            3 if !body.is_empty() => {
                body.remove(rng.random_range(0..body.len()));
            }
            4 => {
                let text = String::from_utf8_lossy(&body).into_owned();
                let fields: Vec<&str> = text.split(',').collect();
                let repeated = fields[rng.random_range(0..fields.len())];
                body = format!("{text},{repeated}").into_bytes();
            }
            _ => {}
        }
    }
    let mut line = framed(&body);
    if rng.random_bool(0.05) {
        let last = line.len() - 1;
        line[last] = if line[last] == b'0' { b'1' } else { b'0' };
    }
    line
}

#[test]
fn the_firmware_parses_every_command_as_the_rust_parser_does() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed_c0de);
    let mut taken = 0;
    let lines = BODIES
        .iter()
        .map(|b| framed(b.as_bytes()))
        .chain((0..20_000).map(|_| mutant(&mut rng)))
        .filter(|l| l.len() <= MAX_LINE);
    for line in lines {
        let rust = parse_command(&line, ProtocolVersion::V2).ok();
        let firmware = firmware_parse(&line);
        assert_eq!(
            firmware,
            rust,
            "{:?}: the firmware and the Rust parser disagree",
            String::from_utf8_lossy(&line)
        );
        taken += usize::from(rust.is_some());
    }
    // Enough lines get through both parsers' checks for the comparison to mean something.
    assert!(taken > 1_000, "only {taken} lines taken");
}
