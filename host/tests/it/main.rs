//! Behaviour tests of `cms-host`, one test binary (linking one binary, not
//! one per file, is what keeps `cargo test` fast). One module per area;
//! [`common`] holds what they share.

mod analyze;
mod calibrate_camera;
mod calibrate_cli;
mod calibrate_sim;
mod capture_cli;
mod common;
mod corrugation_sim;
mod detect;
mod durability;
mod exit_codes;
mod fit;
mod gnss;
mod hostile;
mod hostile_survey;
mod input_props;
mod listen;
mod marks;
mod measure;
mod python;
mod real_light;
mod record;
mod render;
mod robust;
mod serve;
mod simulate;
mod standards;
mod trend;
mod triangulate_sim;
mod v3_recording;
mod v4_recording;
