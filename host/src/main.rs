//! `cms-host`: the rail corrugation measurement system's host tools. The
//! command line is [`cli`]; everything it runs is the `cms_host` library.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
