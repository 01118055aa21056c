use cms_core::fixed::Px;
use cms_core::optics::ScaleRange;
use cms_core::peak::{Config, Detector, Method, Stripes};
use cms_tests::*;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let method = Method::from_name(args.get(1).map(|s| s.as_str()).unwrap_or("cwt")).unwrap();
    let trials = 400;
    for &sigma in &[1.5f64, 2.5, 4.0, 10.0] {
        for &snr in &[20.0f64, 30.0, 40.0] {
            let smin = (sigma / 2.0).max(1.0);
            let mut cfg = Config::new(12, ScaleRange::new(Px::from_f64(smin), Px::from_f64(1.5 * sigma)).unwrap());
            cfg.method = method;
            cfg.max_stripes = 1;
            let mut det = Detector::<480>::new(cfg).unwrap();
            let mut rng = Rng::new(42);
            let (mut se, mut sb, mut miss, mut maxe) = (0.0, 0.0, 0, 0.0f64);
            let a = 3000.0;
            let mut cr = 0.0;
            for _ in 0..trials {
                let x0 = 200.0 + rng.uniform();
                let sig = clean_row(480, 0.0, &[Gauss { x0, sigma, amplitude: a }]);
                let noise = awgn_sigma(&sig, snr);
                let row: Vec<f64> = sig.iter().map(|v| v + 300.0).collect();
                let q = quantise(&row, noise, 12, &mut rng);
                cr = crlb(sigma, a, (noise * noise + 1.0 / 12.0).sqrt());
                let mut out: Stripes<4> = Stripes::new();
                det.detect(&q, &mut out).unwrap();
                if out.len() != 1 {
                    miss += 1;
                    continue;
                }
                let e = out[0].position.to_f64() - x0;
                se += e * e;
                sb += e;
                maxe = maxe.max(e.abs());
            }
            let m = (trials - miss) as f64;
            let rms = (se / m).sqrt();
            println!(
                "{} sigma {sigma:4} snr {snr}: rms {rms:.5} crlb {cr:.5} ratio {:.3} bias {:.5} max {maxe:.4} miss {miss}",
                method.name(),
                rms / cr,
                sb / m
            );
        }
    }
}
