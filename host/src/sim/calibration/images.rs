//! `cms-host calibrate render`: calibration images from the simulated head
//! (see [`crate::sim::calibration::board`]), with the truth beside them.
//!
//! ```text
//! cms-host calibrate render [--preset reference|paper] [--poses N] [--seed S] [--noiseless] --out DIR
//! ```
//!
//! writes into `DIR` (created if missing), for each pose `k` (00, 01, …):
//!
//! * `board-KK.png`: the board, lasers off;
//! * `lasers-KK.png`: the same pose with every laser on (independent noise);
//!
//! as 8-bit grayscale PNG if the camera has ≤ 8 bits, else 16-bit holding
//! the raw codes (0..2^bits − 1); and `truth.json`:
//!
//! ```text
//! { "preset", "seed", "noiseless", "image": {width, height, bits},
//!   "intrinsics": {width, height, fx, fy, cx, cy, skew, k1, k2, p1, p2, k3},
//!   "board": {cols, rows, square_mm, margin_squares},
//!   "render": {psf_sigma_px, white, black, background, lamp_fraction, laser_gain},
//!   "lasers": [{index, normal, d_mm, sheet_sigma_mm}],          camera frame, n·X = d
//!   "poses": [{index, board_image, lasers_image, rot, t_mm}] }  X_cam = rot·X_board + t_mm
//! ```
//!
//! Laser `k` is bit `k` of the head's laser mask; in every image row the
//! lasers' stripes are left to right in index order (the order the head's
//! pipeline assigns them in).

use std::path::{Path, PathBuf};

use serde_json::json;

use crate::Error;
use crate::sim::calibration::board::{self, BoardImage, BoardRenderer, RenderOptions};
use crate::sim::scene::Preset;
use crate::sim::scene::{NoiseModel, Scene, SimConfig};

/// Most poses (two-digit file names).
pub const MAX_POSES: usize = 100;

/// What `cms-host calibrate render` renders, and where.
#[derive(Debug, Clone)]
pub struct Options {
    /// The simulated head.
    pub preset: Preset,
    /// Number of board poses, 1..=100.
    pub poses: usize,
    /// Seed of the poses, the sensor's pattern and the images' noise.
    pub seed: u64,
    /// No random noise (read, shot, banding): the images differ from the
    /// model only by quantisation and the sensor's fixed pattern.
    pub noiseless: bool,
    /// Output directory (created if missing).
    pub out: PathBuf,
}

fn preset_name(p: Preset) -> &'static str {
    match p {
        Preset::Reference => "reference",
        Preset::Paper => "paper",
    }
}

/// The simulated head's configuration for the arguments.
pub fn config(args: &Options) -> SimConfig {
    let mut cfg = match args.preset {
        Preset::Reference => SimConfig::reference(),
        Preset::Paper => SimConfig::paper(),
    };
    cfg.seed = args.seed;
    if args.noiseless {
        cfg.noise = NoiseModel { read_noise_e: 0.0, shot_noise: false, row_banding_e: 0.0, ..cfg.noise };
    }
    cfg
}

fn write_png(path: &Path, img: &BoardImage) -> Result<(), Error> {
    let (w, h) = (img.width as u32, img.height as u32);
    let mut png = std::io::Cursor::new(Vec::new());
    let r = if img.bits <= 8 {
        let data: Vec<u8> = img.pixels.iter().map(|&v| v.min(255) as u8).collect();
        image::GrayImage::from_raw(w, h, data).map(|b| b.write_to(&mut png, image::ImageFormat::Png))
    } else {
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w, h, img.pixels.clone())
            .map(|b| b.write_to(&mut png, image::ImageFormat::Png))
    };
    match r {
        Some(Ok(())) => Ok(crate::output::write_atomically(path, |w| w.write_all(png.get_ref()))?),
        Some(Err(e)) => Err(Error::Output(std::io::Error::other(format!("{}: {e}", path.display())))),
        None => Err(Error::Output(std::io::Error::other("image buffer size mismatch"))),
    }
}

/// `cms-host calibrate render`: the board images and `truth.json`.
pub fn render(args: &Options) -> Result<(), Error> {
    if !(1..=MAX_POSES).contains(&args.poses) {
        return Err(Error::Input(format!("--poses must be in 1..={MAX_POSES}, got {}", args.poses)));
    }
    if args.out.exists() && !args.out.is_dir() {
        return Err(Error::Input(format!("--out {}: exists and is not a directory", args.out.display())));
    }
    let scene = Scene::new(config(args)).map_err(|e| Error::Input(format!("simulated head: {e}")))?;
    std::fs::create_dir_all(&args.out)
        .map_err(|e| Error::Input(format!("--out {}: cannot create: {e}", args.out.display())))?;
    let opts = RenderOptions::default();
    let renderer = BoardRenderer::new(&scene, opts);
    let cfg = scene.config();
    let brd = board::board_for(cfg);
    let poses = board::calibration_poses(&scene, &brd, args.poses, args.seed);
    let all = scene.all_lasers_mask();
    let mut pose_json = Vec::new();
    for (k, pose) in poses.iter().enumerate() {
        let board_name = format!("board-{k:02}.png");
        let lasers_name = format!("lasers-{k:02}.png");
        let off = renderer.render(&brd, pose, 0, 2 * k as u64);
        write_png(&args.out.join(&board_name), &off)?;
        let on = renderer.render(&brd, pose, all, 2 * k as u64 + 1);
        write_png(&args.out.join(&lasers_name), &on)?;
        pose_json.push(json!({
            "index": k,
            "board_image": board_name,
            "lasers_image": lasers_name,
            "rot": pose.rot,
            "t_mm": pose.t_mm,
        }));
    }
    let i = &cfg.camera.intrinsics;
    let lasers: Vec<_> = scene
        .laser_planes()
        .iter()
        .zip(renderer.sheet_sigma_mm())
        .enumerate()
        .map(|(k, (p, s))| json!({ "index": k, "normal": p.normal, "d_mm": p.d_mm, "sheet_sigma_mm": s }))
        .collect();
    let truth = json!({
        "preset": preset_name(args.preset),
        "seed": args.seed,
        "noiseless": args.noiseless,
        "image": { "width": i.width_px, "height": i.height_px, "bits": cfg.camera.bits },
        "intrinsics": i,
        "board": { "cols": brd.cols, "rows": brd.rows, "square_mm": brd.square_mm, "margin_squares": opts.margin_squares },
        "render": {
            "psf_sigma_px": opts.psf_sigma_px, "white": opts.white, "black": opts.black,
            "background": opts.background, "lamp_fraction": opts.lamp_fraction, "laser_gain": opts.laser_gain,
        },
        "lasers": lasers,
        "poses": pose_json,
    });
    let text = serde_json::to_string_pretty(&truth).map_err(|e| Error::Output(std::io::Error::other(e)))?;
    let text = text + "\n";
    crate::output::write_atomically(&args.out.join("truth.json"), |w| w.write_all(text.as_bytes()))?;
    Ok(())
}
