//! Generates the detector's constant tables in f64 and rounds them once.
//!
//! Everything the hot path multiplies by is produced here, so the firmware
//! and the host run on the same integers and no float touches a pixel.
//!
//! * The scale ladder: `s_k = 2^(k/4)` px for `k = 0..LADDER_LEN` (1 … 45 px).
//!   A quarter octave between rungs keeps the worst mismatch between a
//!   stripe's width and the nearest rung at ±9 %, which costs < 1.3 % of
//!   Cramér–Rao efficiency in the sub-pixel stage (see `peak/cwt.rs`).
//! * `RICKER`: the Ricker wavelet `ψ(u) = (1 − u²)·e^(−u²/2)` at integer
//!   offsets `m = 0..=ceil(4 s)` (one half; the kernel is even), peak scaled to
//!   `RICKER_ONE`. Cut at 4 s, where |ψ| is 5·10⁻³ of its peak (the tail
//!   past it changes a Gaussian stripe's response by < 10⁻⁴; 5 s cost a
//!   fifth more taps for nothing the climb in scale can see). Rounding is
//!   to nearest; the centre tap then absorbs the residue so that the full
//!   kernel sums to exactly zero, which makes the response to any constant
//!   background exactly zero. `RICKER_PAIRS_OF`: the same integers two per
//!   u32 word, one array per rung.
//! * `DERIV`: the sub-pixel kernel `D(u) = w(u)·(−ψ′(u) − λ·u·e^(−u²/2))`,
//!   `−ψ′(u) = (3u − u³)·e^(−u²/2)`, at sub-pixel offsets `t = j/PHASES`,
//!   `j = 0..=ceil(4 s)·PHASES` (one half; the kernel is odd, so
//!   antisymmetry is exact by construction), peak scaled to `DERIV_ONE`.
//!   `w` is 1 to 3.25 s and a raised cosine to 0 at 4 s: a hard cut there
//!   (where `−ψ′` is still 1.3 % of its peak) makes the slope jump as a tap
//!   enters at each whole pixel, the taper makes it smooth. The taper alone
//!   would make the kernel see a linear background (`∫ u·D ≠ 0`); the odd
//!   Gaussian term with `λ` (≈ 0.058, computed here by Simpson's rule) takes
//!   that out again. Against the untruncated `−ψ′` to 5 s the kernel has a
//!   fifth fewer taps and costs 0.5 % of the estimator's RMS at the
//!   Cramér–Rao bound (1.056 × the bound instead of 1.051; `cwt.rs`).
//!   Stored phase-major (all taps of phase 0, then of phase 1/PHASES, …) so
//!   that one evaluation at a phase reads two contiguous runs.
//!   `DERIV_PAIRS_OF` holds the same integers of phases 1.. of the rungs up
//!   to `PAIR_RUNGS`, two neighbouring taps per u32 word (no second
//!   rounding), one array per rung.
//! * `PAPER`: Eq. (2)+(4) of the paper for integer scales 1..=45 px:
//!   `s^(−1/2)·(1 − u²)·e^(−u²/2)`, `u = m/s`, the same constant for all scales
//!   (so responses compare across scales exactly as in Eq. 2), rounded to
//!   nearest, zero-sum corrected like `RICKER`.
//! * Per-rung scalars (`RUNGS`): the response normalisation `s^(−3/2)` (so the
//!   best-matching scale of a Gaussian stripe of width σ is s = σ), the gain
//!   (response to a unit-amplitude Gaussian of σ = s), the white-noise gain,
//!   and the box-cascade parameters of the coarse pass.
//! * `LOG2_Q16`: log2(1 + i/256), i = 0..=256, in Q16, for the Gaussian
//!   3-point baseline (linear interpolation error < 3·10⁻⁶).

use std::env;
use std::fmt::Write as _;
use std::fs;
use std::path::Path;

const LADDER_LEN: usize = 23;
const PHASES: usize = 16;
const RICKER_ONE: f64 = 30000.0;
const DERIV_ONE: f64 = 32000.0;
const PAPER_ONE: f64 = 30000.0;
const PAPER_MAX_SCALE: usize = 45;
/// Widest rung whose derivative taps are also stored in pairs (`DERIV_PAIRS_OF`).
const PAIR_RUNGS: usize = 15;
/// Fixed-point shift of the response normalisation (see `peak/kernels.rs`).
const NORM_SHIFT: u32 = 24;

