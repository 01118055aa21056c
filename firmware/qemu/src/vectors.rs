//! The device part of the vector table (cortex-m-rt's `device` feature):
//! 32 external interrupts, all on cortex-m-rt's `DefaultHandler` except
//! UART0's receive interrupt. mps2-an386/an500 wire UART0 RX to IRQ 0 and TX
//! to IRQ 1 (the transmitter is polled, so IRQ 1 stays masked); QEMU uses no
//! line above 31 on these boards.

unsafe extern "C" {
    /// cortex-m-rt's default handler (`link.x` provides it).
    fn DefaultHandler();
}

/// IRQ 0..=31, placed right after the core exceptions by cortex-m-rt's `link.x`.
#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
pub static __INTERRUPTS: [unsafe extern "C" fn(); 32] = {
    let mut v: [unsafe extern "C" fn(); 32] = [DefaultHandler; 32];
    v[crate::uart::RX_IRQ as usize] = crate::uart::uart0_rx;
    v
};
