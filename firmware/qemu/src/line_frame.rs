//! The line pass's benchmark frame (`cms-qemu-line`, `cms-qemu-bench`,
//! `cms-qemu-profile`): one frame of the reference head, three lasers × 480
//! rows, each laser's line slanted and bent, a detector's scatter of
//! ±0.6 px, one outlier in 40 rows, and second candidates in `n_seconds`
//! rows of laser 1 (a ghost 12 px beside it). Deterministic. [`calibrate`]
//! gives its points metric points (the link's encoder's frame:
//! `cms-qemu-bench`, `cms-qemu-profile`).

use cms_core::fixed::Px;
use cms_core::peak::Flags;
use cms_core::pipeline::line::Seconds;
use cms_core::protocol::{LASERS, LaserPoints, MAX_ROWS_PER_PROFILE, Metric, Point};
use heapless::Vec;

/// A frame's lasers' points.
pub type Lasers = Vec<LaserPoints, LASERS>;

/// A uniform scatter in ±`amp_q16` (Q16.16 px), deterministic.
fn scatter(state: &mut u32, amp_q16: i32) -> i32 {
    *state ^= *state << 13;
    *state ^= *state >> 17;
    *state ^= *state << 5;
    ((i64::from(*state) * 2 * i64::from(amp_q16)) >> 32) as i32 - amp_q16
}

fn point(row: u16, position: Px) -> Point {
    Point { row, position, strength: 1000, width: Px::from_int(2), flags: Flags::NONE, metric: None }
}

/// The frame and `n_seconds` second candidates of laser 1.
pub fn build(frame: &mut Lasers, seconds: &mut Seconds, n_seconds: usize) {
    let mut s = 0x9e37_79b9u32;
    frame.clear();
    seconds.clear();
    for k in 0..LASERS as u8 {
        let mut points = Vec::new();
        for r in 0..MAX_ROWS_PER_PROFILE as u16 {
            let rr = i32::from(r);
            // 200 + 180 k px, 0.05 px a row, a crown of 5 px.
            let mut x =
                ((200 + 180 * i32::from(k)) << 16) + rr * 3277 - ((rr - 240) * (rr - 240) * 5) / 58 * 65536 / 1000;
            x += scatter(&mut s, 39_322);
            if r % 40 == 17 {
                x += 6 << 16;
            }
            let _ = points.push(point(r, Px(x)));
        }
        let _ = frame.push(LaserPoints { laser: k, points });
    }
    for i in 0..n_seconds {
        let r = (i * MAX_ROWS_PER_PROFILE / n_seconds.max(1)) as u16;
        let p = frame[1].points[usize::from(r)];
        let _ = seconds.push((1, point(r, p.position + Px::from_int(12))));
    }
}

/// A metric point in every point, as the reference head's calibration
/// makes them: 143 µm a row along, 190 µm of height a pixel sideways.
pub fn calibrate(frame: &mut Lasers) {
    for lp in frame.iter_mut() {
        let x0 = lp.points.first().map_or(0, |q| q.position.0);
        for q in lp.points.iter_mut() {
            let dx = i64::from(q.position.0 - x0);
            q.metric = Some(Metric {
                along_um: -34_000 + 143 * i32::from(q.row),
                height_nm: -140_000 - ((dx * 190_000) >> 16) as i32,
            });
        }
    }
}
