//! The model test: random command sequences against the laser-safety
//! invariants.

use super::*;

/// A dark camera that records when it exposed, for how long and with which
/// lasers lit (fast: the model test polls thousands of frames).
struct Strobes {
    now_us: Rc<Cell<u64>>,
    lasers: Lasers,
    exposures: Rc<RefCell<Vec<(u64, u32, u8)>>>,
}
impl Camera for Strobes {
    type Error = ();
    fn width(&self) -> u16 {
        752
    }
    fn height(&self) -> u16 {
        8
    }
    fn bits(&self) -> u8 {
        12
    }
    fn expose(&mut self, exposure_us: u32, _laser_mask: u8) -> Result<i64, ()> {
        self.exposures.borrow_mut().push((self.now_us.get(), exposure_us, self.lasers.now()));
        Ok(0)
    }
    fn read_row(&mut self, out: &mut [u16]) -> Result<(), ()> {
        out.fill(100);
        Ok(())
    }
}

/// What the host may do next in the model test.
#[derive(Clone, Debug)]
enum Step {
    Poll,
    Heartbeat,
    Start { mask: u8, sequential: bool, rate_hz: u16 },
    Stop,
    SetExposure(u32),
    GetInfo,
    Capture(u8),
}

fn step() -> impl Strategy<Value = Step> {
    prop_oneof![
        6 => Just(Step::Poll),
        3 => Just(Step::Heartbeat),
        2 => (0u8..8, any::<bool>(), 0u16..1200)
            .prop_map(|(mask, sequential, rate_hz)| Step::Start { mask, sequential, rate_hz }),
        1 => Just(Step::Stop),
        1 => (0u32..2_000_000).prop_map(Step::SetExposure),
        1 => Just(Step::GetInfo),
        1 => (0u8..8).prop_map(Step::Capture),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]
    /// `Head::handle` and `Head::poll` over arbitrary sequences of commands
    /// and times, against the laser rules as a model states them:
    /// * after every call the lasers are off (they are lit only around an
    ///   exposure, inside the call);
    /// * an exposure with lasers lit happens only while streaming — after a
    ///   `Start` the head acknowledged and before any `Stop` or error since —
    ///   or for a capture the head took, with that capture's lasers, and
    ///   never more than 1 s (the heartbeat timeout) after the last command
    ///   the head heard;
    /// * lit exposures add up to at most duty · T + burst over every interval.
    #[test]
    fn the_laser_rules_hold_whatever_the_host_does(
        steps in proptest::collection::vec((0u64..400_000, step()), 1..120),
    ) {
        let (mut h, l) = head();
        let now = Rc::new(Cell::new(0u64));
        let exposures = Rc::new(RefCell::new(Vec::new()));
        let mut cam = Strobes { now_us: now.clone(), lasers: l.clone(), exposures: exposures.clone() };
        let mut t = 0u64;
        let mut seq = 0u16;
        let mut last_heard = 0u64;
        // Streaming as the model sees it: since when, if at all.
        let mut streaming_since: Option<u64> = None;
        // The lasers of the last capture the head took (it lights them for
        // that capture's exposures only, streaming or not).
        let mut capture_mask = 0u8;
        for (gap, s) in steps {
            t += gap;
            now.set(t);
            let before = exposures.borrow().len();
            let mut out = Vec::new();
            let msg = match s {
                Step::Poll => None,
                Step::Heartbeat => Some(HostMsg::Heartbeat),
                Step::Start { mask, sequential, rate_hz } => Some(HostMsg::Start(Start {
                    rate_hz,
                    laser_mask: mask,
                    pattern: if sequential { LaserPattern::Sequential } else { LaserPattern::Simultaneous },
                })),
                Step::Stop => Some(HostMsg::Stop),
                Step::SetExposure(us) => Some(HostMsg::SetExposure { exposure_us: us }),
                Step::GetInfo => Some(HostMsg::GetInfo),
                Step::Capture(mask) => Some(HostMsg::CaptureImage(mask)),
            };
            match msg {
                Some(m) => {
                    seq = seq.wrapping_add(1).max(1);
                    let is_start = matches!(m, HostMsg::Start(_));
                    let is_stop = matches!(m, HostMsg::Stop);
                    let capture = if let HostMsg::CaptureImage(mask) = m { Some(mask) } else { None };
                    h.handle(cmd(seq, m), t, &cam, &mut |r| out.push(r.clone()));
                    last_heard = t;
                    if is_stop {
                        streaming_since = None;
                    }
                    if is_start && out.contains(&DeviceMsg::Ack(seq)) {
                        streaming_since = Some(t);
                    }
                    if let Some(mask) = capture
                        && !out.iter().any(|r| matches!(r, DeviceMsg::Error { seq: Some(q), .. } if *q == seq))
                    {
                        capture_mask = mask;
                    }
                }
                None => h.poll(t, &mut cam, &mut || 0, &mut |r| out.push(r.clone())),
            }
            if out.iter().any(|r| matches!(r, DeviceMsg::Error { .. })) {
                // Any error while streaming stops it (a refused command
                // while idle changes nothing either way).
                if h.state() != HeadState::Streaming {
                    streaming_since = None;
                }
            }
            prop_assert_eq!(l.now(), 0, "lasers left on after {:?} at {} us", out, t);
            for &(at, _, mask) in &exposures.borrow()[before..] {
                if mask != 0 {
                    prop_assert!(
                        streaming_since.is_some() || mask & !capture_mask == 0,
                        "lit exposure ({:#05b}) at {} us while neither streaming nor capturing", mask, at
                    );
                    prop_assert!(
                        at - last_heard <= HEARTBEAT_TIMEOUT_US,
                        "lit exposure at {} us, {} us after the last command", at, at - last_heard
                    );
                }
            }
        }
        let lit: Vec<(u64, u64)> =
            exposures.borrow().iter().filter(|e| e.2 != 0).map(|&(at, us, _)| (at, us as u64)).collect();
        for i in 0..lit.len() {
            let mut on = 0;
            for j in i..lit.len() {
                on += lit[j].1;
                let span = (lit[j].0 + lit[j].1).saturating_sub(lit[i].0);
                prop_assert!(
                    on * 1000 <= span * MAX_DUTY_PERMILLE as u64 + DUTY_BURST_US as u64 * 1000,
                    "{} us lit in {} us", on, span
                );
            }
        }
    }
}
