//! `cms-host view`: a recording in the browser (the library's
//! [`cms_host::serve::viewer`]); its arguments and what it prints.

use std::io::Write as _;
use std::net::SocketAddr;

use clap::Args;
use cms_host::Error;
use cms_host::serve::viewer::{View, Viewer};

use super::analyze::AnalysisArgs;
use super::progress::Bar;

/// Arguments of `cms-host view`.
#[derive(Args, Debug, Clone)]
pub struct ViewArgs {
    #[command(flatten)]
    pub analysis: AnalysisArgs,
    /// Where to serve the page: loopback port 8130 unless an address is
    /// given (`0.0.0.0:8130` opens it to the network; port 0 picks a free one).
    #[arg(long, value_name = "ADDR", default_value_t = cms_host::serve::DEFAULT_ADDR)]
    pub serve: SocketAddr,
}

/// Analyses the inputs as `cms-host analyze` does, then serves the viewer
/// until interrupted.
pub fn run(args: &ViewArgs) -> anyhow::Result<()> {
    let view = View::open(&args.analysis.request(), &args.analysis.options(), &Bar::stderr())?;
    let viewer = Viewer::start(view, args.serve).map_err(Error::from)?;
    let mut err = std::io::stderr().lock();
    writeln!(err, "view: on http://{}/ (Ctrl-C to stop)", viewer.addr()).map_err(Error::Output)?;
    drop(err);
    viewer.wait();
    Ok(())
}
