//! What a channel's schema is made of, as each message family gives it.

/// Schema name, schema encoding, schema, message encoding.
pub(crate) type SchemaParts = (String, String, Vec<u8>, String);
