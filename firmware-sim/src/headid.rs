//! The head's identity in EEPROM, in the firmware's layout: bytes 0..7 the id, 8..9 the
//! CRC-16/CCITT-FALSE of those eight, big-endian. A blank EEPROM (0xFF, a new chip) makes the
//! firmware draw an id at its first boot.

use std::fmt;
use std::str::FromStr;

use sonar_common::protocol::crc16_ccitt_false;

/// Bytes of the id.
pub const ID_LEN: usize = 8;
/// Bytes of the EEPROM record: id and CRC.
pub const RECORD_LEN: usize = ID_LEN + 2;

/// An 8-byte head id, written as 16 hex digits as in the `HELLO` reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HeadId(pub [u8; ID_LEN]);

/// A `--head-id` that is not 16 hex digits.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0:?} is no head id: give 16 hex digits, e.g. 3F2A9C0417B6E5D1")]
pub struct BadHeadId(pub String);

impl FromStr for HeadId {
    type Err = BadHeadId;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || BadHeadId(s.to_owned());
        if s.len() != 2 * ID_LEN || !s.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(bad());
        }
        let mut id = [0u8; ID_LEN];
        for (byte, pair) in id.iter_mut().zip(s.as_bytes().chunks(2)) {
            let digits = std::str::from_utf8(pair).map_err(|_| bad())?;
            *byte = u8::from_str_radix(digits, 16).map_err(|_| bad())?;
        }
        Ok(Self(id))
    }
}

impl fmt::Display for HeadId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.iter().try_for_each(|b| write!(f, "{b:02X}"))
    }
}

impl HeadId {
    /// The EEPROM record: id, then its CRC big-endian.
    pub fn record(&self) -> [u8; RECORD_LEN] {
        let mut rec = [0u8; RECORD_LEN];
        rec[..ID_LEN].copy_from_slice(&self.0);
        rec[ID_LEN..].copy_from_slice(&crc16_ccitt_false(&self.0).to_be_bytes());
        rec
    }

    /// The id in an EEPROM record, if its CRC holds.
    pub fn from_record(rec: &[u8; RECORD_LEN]) -> Option<Self> {
        let mut id = [0u8; ID_LEN];
        id.copy_from_slice(&rec[..ID_LEN]);
        let crc = u16::from_be_bytes([rec[ID_LEN], rec[ID_LEN + 1]]);
        (crc16_ccitt_false(&id) == crc).then_some(Self(id))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_parse_from_hex_and_print_back_in_upper_case() {
        let id: HeadId = "3f2a9c0417B6E5D1".parse().unwrap();
        assert_eq!(id.0, [0x3F, 0x2A, 0x9C, 0x04, 0x17, 0xB6, 0xE5, 0xD1]);
        assert_eq!(id.to_string(), "3F2A9C0417B6E5D1");
        for bad in [
            "",
            "3F2A9C0417B6E5D",
            "3F2A9C0417B6E5D1F",
            "3F2A9C0417B6E5DG",
            "+F2A9C0417B6E5D1",
        ] {
            assert!(bad.parse::<HeadId>().is_err(), "{bad}");
        }
        assert!("3F2A9C0417B6E5Dé".parse::<HeadId>().is_err());
    }

    #[test]
    fn the_record_carries_the_crc_big_endian() {
        // CRC-16/CCITT-FALSE of "12345678" is 0xA12B.
        let id = HeadId(*b"12345678");
        let rec = id.record();
        assert_eq!(&rec[..8], b"12345678");
        assert_eq!(rec[8..], [0xA1, 0x2B]);
        assert_eq!(HeadId::from_record(&rec), Some(id));
        let mut broken = rec;
        broken[3] ^= 1;
        assert_eq!(HeadId::from_record(&broken), None);
        assert_eq!(
            HeadId::from_record(&[0xFF; RECORD_LEN]),
            None,
            "blank EEPROM"
        );
    }
}