fn ricker(u: f64) -> f64 {
    (1.0 - u * u) * (-u * u / 2.0).exp()
}

fn deriv(u: f64) -> f64 {
    (3.0 * u - u * u * u) * (-u * u / 2.0).exp()
}

fn scale(k: usize) -> f64 {
    2f64.powf(k as f64 / 4.0)
}

/// Where the kernels end, in units of the scale: the Ricker is cut there
/// (|ψ| = 5·10⁻³ of its peak), the derivative tapered to zero by then.
const CUT: f64 = 4.0;
/// Where the derivative's taper begins, in units of the scale.
const TAPER_FROM: f64 = 3.25;

/// Half length of a rung's kernels, px: offsets `0..=ceil(CUT · s)`.
fn half_len(s: f64) -> usize {
    (CUT * s).ceil() as usize
}

/// Half length of the paper's kernels (Eq. 2 taken to 5 s).
fn paper_half_len(s: f64) -> usize {
    (5.0 * s).ceil() as usize
}

/// The derivative kernel's taper: 1 up to `TAPER_FROM`, a raised cosine
/// down to 0 at `CUT` (value and slope continuous, so no tap jumps in or
/// out as the phase moves), 0 beyond.
fn taper(u: f64) -> f64 {
    let a = u.abs();
    if a <= TAPER_FROM {
        1.0
    } else if a >= CUT {
        0.0
    } else {
        (std::f64::consts::FRAC_PI_2 * (a - TAPER_FROM) / (CUT - TAPER_FROM)).cos().powi(2)
    }
}

/// `∫₀^CUT f(u) du` by Simpson's rule on 8 000 intervals (exact to ~10⁻¹⁴
/// for these smooth integrands).
fn integral(f: impl Fn(f64) -> f64) -> f64 {
    let n = 8000;
    let h = CUT / n as f64;
    let inner: f64 = (1..n).map(|i| f(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 }).sum();
    (f(0.0) + inner + f(CUT)) * h / 3.0
}

/// The weight of the odd Gaussian `u·e^(−u²/2)` taken off the tapered
/// `−ψ′` so that the kernel stays orthogonal to a linear background
/// (`∫ u·D(u) du = 0`, which the taper alone would break).
fn slope_fix() -> f64 {
    integral(|u| u * deriv(u) * taper(u)) / integral(|u| u * u * (-u * u / 2.0).exp() * taper(u))
}

/// The sub-pixel kernel `D(u) = taper(u)·(−ψ′(u) − λ·u·e^(−u²/2))`, `λ` =
/// [`slope_fix`].
fn deriv_kernel(u: f64, lambda: f64) -> f64 {
    taper(u) * (deriv(u) - lambda * u * (-u * u / 2.0).exp())
}

/// The largest value of [`deriv_kernel`] (its peak lies below u = 1): a
/// dense grid, then golden-section search around the best point.
fn deriv_kernel_max(lambda: f64) -> f64 {
    let f = |u: f64| deriv_kernel(u, lambda);
    let best = (0..=20_000).map(|i| i as f64 * 1e-4).fold(0.0, |b: f64, u| if f(u) > f(b) { u } else { b });
    let (mut a, mut b) = (best - 1e-4, best + 1e-4);
    let g = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..60 {
        let (c, d) = (b - g * (b - a), a + g * (b - a));
        if f(c) > f(d) {
            b = d;
        } else {
            a = c;
        }
    }
    f((a + b) / 2.0)
}

/// Rounds an even half-kernel and moves the residue into the centre tap.
fn zero_sum_even(vals: &[f64]) -> Vec<i64> {
    let mut q: Vec<i64> = vals.iter().map(|v| v.round() as i64).collect();
    let total: i64 = q[0] + 2 * q[1..].iter().sum::<i64>();
    q[0] -= total;
    q
}

fn full_even(half: &[i64]) -> Vec<(i64, i64)> {
    let l = half.len() as i64 - 1;
    (-l..=l).map(|m| (m, half[m.unsigned_abs() as usize])).collect()
}

