//! The SocketCAN backend: a raw CAN socket on a Linux interface (`can0`, `vcan0`).
//!
//! Sends and receives never block; [`Bus::recv_until`] waits with `ppoll`. Error frames are
//! requested from the kernel and only update the bus state; timestamps are taken from
//! [`monotonic_now`] when a frame is read, so they share the clock of every other backend.
//!
//! On a kernel without CAN (no `AF_CAN`, no vcan module) opening fails with
//! [`SocketCanError::NoKernelCan`], whose message points to the shared-memory virtual bus
//! `vbus:NAME`.

use super::{Bus, BusCounters, BusError, BusState, Frame};
use crate::time::{Instant, monotonic_now};
use socketcan::{CanFrame, CanSocket, EmbeddedFrame, Socket, SocketOptions};
use std::io;
use std::os::fd::AsRawFd;

/// Why a SocketCAN interface could not be opened.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SocketCanError {
    /// The kernel has no CAN support: `socket(AF_CAN)` fails (EAFNOSUPPORT).
    #[error(
        "cannot open CAN interface `{iface}`: this kernel lacks CAN/vcan support \
         (socket(AF_CAN) fails with os error {errno}); use the virtual bus `vbus:NAME` instead"
    )]
    NoKernelCan {
        /// The interface asked for.
        iface: String,
        /// The errno of `socket(AF_CAN)`.
        errno: i32,
    },
    /// The kernel has CAN, but there is no interface of that name.
    #[error(
        "no CAN interface `{iface}` (os error {errno}); create it (e.g. `ip link add dev {iface} \
         type vcan`) or use the virtual bus `vbus:NAME`"
    )]
    NoSuchInterface {
        /// The interface asked for.
        iface: String,
        /// The errno of the open.
        errno: i32,
    },
    /// Any other failure while opening or configuring the socket.
    #[error("cannot open CAN interface `{iface}`: {message} (os error {errno})")]
    Os {
        /// The interface asked for.
        iface: String,
        /// The errno.
        errno: i32,
        /// The system's text for it.
        message: String,
    },
}

/// Whether this kernel can create CAN sockets: `Err(errno)` when `socket(AF_CAN)` fails.
pub fn probe_kernel_can() -> Result<(), i32> {
    // SAFETY: socket() takes plain integers and returns a new descriptor or -1.
    let fd = unsafe { libc::socket(libc::AF_CAN, libc::SOCK_RAW, libc::CAN_RAW) };
    if fd < 0 {
        return Err(io::Error::last_os_error().raw_os_error().unwrap_or(0));
    }
    // SAFETY: fd is a descriptor this function just created and owns.
    unsafe { libc::close(fd) };
    Ok(())
}

fn classify(iface: &str, err: &io::Error) -> SocketCanError {
    let errno = err.raw_os_error().unwrap_or(0);
    // A missing interface is reported before the socket is created (the index is resolved
    // first), so probe AF_CAN itself to tell "no CAN at all" from "no such interface".
    if let Err(af_errno) = probe_kernel_can() {
        return SocketCanError::NoKernelCan {
            iface: iface.to_owned(),
            errno: af_errno,
        };
    }
    if errno == libc::ENODEV {
        return SocketCanError::NoSuchInterface {
            iface: iface.to_owned(),
            errno,
        };
    }
    SocketCanError::Os {
        iface: iface.to_owned(),
        errno,
        message: err.to_string(),
    }
}

// Error-frame layout, <linux/can/error.h>.
const CAN_ERR_CRTL: u32 = 0x0000_0004;
const CAN_ERR_BUSOFF: u32 = 0x0000_0040;
const CAN_ERR_RESTARTED: u32 = 0x0000_0100;
const CAN_ERR_CRTL_RX_PASSIVE: u8 = 0x10;
const CAN_ERR_CRTL_TX_PASSIVE: u8 = 0x20;
const CAN_ERR_CRTL_ACTIVE: u8 = 0x40;

/// The bus state after an error frame with error class bits `error_bits` (the `can_id` without
/// flags) and data `data`, starting from `current`. Pure, so it can be tested without a kernel.
pub fn state_after_error_frame(current: BusState, error_bits: u32, data: &[u8]) -> BusState {
    if error_bits & CAN_ERR_BUSOFF != 0 {
        return BusState::BusOff;
    }
    if error_bits & CAN_ERR_RESTARTED != 0 {
        return BusState::ErrorActive;
    }
    if error_bits & CAN_ERR_CRTL != 0 {
        let ctrl = data.get(1).copied().unwrap_or(0);
        if ctrl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE) != 0 {
            return BusState::ErrorPassive;
        }
        if ctrl & CAN_ERR_CRTL_ACTIVE != 0 {
            return BusState::ErrorActive;
        }
    }
    current
}

/// A SocketCAN raw socket as a [`Bus`].
#[derive(Debug)]
pub struct SocketCanBus {
    socket: CanSocket,
    iface: String,
    counters: BusCounters,
    state: BusState,
}

impl SocketCanBus {
    /// Opens `iface` non-blocking, with error frames enabled.
    pub fn open(iface: &str) -> Result<SocketCanBus, SocketCanError> {
        let socket = CanSocket::open(iface).map_err(|e| classify(iface, &e))?;
        let os = |e: io::Error| SocketCanError::Os {
            iface: iface.to_owned(),
            errno: e.raw_os_error().unwrap_or(0),
            message: e.to_string(),
        };
        socket.set_nonblocking(true).map_err(os)?;
        socket.set_error_filter_accept_all().map_err(os)?;
        Ok(SocketCanBus {
            socket,
            iface: iface.to_owned(),
            counters: BusCounters::default(),
            state: BusState::ErrorActive,
        })
    }

