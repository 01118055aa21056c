//! `cms-host trend`: its arguments and output.

use std::io::Write as _;
use std::path::PathBuf;

use clap::Args;
use cms_host::Error;
use cms_host::analyze::Options;
use cms_host::analyze::reprofiling;
use cms_host::analyze::survey::Placement;
use cms_host::analyze::trend;
use cms_host::recording::survey_info::SurveyDate;

use super::analyze::EditionArg;
use super::progress::Bar;

/// Arguments of `cms-host trend`.
#[derive(Args, Debug, Clone)]
pub struct TrendArgs {
    /// Recordings of one site, one per survey (each analysed as `cms-host analyze` analyses one recording).
    #[arg(value_name = "RECORDING", required = true, num_args = 1..)]
    pub inputs: Vec<PathBuf>,
    /// Where each survey lies, one per recording in order (as `analyze --chainage`;
    /// default its survey block's start).
    #[arg(long, value_name = "KM+M[:up|:down]", value_parser = placement)]
    pub chainage: Vec<Placement>,
    /// Each survey's date, one per recording in order (default its survey block's `date`).
    #[arg(long, value_name = "YYYY-MM-DD", value_parser = date)]
    pub date: Vec<SurveyDate>,
    /// A track register (CSV): each survey's runs with GNSS fixes placed by
    /// them, their typed starts checked against them (as `analyze --track-register`).
    #[arg(long = "track-register", value_name = "REGISTER.csv")]
    pub track_register: Option<PathBuf>,
    /// The EN 13231-3 edition whose criterion and limits are followed.
    #[arg(long, value_enum, default_value_t = EditionArg::En2006)]
    pub edition: EditionArg,
    /// Block length, m (1 to 1000): the blocks are the first survey's.
    #[arg(long = "block-m", value_name = "M", default_value_t = 50.0, value_parser = block_m)]
    pub block_m: f64,
    /// How far the check of each survey's chainage looks, m (above 0, at most 100).
    #[arg(long = "search-m", value_name = "M", default_value_t = 2.0, value_parser = search_m)]
    pub search_m: f64,
    /// Crossings later than this after the last survey are "not within", years (1 to 100).
    #[arg(long = "horizon-years", value_name = "Y", default_value_t = 10.0, value_parser = horizon)]
    pub horizon_years: f64,
    /// Print one JSON object instead of the text table.
    #[arg(long)]
    pub json: bool,
    /// Write the trend report (trend.html, trend.svg/png, trend.csv,
    /// trend_iso3095.csv, summary.txt) into DIR
    /// (created if missing; an existing trend report is replaced whole).
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
}

fn placement(s: &str) -> Result<Placement, String> {
    s.parse().map_err(|e: cms_host::recording::survey_info::SurveyError| e.to_string())
}

fn date(s: &str) -> Result<SurveyDate, String> {
    s.parse().map_err(|e: cms_host::recording::survey_info::SurveyError| e.to_string())
}

fn in_range(s: &str, (lo, hi): (f64, f64), open: bool, what: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && (v > lo || (!open && v == lo)) && v <= hi => Ok(v),
        _ => Err(format!("`{s}` is not {what} ({}{lo} to {hi})", if open { "above " } else { "" })),
    }
}

fn block_m(s: &str) -> Result<f64, String> {
    in_range(s, (1.0, 1000.0), false, "a block length in m")
}

fn search_m(s: &str) -> Result<f64, String> {
    in_range(s, (0.0, 100.0), true, "a search distance in m")
}

fn horizon(s: &str) -> Result<f64, String> {
    in_range(s, (1.0, 100.0), false, "a horizon in years")
}

/// Runs `cms-host trend`.
pub fn run(args: &TrendArgs) -> anyhow::Result<()> {
    if let Some(dir) = &args.report {
        if let Some(input) = args.inputs.iter().find(|i| cms_host::output::folder_holds(dir, i)) {
            return Err(Error::Input(format!(
                "--report {}: the folder holds the input {}; write the report into another folder",
                dir.display(),
                input.display()
            ))
            .into());
        }
        cms_host::output::set::check_set(dir, cms_host::report::trend::owns)
            .map_err(|e| anyhow::Error::from(Error::from(e)).context("--report"))?;
    }
    let opts = Options {
        verdict: reprofiling::Options { edition: args.edition.edition(), block_mm: args.block_m * 1000.0 },
        ..Options::default()
    };
    let surveys = cms_host::report::trend::survey_runs(
        &args.inputs,
        &args.chainage,
        &args.date,
        args.track_register.as_deref(),
        &opts,
        &Bar::stderr(),
    )?;
    let topts = trend::Options {
        search_mm: args.search_m * 1000.0,
        horizon_years: args.horizon_years,
        ..trend::Options::default()
    };
    let t = trend::trend(&surveys, &topts).map_err(Error::from)?;
    if let Some(dir) = &args.report {
        cms_host::report::trend::write(dir, &t)?;
    }
    let mut out = std::io::stdout().lock();
    if args.json {
        writeln!(out, "{}", cms_host::report::trend::json(&t)).map_err(Error::Output)?;
    } else {
        out.write_all(cms_host::report::trend::summary(&t).as_bytes()).map_err(Error::Output)?;
        if let Some(dir) = &args.report {
            writeln!(out, "\nreport: {}", dir.join("trend.html").display()).map_err(Error::Output)?;
        }
    }
    out.flush().map_err(Error::Output)?;
    Ok(())
}
