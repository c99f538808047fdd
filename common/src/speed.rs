//! How fast a time source runs against wall time: the simulator's clock, a replay's timestamps.

use std::fmt;
use std::str::FromStr;

/// A speed factor or "as fast as possible", as the `--speed` flags take it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Speed {
    /// Source seconds per wall second (1 = real time).
    Factor(f64),
    /// As fast as the consumer (and any rate ceiling) allows.
    Max,
}

impl FromStr for Speed {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.eq_ignore_ascii_case("max") {
            return Ok(Speed::Max);
        }
        match s.parse::<f64>() {
            Ok(f) if f.is_finite() && f > 0.0 => Ok(Speed::Factor(f)),
            _ => Err(format!(
                "{s:?} is not a speed: give a factor > 0 (1 = real time) or `max`"
            )),
        }
    }
}

impl fmt::Display for Speed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Speed::Factor(x) => write!(f, "{x}×"),
            Speed::Max => f.write_str("max"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speeds_parse_as_factors_or_max() {
        assert_eq!("max".parse(), Ok(Speed::Max));
        assert_eq!("MAX".parse(), Ok(Speed::Max));
        assert_eq!("1".parse(), Ok(Speed::Factor(1.0)));
        assert_eq!("20".parse(), Ok(Speed::Factor(20.0)));
        assert_eq!("0.5".parse(), Ok(Speed::Factor(0.5)));
        for bad in ["0", "-1", "inf", "NaN", "fast", ""] {
            assert!(bad.parse::<Speed>().is_err(), "{bad}");
        }
        assert_eq!(Speed::Factor(2.5).to_string(), "2.5×");
    }
}
