//! The board's wiring: which ATmega328P pin goes to which part, and the chip's clock. The firmware's
//! `firmware/src/pins.h` declares the same (a test holds the two together).
//!
//! | signal | pin | |
//! |---|---|---|
//! | UART0 RX/TX | PD0/PD1 | the serial line (USB adapter), bridged to the pseudo-terminal |
//! | TRIG | PB1 | SRF05 trigger, output |
//! | ECHO | PB0 | SRF05 echo, input; ICP1, so Timer1 captures its edges |
//! | MIN, MAX switches | PB2, PB3 | inputs with pull-ups, closed = low |
//! | LED | PB5 | output (Arduino D13) |
//! | servo signal | PB2 | the servo head's PWM (OC1B), output; no switches on that head |
//! | IN1..IN4 | PD4..PD7 | ULN2003 inputs (unipolar stepper, half-stepped) |
//! | STEP, DIR, EN | PD4, PD5, PD6 | A4988/DRV8825 inputs (bipolar stepper); EN low = enabled |

/// The ATmega328P's crystal: 16 MHz.
pub const CLOCK_HZ: u32 = 16_000_000;
/// Clock cycles per microsecond.
pub const CYCLES_PER_US: u64 = CLOCK_HZ as u64 / 1_000_000;

/// An I/O port of the ATmega328P (it has B, C and D).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Port {
    B,
    C,
    D,
}

impl Port {
    /// The port's letter, as simavr names it.
    pub fn letter(self) -> char {
        match self {
            Port::B => 'B',
            Port::C => 'C',
            Port::D => 'D',
        }
    }

    /// The port with this letter.
    pub fn from_letter(letter: char) -> Option<Self> {
        match letter {
            'B' => Some(Port::B),
            'C' => Some(Port::C),
            'D' => Some(Port::D),
            _ => None,
        }
    }
}

/// One pin: port and bit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Pin {
    pub port: Port,
    pub bit: u8,
}

impl Pin {
    pub const fn new(port: Port, bit: u8) -> Self {
        Self { port, bit }
    }

    /// The pin's level in a port's 8 levels.
    pub fn level_in(self, levels: u8) -> bool {
        levels >> self.bit & 1 == 1
    }
}

impl std::fmt::Display for Pin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "P{}{}", self.port.letter(), self.bit)
    }
}

