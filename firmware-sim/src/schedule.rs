//! Pin levels the hardware will drive at given cycles: the ECHO pulse after a trigger, a bouncing
//! switch. The run loop runs the chip exactly to the next one and applies it.

use crate::pins::Pin;

/// A level to drive on an input pin at a cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Edge {
    pub at: u64,
    pub pin: Pin,
    pub high: bool,
}

/// Future edges in order of time; edges at the same cycle keep the order they were added in.
#[derive(Debug, Clone, Default)]
pub struct Schedule {
    edges: Vec<Edge>,
}

impl Schedule {
    pub fn push(&mut self, at: u64, pin: Pin, high: bool) {
        let i = self.edges.partition_point(|e| e.at <= at);
        self.edges.insert(i, Edge { at, pin, high });
    }

    /// Drops every future edge of `pin`.
    pub fn cancel(&mut self, pin: Pin) {
        self.edges.retain(|e| e.pin != pin);
    }

    /// The cycle of the next edge.
    pub fn next_at(&self) -> Option<u64> {
        self.edges.first().map(|e| e.at)
    }

    /// Removes the edges due at `now` (or before) and appends them to `out`, in order.
    pub fn take_due(&mut self, now: u64, out: &mut Vec<Edge>) {
        let n = self.edges.partition_point(|e| e.at <= now);
        out.extend(self.edges.drain(..n));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pins::{ECHO, SWITCH_MIN};

    #[test]
    fn edges_come_out_in_time_order_and_can_be_cancelled_per_pin() {
        let mut s = Schedule::default();
        s.push(30, ECHO, false);
        s.push(10, ECHO, true);
        s.push(20, SWITCH_MIN, false);
        s.push(20, SWITCH_MIN, true);
        assert_eq!(s.next_at(), Some(10));
        let mut out = Vec::new();
        s.take_due(20, &mut out);
        assert_eq!(
            out.iter().map(|e| (e.at, e.high)).collect::<Vec<_>>(),
            [(10, true), (20, false), (20, true)]
        );
        s.cancel(ECHO);
        assert_eq!(s.next_at(), None);
    }
}
