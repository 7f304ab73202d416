//! Bus transports: how frames get between the runtime and the simulated axes.
//!
//! [`Transport`] is the one interface; [`InProcessBus`] (the default, deterministic, works
//! everywhere) and, on Linux with the `socketcan` feature, [`crate::socketcan::SocketCan`]
//! implement it. The in-process bus runs on *simulated* time: every call carries `now_us`, so a
//! test runs as fast as the CPU allows and gives the same result every time.
//!
//! Fault injection lives on the in-process bus ([`Faults`]): each frame a port sends may be
//! dropped, delayed or duplicated, decided by a seeded generator so a failing run can be
//! replayed exactly. (A node that goes silent is a property of the axis:
//! [`crate::axis::SimAxis::set_silent`].)

use std::collections::VecDeque;
use std::fmt;
use std::sync::{Arc, Mutex, MutexGuard};
use wheelleg_runtime::can::CanFrame;

/// Why a transport failed.
#[derive(Debug)]
pub enum BusError {
    /// The operating system refused (SocketCAN).
    Io(std::io::Error),
    /// The in-process bus has no port with this index.
    NoSuchPort(usize),
}

impl fmt::Display for BusError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BusError::Io(e) => write!(f, "CAN I/O error: {e}"),
            BusError::NoSuchPort(p) => write!(f, "no bus port {p}"),
        }
    }
}

impl std::error::Error for BusError {}

impl From<std::io::Error> for BusError {
    fn from(e: std::io::Error) -> Self {
        BusError::Io(e)
    }
}

/// A CAN interface as one participant sees it.
pub trait Transport {
    /// Puts a frame on the bus at `now_us`.
    fn send(&mut self, frame: &CanFrame, now_us: u64) -> Result<(), BusError>;
    /// The next frame from the other participants that has arrived by `now_us`, if any.
    fn recv(&mut self, now_us: u64) -> Result<Option<CanFrame>, BusError>;
}

/// Probabilities of faults applied to every frame sent on an [`InProcessBus`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Faults {
    /// Probability a frame is lost.
    pub drop_probability: f64,
    /// Probability a frame arrives late.
    pub delay_probability: f64,
    /// How late a delayed frame arrives.
    pub delay_us: u64,
    /// Probability a frame arrives twice.
    pub duplicate_probability: f64,
    /// Seed of the fault generator.
    pub seed: u64,
}

impl Faults {
    /// A perfect bus.
    pub const NONE: Faults = Faults {
        drop_probability: 0.0,
        delay_probability: 0.0,
        delay_us: 0,
        duplicate_probability: 0.0,
        seed: 0,
    };
}

impl Default for Faults {
    fn default() -> Self {
        Faults::NONE
    }
}

/// Counters of what the in-process bus did to the traffic.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct BusCounters {
    /// Frames offered by senders.
    pub sent: u64,
    /// Frames lost by fault injection.
    pub dropped: u64,
    /// Frames delayed by fault injection.
    pub delayed: u64,
    /// Extra copies created by fault injection.
    pub duplicated: u64,
}

/// SplitMix64: tiny, seedable, good enough to decide faults.
#[derive(Clone, Debug)]
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[derive(Debug)]
struct Medium {
    /// Per port: frames in flight to it, (arrival time, frame), in send order.
    inboxes: Vec<VecDeque<(u64, CanFrame)>>,
    faults: Faults,
    rng: SplitMix64,
    counters: BusCounters,
}

/// A CAN bus inside one process: every frame a port sends reaches every other port.
#[derive(Clone, Debug)]
pub struct InProcessBus {
    medium: Arc<Mutex<Medium>>,
}

impl Default for InProcessBus {
    fn default() -> Self {
        InProcessBus::new(Faults::NONE)
    }
}