    /// The interface name.
    pub fn interface(&self) -> &str {
        &self.iface
    }

    fn to_socketcan(frame: &Frame) -> Option<CanFrame> {
        if frame.is_remote() {
            CanFrame::new_remote(frame.id(), frame.dlc() as usize)
        } else {
            CanFrame::new(frame.id(), frame.data())
        }
    }

    /// Waits until the socket is readable or `deadline` passes; true if readable.
    fn wait_readable(&self, deadline: Instant) -> Result<bool, BusError> {
        let now = monotonic_now();
        if now >= deadline {
            return Ok(false);
        }
        let left = deadline - now;
        let ts = libc::timespec {
            tv_sec: left.as_secs() as libc::time_t,
            tv_nsec: left.subsec_nanos() as libc::c_long,
        };
        let mut pfd = libc::pollfd {
            fd: self.socket.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: pfd and ts are valid for the call; a null sigmask leaves signals unchanged.
        let rc = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
        if rc < 0 {
            let e = io::Error::last_os_error();
            if e.kind() == io::ErrorKind::Interrupted {
                return Ok(false);
            }
            return Err(BusError::Os(e.raw_os_error().unwrap_or(0)));
        }
        Ok(rc > 0)
    }
}

fn io_to_bus(e: &io::Error) -> BusError {
    match e.raw_os_error() {
        Some(libc::EAGAIN) | Some(libc::ENOBUFS) => BusError::WouldBlock,
        Some(libc::ENETDOWN) | Some(libc::ENODEV) | Some(libc::ENXIO) => BusError::Disconnected,
        Some(n) => BusError::Os(n),
        None => BusError::Os(0),
    }
}

impl Bus for SocketCanBus {
    fn send(&mut self, frame: &Frame) -> Result<(), BusError> {
        if self.state == BusState::BusOff {
            return Err(BusError::BusOff);
        }
        let f = Self::to_socketcan(frame).ok_or(BusError::Unsupported("this frame"))?;
        self.socket.write_frame(&f).map_err(|e| io_to_bus(&e))?;
        self.counters.sent += 1;
        Ok(())
    }

    fn try_recv(&mut self) -> Result<Option<Frame>, BusError> {
        loop {
            let f = match self.socket.read_frame() {
                Ok(f) => f,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Ok(None),
                Err(e) => return Err(io_to_bus(&e)),
            };
            let now = monotonic_now();
            let frame = match f {
                CanFrame::Data(d) => Frame::new_data(d.id(), d.data()),
                CanFrame::Remote(r) => Frame::new_remote(r.id(), r.dlc() as u8),
                CanFrame::Error(e) => {
                    self.state = state_after_error_frame(self.state, e.error_bits(), e.data());
                    continue;
                }
            };
            match frame {
                Ok(frame) => {
                    self.counters.received += 1;
                    return Ok(Some(frame.with_timestamp(now)));
                }
                // The kernel only hands out classic frames of at most 8 bytes; count oddities.
                Err(_) => self.counters.dropped += 1,
            }
        }
    }

    fn recv_until(&mut self, deadline: Instant) -> Result<Option<Frame>, BusError> {
        loop {
            if let Some(f) = self.try_recv()? {
                return Ok(Some(f));
            }
            if !self.wait_readable(deadline)? && monotonic_now() >= deadline {
                return Ok(None);
            }
        }
    }

    fn now(&self) -> Instant {
        monotonic_now()
    }

    fn state(&self) -> BusState {
        self.state
    }

    fn counters(&self) -> BusCounters {
        self.counters
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn open_fails_clearly_or_works() {
        match SocketCanBus::open("vcan0") {
            Ok(bus) => assert_eq!(bus.interface(), "vcan0"),
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.contains("vcan0"), "{msg}");
                assert!(msg.contains("vbus:NAME"), "{msg}");
                if probe_kernel_can().is_err() {
                    assert!(matches!(e, SocketCanError::NoKernelCan { .. }), "{e:?}");
                    assert!(msg.contains("lacks CAN/vcan support"), "{msg}");
                }
            }
        }
    }

    #[test]
    fn error_frames_drive_the_state() {
        let s = state_after_error_frame(BusState::ErrorActive, CAN_ERR_CRTL, &[0, 0x20]);
        assert_eq!(s, BusState::ErrorPassive);
        let s = state_after_error_frame(s, CAN_ERR_BUSOFF, &[0; 8]);
        assert_eq!(s, BusState::BusOff);
        let s = state_after_error_frame(s, CAN_ERR_RESTARTED, &[0; 8]);
        assert_eq!(s, BusState::ErrorActive);
        // A warning alone or a short frame changes nothing.
        assert_eq!(
            state_after_error_frame(BusState::ErrorPassive, CAN_ERR_CRTL, &[0, 0x04]),
            BusState::ErrorPassive
        );
        assert_eq!(
            state_after_error_frame(BusState::ErrorActive, CAN_ERR_CRTL, &[]),
            BusState::ErrorActive
        );
    }
}
