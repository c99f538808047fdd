//! Bytes off the serial line through the framer, both versions' parsers and the driver's decoder;
//! see `sonar_fuzz::lines`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| sonar_fuzz::lines(data));