/// SRF05 trigger (output).
pub const TRIG: Pin = Pin::new(Port::B, 1);
/// SRF05 echo (input, ICP1).
pub const ECHO: Pin = Pin::new(Port::B, 0);
/// Limit switch at the clockwise end, −150° (input, active low).
pub const SWITCH_MIN: Pin = Pin::new(Port::B, 2);
/// Limit switch at the counter-clockwise end, +150° (input, active low).
pub const SWITCH_MAX: Pin = Pin::new(Port::B, 3);
/// The servo head's signal line (OC1B, Timer1's fast PWM, output): a pulse every 20 ms, its width
/// the angle.
pub const SERVO: Pin = Pin::new(Port::B, 2);
/// The board's LED (output).
pub const LED: Pin = Pin::new(Port::B, 5);
/// ULN2003 inputs IN1..IN4.
pub const COIL: [Pin; 4] = [
    Pin::new(Port::D, 4),
    Pin::new(Port::D, 5),
    Pin::new(Port::D, 6),
    Pin::new(Port::D, 7),
];
/// Stepper driver STEP: one microstep per rising edge.
pub const STEP: Pin = Pin::new(Port::D, 4);
/// Stepper driver DIR: high = counter-clockwise (angle increasing).
pub const DIR: Pin = Pin::new(Port::D, 5);
/// Stepper driver EN: low = enabled.
pub const ENABLE: Pin = Pin::new(Port::D, 6);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pins_read_their_bit_and_print_as_avr_names() {
        assert!(TRIG.level_in(0b10));
        assert!(!TRIG.level_in(0b01));
        assert!(COIL[3].level_in(0x80));
        assert_eq!(SWITCH_MAX.to_string(), "PB3");
        assert_eq!(Port::from_letter('D'), Some(Port::D));
        assert_eq!(Port::from_letter('A'), None);
        assert_eq!(CYCLES_PER_US, 16);
    }

    /// `#define NAME VALUE` lines of a C header, comments removed.
    fn defines(header: &str) -> std::collections::HashMap<String, String> {
        let mut text = String::new();
        let mut rest = header;
        while let Some(start) = rest.find("/*") {
            text.push_str(&rest[..start]);
            rest = rest[start..]
                .find("*/")
                .map_or("", |end| &rest[start + end + 2..]);
        }
        text.push_str(rest);
        text.lines()
            .filter_map(|l| l.trim().strip_prefix("#define"))
            .filter_map(|l| {
                let mut words = l.split_whitespace();
                Some((
                    words.next()?.to_owned(),
                    words.collect::<Vec<_>>().join(" "),
                ))
            })
            .collect()
    }

    /// The pin that `PORTx` (or `DDRx`) macro `port` and `Pxn` macro `bit` name in the header.
    fn header_pin(defs: &std::collections::HashMap<String, String>, port: &str, bit: &str) -> Pin {
        let port_reg = &defs[port];
        let letter = port_reg
            .strip_prefix("PORT")
            .or_else(|| port_reg.strip_prefix("DDR"))
            .and_then(|l| l.chars().next())
            .unwrap_or_else(|| panic!("{port} = {port_reg} is no PORTx"));
        let bit_name = &defs[bit];
        let (bit_letter, n) = bit_name
            .strip_prefix('P')
            .and_then(|b| Some((b.chars().next()?, b.get(1..)?.parse::<u8>().ok()?)))
            .unwrap_or_else(|| panic!("{bit} = {bit_name} is no Pxn"));
        assert_eq!(
            bit_letter, letter,
            "{bit} = {bit_name} is not on {port} = {port_reg}"
        );
        Pin::new(Port::from_letter(letter).unwrap(), n)
    }

    /// The firmware's `pins.h` is the contract this board plays to: every pin must agree. Passes
    /// without a firmware directory (a checkout of this crate alone); fails if the firmware is there
    /// and its header is not.
    #[test]
    fn the_firmware_pins_header_agrees() {
        let firmware = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware");
        if !firmware.is_dir() {
            eprintln!("no {}: nothing to compare", firmware.display());
            return;
        }
        let header = firmware.join("src/pins.h");
        let text = std::fs::read_to_string(&header)
            .unwrap_or_else(|e| panic!("{}: {e}", header.display()));
        let defs = defines(&text);
        assert_eq!(header_pin(&defs, "SONAR_TRIG_PORT", "SONAR_TRIG_BIT"), TRIG);
        assert_eq!(header_pin(&defs, "SONAR_ECHO_PORT", "SONAR_ECHO_BIT"), ECHO);
        assert_eq!(
            header_pin(&defs, "SWITCH_PORT", "SWITCH_MIN_BIT"),
            SWITCH_MIN
        );
        assert_eq!(
            header_pin(&defs, "SWITCH_PORT", "SWITCH_MAX_BIT"),
            SWITCH_MAX
        );
        assert_eq!(header_pin(&defs, "LED_PORT", "LED_BIT"), LED);
        assert_eq!(header_pin(&defs, "SERVO_DDR", "SERVO_BIT"), SERVO);
        assert_eq!(header_pin(&defs, "STEPPER_PORT", "STEPDIR_STEP_BIT"), STEP);
        assert_eq!(header_pin(&defs, "STEPPER_PORT", "STEPDIR_DIR_BIT"), DIR);
        assert_eq!(header_pin(&defs, "STEPPER_PORT", "STEPDIR_EN_BIT"), ENABLE);
        // ULN2003 IN1..IN4: the four bits of STEPPER_MASK from STEPPER_SHIFT up, on STEPPER_PORT.
        let shift: u8 = defs["STEPPER_SHIFT"].parse().unwrap();
        let mask = u8::from_str_radix(
            defs["STEPPER_MASK"]
                .trim_end_matches(['u', 'U'])
                .trim_start_matches("0x"),
            16,
        )
        .unwrap();
        assert_eq!(mask, 0x0F << shift, "STEPPER_MASK");
        let stepper_port = header_pin(&defs, "STEPPER_PORT", "STEPDIR_STEP_BIT").port;
        let coils: Vec<Pin> = (0..4).map(|i| Pin::new(stepper_port, shift + i)).collect();
        assert_eq!(coils, COIL);
    }
}