fn main() {
    println!("cargo::rerun-if-changed=build.rs");
    let out = Path::new(&env::var("OUT_DIR").unwrap()).join("kernels.rs");
    let mut src = String::new();
    writeln!(src, "// @generated by core/build.rs — do not edit.").unwrap();
    writeln!(src, "pub const LADDER_LEN: usize = {LADDER_LEN};").unwrap();
    writeln!(src, "pub const PHASES: usize = {PHASES};").unwrap();
    writeln!(src, "pub const NORM_SHIFT: u32 = {NORM_SHIFT};").unwrap();
    writeln!(src, "pub const PAPER_MAX_SCALE: usize = {PAPER_MAX_SCALE};").unwrap();
    writeln!(src, "pub const PAIR_RUNGS: usize = {PAIR_RUNGS};").unwrap();

    let mut ricker_all: Vec<i64> = Vec::new();
    let mut deriv_all: Vec<i64> = Vec::new();
    let mut deriv_pairs: Vec<i64> = Vec::new();
    let mut ricker_pairs: Vec<i64> = Vec::new();
    let mut ricker_words: Vec<Vec<i64>> = Vec::new();
    let mut deriv_words: Vec<Vec<i64>> = Vec::new();
    let mut rungs = String::new();
    let lambda = slope_fix();
    for k in 0..LADDER_LEN {
        let s = scale(k);
        let l = half_len(s);
        // Ricker, integer offsets.
        let half: Vec<f64> = (0..=l).map(|m| RICKER_ONE * ricker(m as f64 / s)).collect();
        let rq = zero_sum_even(&half);
        let r_off = ricker_all.len();
        ricker_all.extend_from_slice(&rq);
        // The same half-kernel two taps a word (offsets 2i, 2i + 1 in word
        // i, as i16 halves; a last odd tap with a zero high half) for the
        // 32-bit responses (`cwt::Folded`).
        let rp_off = ricker_pairs.len();
        for two in rq.chunks(2) {
            let lo = two[0] as i16 as u16 as u32;
            let hi = two.get(1).map_or(0, |&t| t as i16 as u16 as u32);
            ricker_pairs.push((lo | hi << 16) as i64);
        }
        ricker_words.push(ricker_pairs[rp_off..].to_vec());
        // Normalised response R = acc · norm >> NORM_SHIFT, in counts·256 (Q8):
        // norm = 2^NORM_SHIFT · 256 · s^(−3/2) / RICKER_ONE.
        let norm_f = 2f64.powi(NORM_SHIFT as i32) * 256.0 * s.powf(-1.5) / RICKER_ONE;
        let norm = norm_f.round() as i64;
        let norm_used = norm as f64 / 2f64.powi(NORM_SHIFT as i32) / 256.0;
        // Gain: response (counts) to a unit Gaussian of σ = s centred on a pixel,
        // computed from the rounded taps actually used.
        let full = full_even(&rq);
        let gain: f64 =
            full.iter().map(|&(m, w)| w as f64 * (-(m as f64).powi(2) / (2.0 * s * s)).exp()).sum::<f64>() * norm_used;
        let noise: f64 = full.iter().map(|&(_, w)| (w as f64).powi(2)).sum::<f64>().sqrt() * norm_used;
        // Amplitude from response: A = R_q8 · amp_inv >> 24, amp_inv = 2^16 / gain.
        let amp_inv = (65536.0 / gain).round() as i64;
        // Noise gain in Q8: response std (counts) per unit pixel noise std.
        let noise_q8 = (noise * 256.0).round() as i64;
        // Derivative kernel at sub-pixel phases.
        let d_off = deriv_all.len();
        let dmax = deriv_kernel_max(lambda);
        // Stored phase by phase (residue r = j mod PHASES, then j / PHASES),
        // so that the taps one slope evaluation reads are contiguous: phase 0
        // holds l + 1 taps, phases 1.. hold l each.
        let tap = |j: usize| (DERIV_ONE * deriv_kernel(j as f64 / PHASES as f64 / s, lambda) / dmax).round() as i64;
        for r in 0..PHASES {
            let mut j = r;
            while j <= l * PHASES {
                deriv_all.push(tap(j));
                j += PHASES;
            }
        }
        // The same taps of phases 1.. (l each) in pairs, one u32 word per
        // two neighbouring taps (the first in the low half, as i16; an odd
        // run's last word has a zero high half), for the two-taps-a-word
        // multiply-accumulates of the 32-bit slope (`cwt::slope_pair32`).
        // Only the rungs up to PAIR_RUNGS (flash): wider rungs take the
        // 64-bit path anyway at any usual bit depth.
        if k <= PAIR_RUNGS {
            let off = deriv_pairs.len();
            for r in 1..PHASES {
                let taps: Vec<i64> = (0..l).map(|m| tap(r + m * PHASES)).collect();
                for two in taps.chunks(2) {
                    let lo = two[0] as i16 as u16 as u32;
                    let hi = two.get(1).map_or(0, |&t| t as i16 as u16 as u32);
                    deriv_pairs.push((lo | hi << 16) as i64);
                }
            }
            deriv_words.push(deriv_pairs[off..].to_vec());
        }
        // The largest Σ|D| one slope evaluation applies at a phase p in
        // 1..PHASES (right of k phase PHASES − p, at and left of k phase p):
        // a slope of pixels in 0..=sat is within ±sat × this, which decides
        // whether it fits 32 bits (`Plan`).
        let phase_abs = |r: usize| (0..l).map(|m| tap(r + m * PHASES).abs()).sum::<i64>();
        let deriv_abs = (1..PHASES).map(|p| phase_abs(PHASES - p) + phase_abs(p)).max().unwrap_or(0);
        // And Σ|ψ| over the whole Ricker kernel (both halves), for the same
        // question about a response.
        let ricker_abs = rq[0].abs() + 2 * rq[1..].iter().map(|v| v.abs()).sum::<i64>();
        // Coarse box cascade: three boxes of width w = 2h+1 have variance
        // 3(w²−1)/12; choose the odd w closest to that of a Gaussian of σ = s.
        let w = (4.0 * s * s + 1.0).sqrt();
        let mut h = ((w - 1.0) / 2.0).round() as i64;
        if h < 1 {
            h = 1;
        }
        // Second-difference lag of the coarse Ricker approximation.
        let lag = (s.round() as i64).max(1);
        // Each box pass is followed by >> shift so three passes of 16-bit data
        // stay well inside i32 (w³·65535 would overflow for w > 32).
        let shift = (63 - ((2 * h + 1) as u64).leading_zeros()) as i64; // floor(log2 w)
        // Coarse gain (response to unit Gaussian σ=s) and noise gain, both
        // computed from the exact effective integer pipeline as f64.
        let mut kernel = vec![1.0f64];
        for _ in 0..3 {
            let mut nk = vec![0.0; kernel.len() + 2 * h as usize];
            for (i, v) in kernel.iter().enumerate() {
                for b in 0..(2 * h + 1) as usize {
                    nk[i + b] += v;
                }
            }
            kernel = nk;
        }
        let c = kernel.len() as i64 / 2;
        let mut resp = vec![0.0f64; kernel.len() + 2 * lag as usize];
        for (i, v) in kernel.iter().enumerate() {
            let i = i + lag as usize;
            resp[i] += 2.0 * v;
            resp[i - lag as usize] -= v;
            resp[i + lag as usize] -= v;
        }
        let rc = c + lag;
        let scale_down = 1.0 / 2f64.powi(3 * shift as i32);
        let cgain: f64 = resp
            .iter()
            .enumerate()
            .map(|(i, v)| v * (-((i as i64 - rc) as f64).powi(2) / (2.0 * s * s)).exp())
            .sum::<f64>()
            * scale_down;
        let cnoise: f64 = resp.iter().map(|v| v * v).sum::<f64>().sqrt() * scale_down;
        writeln!(
            rungs,
            "    Rung {{ scale_q16: Px({}), half_len: {l}, ricker_off: {r_off}, deriv_off: {d_off}, deriv_abs: {deriv_abs}, ricker_abs: {ricker_abs}, norm: {norm}, amp_inv: {amp_inv}, noise_q8: Q56_8({noise_q8}), box_half: {h}, box_shift: {shift}, lag: {lag}, coarse_gain_q8: Q56_8({}), coarse_noise_q8: Q56_8({}) }},",
            (s * 65536.0).round() as i64,
            (cgain * 256.0).round() as i64,
            (cnoise * 256.0).round() as i64,
        )
        .unwrap();
    }
    writeln!(src, "pub static RUNGS: [Rung; LADDER_LEN] = [\n{rungs}];").unwrap();
    write_array(&mut src, "RICKER", "i16", &ricker_all);
    write_array(&mut src, "DERIV", "i16", &deriv_all);
    // Each pair rung's words as its own slice (one bounds check to find them).
    let mut names = String::new();
    for (k, w) in deriv_words.iter().enumerate() {
        write_array(&mut src, &format!("DERIV_PAIRS_{k}"), "u32", w);
        write!(names, "&DERIV_PAIRS_{k}, ").unwrap();
    }
    writeln!(src, "pub static DERIV_PAIRS_OF: [&[u32]; PAIR_RUNGS + 1] = [{names}];").unwrap();
    // The same as `kernels::DerivPairs` (its words, words per phase, half
    // length), and each rung's `kernels::Deriv` (its run of `DERIV`, cut at
    // compile time by `split_at`): a stripe finds its fit rung's kernels by
    // one index, not by slicing and dividing.
    let mut pairs = String::new();
    for (k, w) in deriv_words.iter().enumerate() {
        let l = half_len(scale(k));
        write!(
            pairs,
            "DerivPairs {{ words: &DERIV_PAIRS_{k}, per_phase: {}, half_len: {l} }}, ",
            w.len() / (PHASES - 1)
        )
        .unwrap();
    }
    writeln!(src, "pub static DERIV_PAIRS_TABLE: [DerivPairs; PAIR_RUNGS + 1] = [{pairs}];").unwrap();
    let mut derivs = String::new();
    let mut off = 0;
    for k in 0..LADDER_LEN {
        let l = half_len(scale(k));
        let n = l * PHASES + 1;
        write!(derivs, "Deriv {{ taps: DERIV.split_at({off}).1.split_at({n}).0, half_len: {l} }}, ").unwrap();
        off += n;
    }
    assert_eq!(off, deriv_all.len(), "every rung's taps in DERIV, in order");
    writeln!(src, "pub static DERIVS: [Deriv; LADDER_LEN] = [{derivs}];").unwrap();
    // And each rung's words as its own slice (one bounds check to find them).
    let mut names = String::new();
    for (k, w) in ricker_words.iter().enumerate() {
        write_array(&mut src, &format!("RICKER_PAIRS_{k}"), "u32", w);
        write!(names, "&RICKER_PAIRS_{k}, ").unwrap();
    }
    writeln!(src, "pub static RICKER_PAIRS_OF: [&[u32]; LADDER_LEN] = [{names}];").unwrap();

    // The paper's kernels, integer scales 1..=PAPER_MAX_SCALE.
    let mut paper_all: Vec<i64> = Vec::new();
    let mut paper_off = Vec::new();
    for s in 1..=PAPER_MAX_SCALE {
        let s = s as f64;
        let l = paper_half_len(s);
        let half: Vec<f64> = (0..=l).map(|m| PAPER_ONE * ricker(m as f64 / s) / s.sqrt()).collect();
        paper_off.push((paper_all.len(), l));
        paper_all.extend_from_slice(&zero_sum_even(&half));
    }
    write_array(&mut src, "PAPER", "i16", &paper_all);
    write!(src, "pub static PAPER_RUNGS: [(usize, usize); {PAPER_MAX_SCALE}] = [").unwrap();
    for (o, l) in &paper_off {
        write!(src, "({o}, {l}),").unwrap();
    }
    writeln!(src, "];").unwrap();

    let log2: Vec<i64> = (0..=256).map(|i| ((1.0 + i as f64 / 256.0).log2() * 65536.0).round() as i64).collect();
    write_array(&mut src, "LOG2_Q16", "u32", &log2);

    fs::write(out, src).unwrap();
}

fn write_array(src: &mut String, name: &str, ty: &str, vals: &[i64]) {
    write!(src, "pub static {name}: [{ty}; {}] = [", vals.len()).unwrap();
    for (i, v) in vals.iter().enumerate() {
        if i % 16 == 0 {
            src.push('\n');
        }
        write!(src, "{v},").unwrap();
    }
    writeln!(src, "\n];").unwrap();
}
