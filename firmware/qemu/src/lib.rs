//! `cms-qemu`: the CMS sensor head on an emulated Cortex-M.
//!
//! QEMU's `mps2-an386` (Cortex-M4F) and `mps2-an500` (Cortex-M7) boards run
//! the head's own code — `cms_core::pipeline::Head`, the detector, the wire
//! protocol — on the thumbv7em instruction set, with the board's CMSDK UART
//! as the link (QEMU puts it on a pseudo-terminal) and a synthetic scene
//! (`cms_core::synthetic`) as the camera. Two programs:
//!
//! * `cms-qemu-head` (`src/bin/head.rs`): the emulated head; `cms-host
//!   listen qemu` starts it and talks to it exactly as to a device.
//! * `cms-qemu-bench` (`src/bin/bench.rs`): instructions per row of every
//!   detection method under `-icount shift=0` (`cms-host bench qemu`).
//!
//! The board support is what QEMU models, kept small:
//!
//! * [`uart`] — the CMSDK APB UART: polled transmit, interrupt-driven
//!   receive into a ring buffer.
//! * [`clock`] — SysTick as a 1 kHz tick plus its sub-tick count: the
//!   `embassy-time` driver, and a 25 MHz timestamp for the benchmark.
//! * [`executor`] — embassy's raw executor, sleeping with WFI.
//! * [`vectors`] — the interrupt vector table.
//! * [`board`] — which board this is, the lasers' stand-in, the panic handler.
//!
//! `unsafe` is confined to register access (volatile reads and writes at the
//! documented addresses), the vector table and the executor's pender symbol;
//! every block says why it is sound.
#![no_std]

pub mod board;
pub mod clock;
pub mod executor;
pub mod line_frame;
pub mod uart;
pub mod vectors;
