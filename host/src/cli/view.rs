//! `cms-host view`: a recording in the browser (the library's
//! [`cms_host::serve::viewer`]); its arguments and what it prints.

use std::io::Write as _;
use std::net::SocketAddr;
use std::path::PathBuf;

use clap::Args;
use cms_host::Error;
use cms_host::serve::access::Token;
use cms_host::serve::tls::Tls;
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
    /// The viewer's secret (16 to 128 letters, digits, `-`, `_`, `.`,
    /// `~`): every request must carry it. Off loopback the viewer has one
    /// anyway (random, in the address printed); on loopback only if given.
    #[arg(long, value_name = "TOKEN", value_parser = Token::given)]
    pub serve_token: Option<Token>,
    /// Serve over HTTPS with the PEM certificate chain CERT and its
    /// private key KEY (the token then crosses the network encrypted;
    /// plain HTTP to the port is refused).
    #[arg(long, num_args = 2, value_names = ["CERT", "KEY"])]
    pub serve_tls: Option<Vec<PathBuf>>,
}

/// `--serve-tls CERT KEY` loaded and checked, before anything is served.
pub(super) fn serve_tls(files: Option<&[PathBuf]>) -> Result<Option<Tls>, Error> {
    match files {
        Some([cert, key]) => Ok(Some(Tls::load(cert, key)?)),
        _ => Ok(None),
    }
}

/// Analyses the inputs as `cms-host analyze` does (or reads a report
/// folder `analyze --report` wrote), then serves the viewer until interrupted.
pub fn run(args: &ViewArgs) -> anyhow::Result<()> {
    let tls = serve_tls(args.serve_tls.as_deref())?;
    let view = match args.analysis.inputs.as_slice() {
        [dir] if dir.is_dir() => {
            // A report is shown as it was analysed: another option would
            // be silently ignored, so it is refused.
            if let Some(flag) = args.analysis.given().first() {
                return Err(Error::Input(format!(
                    "{}: a report folder is shown as analysed; {flag} applies to recordings (view the recordings instead)",
                    dir.display()
                ))
                .into());
            }
            View::open_report(dir, &Bar::stderr())?
        }
        _ => View::open(&args.analysis.request(), &args.analysis.options(), &Bar::stderr())?,
    };
    let viewer = Viewer::start(view, args.serve, args.serve_token.clone(), tls).map_err(Error::from)?;
    let mut err = std::io::stderr().lock();
    writeln!(err, "view: on {} (Ctrl-C to stop)", viewer.url()).map_err(Error::Output)?;
    drop(err);
    viewer.wait();
    Ok(())
}
