//! Selection (step 5 of the detector): minimum separation, then the
//! configured rule, output in ascending position.

use super::{Config, MAX_CANDIDATES, Select, Stripe, Stripes};
use heapless::Vec;

/// Minimum separation, then the selection rule; output sorted by position.
pub(super) fn select<const N: usize>(found: &mut Vec<Stripe, MAX_CANDIDATES>, cfg: &Config, out: &mut Stripes<N>) {
    let limit = match cfg.select {
        Select::All => N,
        _ => (cfg.max_stripes as usize).min(N),
    };
    // The usual row: as many stripes as may be kept or fewer, found in
    // ascending position (candidates come in row order) and each at least
    // the separation from the next. Then no rule drops one (the separation
    // holds between every pair, the limit is not reached) and the output
    // is `found` as it is: the general path below gives the same.
    if found.len() <= limit
        && found
            .windows(2)
            .all(|p| p[1].position.0 > p[0].position.0 && p[0].position.abs_diff(p[1].position) >= cfg.min_separation)
    {
        for s in found.iter() {
            let _ = out.push(*s);
        }
        return;
    }
    found.sort_unstable_by(|a, b| b.strength.cmp(&a.strength).then(a.position.cmp(&b.position)));
    // In place: the first `k` are the ones kept so far (no second buffer to
    // fill and copy out).
    let mut k = 0;
    for i in 0..found.len() {
        let s = found[i];
        if found[..k].iter().all(|kept| kept.position.abs_diff(s.position) >= cfg.min_separation) {
            // (Kept in place when nothing was dropped before it: the
            // assignment is a `memmove` call on the M4.)
            if k != i {
                found[k] = s;
            }
            k += 1;
        }
    }
    found.truncate(k);
    let kept = found;
    match cfg.select {
        Select::Strongest | Select::All => kept.truncate(limit),
        Select::First => {
            kept.sort_unstable_by_key(|s| s.position);
            kept.truncate(limit);
        }
        Select::Last => {
            kept.sort_unstable_by_key(|s| core::cmp::Reverse(s.position));
            kept.truncate(limit);
        }
    }
    kept.sort_unstable_by_key(|s| s.position);
    for s in kept.iter() {
        let _ = out.push(*s);
    }
}
