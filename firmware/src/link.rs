//! The host link: USB full-speed CDC-ACM (`/dev/ttyACM0` on the host),
//! frames of `cms_core::protocol` out, commands in.
//!
//! Two byte pipes decouple the head loop from USB: the head encodes each
//! message straight into [`TX`] if the whole frame fits (otherwise the
//! message is dropped and counted — a half frame would only cost the host a
//! resync), and a task moves it to the IN endpoint in 64-byte packets,
//! ending a transfer that stops on a full packet with a zero-length packet
//! (without it the host never sees the end of the transfer). Received
//! packets go into [`RX`] for the head loop's frame reader. The bytes waiting
//! in [`TX`] are the link backlog reported in `Status`.

use core::sync::atomic::{AtomicU32, Ordering};

use cms_core::protocol::MAX_FRAME;

use defmt::{info, warn};
use embassy_stm32::peripherals::USB_OTG_FS;
use embassy_stm32::usb::Driver;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_usb::class::cdc_acm::{CdcAcmClass, Receiver, Sender, State};
use embassy_usb::driver::EndpointError;
use embassy_usb::{Builder, UsbDevice};
use static_cell::StaticCell;

/// The USB driver of this board.
pub type UsbDriver = Driver<'static, USB_OTG_FS>;

/// Outgoing bytes: room for the largest frame (`MAX_FRAME`, 32.5 KB, a
/// bound no real profile reaches) and 28 KB more — six full profiles of
/// three lasers under laser light (4.3–4.7 KB calibrated; 2.7 KB in
/// incoherent light) — so the head encodes the next frame while the last
/// go out, within the static RAM budget (docs/firmware.md, "Sizes"). A
/// frame that does not fit is dropped whole and counted.
pub const TX_BYTES: usize = MAX_FRAME + 28 * 1024;
/// Packet size of the bulk endpoints (full speed).
const PACKET: usize = 64;

/// Head → host bytes.
pub static TX: Pipe<CriticalSectionRawMutex, TX_BYTES> = Pipe::new();
/// Host → head bytes.
pub static RX: Pipe<CriticalSectionRawMutex, 1024> = Pipe::new();
/// Messages dropped because [`TX`] was full.
pub static DROPPED_MESSAGES: AtomicU32 = AtomicU32::new(0);

/// Queues one encoded frame, whole or not at all.
pub fn send(frame: &[u8]) -> bool {
    if TX.free_capacity() < frame.len() {
        DROPPED_MESSAGES.fetch_add(1, Ordering::Relaxed);
        return false;
    }
    let mut rest = frame;
    // The head loop is the only writer, so the space checked above stays free.
    while !rest.is_empty() {
        match TX.try_write(rest) {
            Ok(n) => rest = &rest[n..],
            Err(_) => return false,
        }
    }
    true
}

/// Bytes waiting to go out.
pub fn backlog() -> u32 {
    TX.len() as u32
}

/// Builds the CDC-ACM device; returns the device (to run) and the class halves.
pub fn build(
    driver: UsbDriver,
) -> (UsbDevice<'static, UsbDriver>, Sender<'static, UsbDriver>, Receiver<'static, UsbDriver>) {
    let mut config = embassy_usb::Config::new(0x1209, 0x0001); // pid.codes test VID/PID: replace for production
    config.manufacturer = Some("CMS");
    config.product = Some("CMS sensor head");
    config.serial_number = Some("0001");
    config.max_power = 100;
    config.max_packet_size_0 = 64;

    static CONFIG_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static BOS_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static CONTROL_BUF: StaticCell<[u8; 64]> = StaticCell::new();
    static STATE: StaticCell<State<'static>> = StaticCell::new();
    let mut builder = Builder::new(
        driver,
        config,
        CONFIG_DESC.init([0; 256]),
        BOS_DESC.init([0; 256]),
        &mut [],
        CONTROL_BUF.init([0; 64]),
    );
    let class = CdcAcmClass::new(&mut builder, STATE.init(State::new()), PACKET as u16);
    let (tx, rx) = class.split();
    (builder.build(), tx, rx)
}

/// Runs the USB device (enumeration, control requests).
#[embassy_executor::task]
pub async fn usb_device(mut device: UsbDevice<'static, UsbDriver>) -> ! {
    device.run().await
}

/// Moves [`TX`] to the host.
#[embassy_executor::task]
pub async fn usb_tx(mut tx: Sender<'static, UsbDriver>) -> ! {
    let mut buf = [0u8; PACKET];
    loop {
        tx.wait_connection().await;
        info!("usb: host connected");
        let _ = pump_tx(&mut tx, &mut buf).await;
        warn!("usb: host disconnected");
    }
}

async fn pump_tx(tx: &mut Sender<'static, UsbDriver>, buf: &mut [u8; PACKET]) -> Result<(), EndpointError> {
    loop {
        let n = TX.read(buf).await;
        tx.write_packet(&buf[..n]).await?;
        if n == PACKET && TX.is_empty() {
            tx.write_packet(&[]).await?;
        }
    }
}

/// Moves host bytes into [`RX`].
#[embassy_executor::task]
pub async fn usb_rx(mut rx: Receiver<'static, UsbDriver>) -> ! {
    let mut buf = [0u8; PACKET];
    loop {
        rx.wait_connection().await;
        while let Ok(n) = rx.read_packet(&mut buf).await {
            RX.write_all(&buf[..n]).await;
        }
    }
}
