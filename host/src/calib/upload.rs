//! See the parent module. (Being written.)

use crate::CliError;

/// Arguments.
#[derive(clap::Args, Debug, Clone)]
pub struct UploadArgs {}

/// Runs the subcommand.
pub fn run(_args: &UploadArgs) -> Result<(), CliError> {
    Err(CliError::Usage("not implemented yet".into()))
}
