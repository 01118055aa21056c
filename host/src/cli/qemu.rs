//! The emulated head's options: `listen qemu`'s `--qemu-…` and `bench qemu`'s.

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use cms_host::device::qemu::{BenchOptions, Machine, QemuPort};

/// `--machine`, `--qemu-machine`: the emulated board.
#[derive(ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MachineArg {
    /// mps2-an386: Cortex-M4F.
    #[default]
    An386,
    /// mps2-an500: Cortex-M7.
    An500,
}

impl From<MachineArg> for Machine {
    fn from(m: MachineArg) -> Machine {
        match m {
            MachineArg::An386 => Machine::An386,
            MachineArg::An500 => Machine::An500,
        }
    }
}

/// The emulated head's options inside `cms-host listen` (flatten into the
/// listener's arguments).
#[derive(Args, Clone, Debug, Default)]
pub struct QemuPortArgs {
    /// With PORT `qemu`: the emulated board.
    #[arg(long = "qemu-machine", value_enum)]
    pub qemu_machine: Option<MachineArg>,
    /// With PORT `qemu`: the head's image [default: $CMS_QEMU_IMAGE, cms-qemu-head beside cms-host, or built in the checkout run from].
    #[arg(long = "qemu-image", value_name = "FILE")]
    pub qemu_image: Option<PathBuf>,
}

impl QemuPortArgs {
    /// The library's options.
    pub fn options(&self) -> QemuPort {
        QemuPort { qemu_machine: self.qemu_machine.map(Into::into), qemu_image: self.qemu_image.clone() }
    }
}

/// Options of `cms-host bench qemu`.
#[derive(Args, Debug, Clone, Default)]
pub struct BenchQemuArgs {
    /// The emulated board.
    #[arg(long, value_enum, default_value_t = MachineArg::An386)]
    pub machine: MachineArg,
    /// The benchmark's image [default: $CMS_QEMU_BENCH_IMAGE, cms-qemu-bench beside cms-host, or built in the checkout run from].
    #[arg(long, value_name = "FILE")]
    pub image: Option<PathBuf>,
    /// Clock of the implied rows per second, MHz (1 instruction per cycle).
    #[arg(long, value_name = "MHZ", default_value_t = 480, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub clock_mhz: u32,
}

impl BenchQemuArgs {
    /// The library's options.
    pub fn options(&self) -> BenchOptions {
        BenchOptions { machine: self.machine.into(), image: self.image.clone(), clock_mhz: self.clock_mhz }
    }
}
