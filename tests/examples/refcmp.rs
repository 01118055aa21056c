use cms_core::fixed::Px;
use cms_core::optics::ScaleRange;
use cms_core::peak::{Config, Detector, Stripes};
use cms_tests::*;
fn main() {
    for &sigma in &[1.5f64, 2.5, 4.0, 10.0] {
        for &snr in &[20.0f64, 30.0, 40.0] {
            let smin = (sigma / 2.0).max(1.0);
            let cfg = Config::new(12, ScaleRange::new(Px::from_f64(smin), Px::from_f64(1.5 * sigma)).unwrap());
            let mut det = Detector::<480>::new(cfg).unwrap();
            let kl = (4.0 * smin.log2() + 1e-9).floor() as usize;
            let kh = (4.0 * (1.5 * sigma).log2() - 1e-9).ceil() as usize;
            let mut rng = Rng::new(7);
            let (mut se, mut sd, mut flips) = (0.0, 0.0, 0);
            let n = 400;
            for _ in 0..n {
                let x0 = 200.0 + rng.uniform();
                let sig = clean_row(480, 0.0, &[Gauss { x0, sigma, amplitude: 3000.0 }]);
                let noise = awgn_sigma(&sig, snr);
                let row: Vec<f64> = sig.iter().map(|v| v + 300.0).collect();
                let q = quantise(&row, noise, 12, &mut rng);
                let mut out: Stripes<2> = Stripes::new();
                det.detect(&q, &mut out).unwrap();
                let y: Vec<f64> = q.iter().map(|&v| v as f64).collect();
                let (p, _w) = reference::cwt(&y, x0.round() as usize, kl, kh).unwrap();
                let d = out[0].position.to_f64() - p;
                if d.abs() > 1e-3 {
                    flips += 1;
                }
                se += (p - x0).powi(2);
                sd += d * d;
            }
            let rms = (se / n as f64).sqrt();
            let rd = (sd / n as f64).sqrt();
            println!("sigma {sigma} snr {snr}: ref rms {rms:.5} diff rms {rd:.6} ratio {:.4} big {flips}", rd / rms);
        }
    }
}
