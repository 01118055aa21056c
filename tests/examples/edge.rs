use cms_core::fixed::Px;
use cms_core::optics::ScaleRange;
use cms_core::peak::{Config, Detector, Select, Stripes};
use cms_tests::*;
fn main() {
    let mut rng = Rng::new(4);
    let row = quantise(&clean_row(752, 200.0, &[Gauss { x0: 3.3, sigma: 2.5, amplitude: 2000.0 }]), 3.0, 12, &mut rng);
    let mut cfg = Config::new(12, ScaleRange::new(Px::from_f64(1.5), Px::from_f64(4.0)).unwrap());
    cfg.select = Select::All;
    let mut det = Detector::<752>::new(cfg).unwrap();
    let mut out: Stripes<8> = Stripes::new();
    det.detect(&row, &mut out).unwrap();
    println!("{:?} {:?}\n{:?}", out, det.stats(), &row[..16]);
}
