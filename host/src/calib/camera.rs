//! See the parent module. (Being written.)

use crate::CliError;

/// Arguments.
#[derive(clap::Args, Debug, Clone)]
pub struct CameraArgs {}

/// Runs the subcommand.
pub fn run(_args: &CameraArgs) -> Result<(), CliError> {
    Err(CliError::Usage("not implemented yet".into()))
}
