//! The hobby "Arduino radar" sketch (HowToMechatronics), which many people already run: a servo
//! sweeps 15° → 165° → 15° in 1° steps, waits 30 ms at each degree, pings once and prints
//! `angle,distance_cm.` with no newline. It takes no commands and starts at power-on.

use crate::firmware::Transducer;

const SERVO_MIN: u32 = 15;
const SERVO_MAX: u32 = 165;
/// Servo angle of the sensor's forward axis.
const SERVO_FORWARD: f64 = 90.0;
/// The sketch's `delay(30)` for the servo to settle.
const SETTLE_US: u64 = 30_000;

/// The sketch's main loop, one ping per [`HobbySketch::step`].
#[derive(Debug)]
pub struct HobbySketch<T> {
    transducer: T,
    step: u32,
    /// The step at the latest (re)boot: the sweep starts over there.
    boot_step: u32,
    now_us: u64,
    /// How long the echo line stays high when nothing returns (SRF05: 30 ms).
    echo_timeout_us: u32,
    /// Passes (15° → 165° or back) completed.
    passes: u64,
}

impl<T: Transducer> HobbySketch<T> {
    pub fn new(transducer: T, echo_timeout_us: u32) -> Self {
        Self {
            transducer,
            step: 0,
            boot_step: 0,
            now_us: 0,
            echo_timeout_us,
            passes: 0,
        }
    }

    /// Passes of the servo completed (each way counts): the sketch's sweeps.
    pub fn passes(&self) -> u64 {
        self.passes
    }

    pub fn transducer_mut(&mut self) -> &mut T {
        &mut self.transducer
    }

    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// Reboots the Arduino: `setup()` runs again (it prints nothing) and the sweep starts over at
    /// 15°. The clock and the count of records run on.
    pub fn reset(&mut self) {
        self.boot_step = self.step;
    }

    /// Records printed so far.
    pub fn records(&self) -> u32 {
        self.step
    }

    /// One turn of the loop: move, settle, ping, print. Returns the record, e.g. `90,118.`.
    pub fn step(&mut self) -> String {
        // `for (i = 15; i <= 165; i++)` then `for (i = 165; i > 15; i--)`: 165 is printed twice,
        // 15 once per cycle.
        let up = SERVO_MAX - SERVO_MIN + 1;
        let k = (self.step - self.boot_step) % (2 * up - 1);
        let servo = if k < up {
            SERVO_MIN + k
        } else {
            SERVO_MAX - (k - up)
        };
        // The last record of each `for` loop: 165 going up, 16 coming down.
        if k == up - 1 || k == 2 * up - 2 {
            self.passes += 1;
        }
        self.step += 1;
        self.now_us += SETTLE_US;
        let echo_us = self.transducer.ping(f64::from(servo) - SERVO_FORWARD);
        // `pulseIn` times the echo line, which stays high until the echo or the sensor's timeout:
        // with no echo the sketch prints the timeout's "distance" (510 cm), as on the bench.
        let pulse_us = if echo_us == 0 {
            self.echo_timeout_us
        } else {
            echo_us
        };
        self.now_us += u64::from(pulse_us);
        // `distance = duration * 0.034 / 2;` into an int: 340 m/s whatever the air, truncated.
        let distance_cm = (f64::from(pulse_us) * 0.034 / 2.0) as u32;
        format!("{servo},{distance_cm}.")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Fixed(Vec<f64>, u32);

    impl Transducer for Fixed {
        fn ping(&mut self, aim_deg: f64) -> u32 {
            self.0.push(aim_deg);
            self.1
        }
    }

    #[test]
    fn sweeps_like_the_sketch_and_prints_integer_centimetres() {
        // 6989 µs is 1.20 m at 20 °C; the sketch's 340 m/s and truncation make it 118 cm.
        let mut sketch = HobbySketch::new(Fixed(Vec::new(), 6989), 30_000);
        let records: Vec<String> = (0..302).map(|_| sketch.step()).collect();
        assert_eq!(records[0], "15,118.");
        assert_eq!(records[75], "90,118.");
        assert_eq!(records[150], "165,118.");
        assert_eq!(records[151], "165,118.");
        assert_eq!(records[300], "16,118.");
        assert_eq!(records[301], "15,118.");
        assert_eq!(sketch.passes(), 2);
        assert_eq!(sketch.transducer.0[75], 0.0);
        assert_eq!(sketch.transducer.0[0], -75.0);
        assert_eq!(sketch.now_us(), 302 * (30_000 + 6989));

        let mut silent = HobbySketch::new(Fixed(Vec::new(), 0), 30_000);
        assert_eq!(silent.step(), "15,510.");

        sketch.step();
        sketch.reset();
        assert_eq!(sketch.step(), "15,118.", "a reset starts the sweep over");
        assert_eq!(sketch.step(), "16,118.");
        assert_eq!(sketch.records(), 305);
    }
}
