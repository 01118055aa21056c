//! Shared helpers of the behaviour tests of `cms-core`: the synthetic rows,
//! the Cramér–Rao bound and the seeded generator come from `cms-study`
//! (re-exported here so that every test names them one way); the `f64`
//! reference of the default estimator is this crate's own.

pub use cms_study::{Gauss, Rng, awgn_sigma, clean_row, crlb, montecarlo, quantise};

pub mod reference;