impl InProcessBus {
    /// A bus with fault injection `faults` (use [`Faults::NONE`] for a perfect bus).
    pub fn new(faults: Faults) -> InProcessBus {
        InProcessBus {
            medium: Arc::new(Mutex::new(Medium {
                inboxes: Vec::new(),
                faults,
                rng: SplitMix64(faults.seed),
                counters: BusCounters::default(),
            })),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Medium> {
        // A panic elsewhere while holding the lock leaves plain data behind; keep using it.
        self.medium.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Connects a new participant.
    pub fn port(&self) -> Port {
        let mut m = self.lock();
        m.inboxes.push(VecDeque::new());
        Port {
            bus: self.clone(),
            index: m.inboxes.len() - 1,
        }
    }

    /// Changes the fault injection from now on.
    pub fn set_faults(&self, faults: Faults) {
        let mut m = self.lock();
        m.faults = faults;
        m.rng = SplitMix64(faults.seed);
    }

    /// What fault injection has done so far.
    pub fn counters(&self) -> BusCounters {
        self.lock().counters
    }
}

/// One participant's connection to an [`InProcessBus`].
#[derive(Clone, Debug)]
pub struct Port {
    bus: InProcessBus,
    index: usize,
}

impl Transport for Port {
    fn send(&mut self, frame: &CanFrame, now_us: u64) -> Result<(), BusError> {
        let mut m = self.bus.lock();
        let m = &mut *m;
        if self.index >= m.inboxes.len() {
            return Err(BusError::NoSuchPort(self.index));
        }
        m.counters.sent += 1;
        let f = m.faults;
        if m.rng.next_f64() < f.drop_probability {
            m.counters.dropped += 1;
            return Ok(());
        }
        let mut arrival_us = now_us;
        if m.rng.next_f64() < f.delay_probability {
            m.counters.delayed += 1;
            arrival_us += f.delay_us;
        }
        let copies = if m.rng.next_f64() < f.duplicate_probability {
            m.counters.duplicated += 1;
            2
        } else {
            1
        };
        for (i, inbox) in m.inboxes.iter_mut().enumerate() {
            if i == self.index {
                continue;
            }
            for _ in 0..copies {
                // Keep each inbox sorted by arrival: a delayed frame is overtaken by later ones,
                // as it would be by a retransmission on a real bus.
                let at = inbox.partition_point(|(t, _)| *t <= arrival_us);
                inbox.insert(at, (arrival_us, *frame));
            }
        }
        Ok(())
    }

    fn recv(&mut self, now_us: u64) -> Result<Option<CanFrame>, BusError> {
        let mut m = self.bus.lock();
        let inbox = m
            .inboxes
            .get_mut(self.index)
            .ok_or(BusError::NoSuchPort(self.index))?;
        match inbox.front() {
            Some((at, _)) if *at <= now_us => Ok(inbox.pop_front().map(|(_, f)| f)),
            _ => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(id: u16) -> CanFrame {
        CanFrame::standard(id, &[1, 2, 3]).unwrap()
    }

    #[test]
    fn frames_reach_every_other_port_but_not_the_sender() {
        let bus = InProcessBus::default();
        let (mut a, mut b, mut c) = (bus.port(), bus.port(), bus.port());
        a.send(&frame(0x21), 0).unwrap();
        assert_eq!(a.recv(0).unwrap(), None);
        assert_eq!(b.recv(0).unwrap(), Some(frame(0x21)));
        assert_eq!(c.recv(0).unwrap(), Some(frame(0x21)));
        assert_eq!(b.recv(0).unwrap(), None);
    }

    #[test]
    fn faults_drop_delay_and_duplicate_reproducibly() {
        let faults = Faults {
            drop_probability: 0.2,
            delay_probability: 0.2,
            delay_us: 5_000,
            duplicate_probability: 0.2,
            seed: 7,
        };
        let run = || {
            let bus = InProcessBus::new(faults);
            let (mut tx, mut rx) = (bus.port(), bus.port());
            let mut got = Vec::new();
            for i in 0..1000u16 {
                tx.send(&frame(i % 0x7FF), u64::from(i) * 100).unwrap();
            }
            // Nothing delayed has arrived before its time.
            while let Some(f) = rx.recv(99_900).unwrap() {
                got.push(f.raw_id());
            }
            let early = got.len();
            while let Some(f) = rx.recv(200_000).unwrap() {
                got.push(f.raw_id());
            }
            (bus.counters(), early, got)
        };
        let (counters, early, got) = run();
        assert_eq!(run().2, got, "same seed, same faults");
        assert!((150..250).contains(&counters.dropped), "{counters:?}");
        assert!(counters.delayed > 100 && counters.duplicated > 100);
        assert_eq!(
            got.len() as u64,
            counters.sent - counters.dropped + counters.duplicated
        );
        assert!(early < got.len());
    }
}
