//! EtherCAT frames on a Linux network interface: an `AF_PACKET` socket bound to EtherType
//! 88A4h on one interface (digest §1: a socket bound to the protocol does not see its own
//! outgoing frames). Raw sockets need `CAP_NET_RAW`; inside a network namespace made with
//! `unshare -rn` a user has it, so tests run there on veth pairs, never on a real interface.

use super::frame::{ETHERTYPE, MAX_FRAME_LEN};
use std::ffi::CString;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::time::Duration;

/// Why an interface could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum RawError {
    /// No interface of that name.
    #[error(
        "no network interface '{0}' (list them with `ip link`; tests make a veth pair in a \
         network namespace)"
    )]
    NoInterface(String),
    /// Raw sockets are refused.
    #[error(
        "raw sockets on '{iface}' are refused ({source}): EtherCAT needs CAP_NET_RAW; run as \
         root, or inside a network namespace (`unshare -rn`) on a veth pair"
    )]
    Refused {
        /// The interface.
        iface: String,
        /// The operating system's error.
        source: io::Error,
    },
    /// Another failure of socket(2) or bind(2).
    #[error("EtherCAT socket on '{iface}': {source}")]
    Io {
        /// The interface.
        iface: String,
        /// The operating system's error.
        source: io::Error,
    },
}

/// A raw socket for EtherCAT frames on one interface.
#[derive(Debug)]
pub struct RawSocket {
    fd: OwnedFd,
    iface: String,
}

impl RawSocket {
    /// Opens `iface` for EtherType 88A4h.
    pub fn open(iface: &str) -> Result<RawSocket, RawError> {
        let name = CString::new(iface).map_err(|_| RawError::NoInterface(iface.to_owned()))?;
        // SAFETY: `name` is a valid NUL-terminated string.
        let index = unsafe { libc::if_nametoindex(name.as_ptr()) };
        if index == 0 {
            return Err(RawError::NoInterface(iface.to_owned()));
        }
        let proto = ETHERTYPE.to_be();
        // SAFETY: plain socket(2) call; the result is checked.
        let fd = unsafe {
            libc::socket(
                libc::AF_PACKET,
                libc::SOCK_RAW | libc::SOCK_CLOEXEC,
                i32::from(proto),
            )
        };
        if fd < 0 {
            let e = io::Error::last_os_error();
            return Err(match e.raw_os_error() {
                Some(libc::EPERM) | Some(libc::EACCES) => RawError::Refused {
                    iface: iface.to_owned(),
                    source: e,
                },
                _ => RawError::Io {
                    iface: iface.to_owned(),
                    source: e,
                },
            });
        }
        // SAFETY: `fd` is a fresh descriptor this function owns.
        let fd = unsafe { OwnedFd::from_raw_fd(fd) };
        // SAFETY: zeroed sockaddr_ll is a valid value; the fields are set below.
        let mut addr: libc::sockaddr_ll = unsafe { core::mem::zeroed() };
        addr.sll_family = libc::AF_PACKET as u16;
        addr.sll_protocol = proto;
        addr.sll_ifindex = index as i32;
        // SAFETY: `addr` is a sockaddr_ll of the size passed.
        let r = unsafe {
            libc::bind(
                fd.as_raw_fd(),
                (&addr as *const libc::sockaddr_ll).cast(),
                core::mem::size_of::<libc::sockaddr_ll>() as u32,
            )
        };
        if r < 0 {
            return Err(RawError::Io {
                iface: iface.to_owned(),
                source: io::Error::last_os_error(),
            });
        }
        Ok(RawSocket {
            fd,
            iface: iface.to_owned(),
        })
    }

    /// The interface's name.
    pub fn interface(&self) -> &str {
        &self.iface
    }

    /// Waits up to `timeout` for a frame; returns its length, or `None` if none came.
    pub fn recv(
        &self,
        buf: &mut [u8; MAX_FRAME_LEN],
        timeout: Duration,
    ) -> io::Result<Option<usize>> {
        let mut pfd = libc::pollfd {
            fd: self.fd.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        let ts = libc::timespec {
            tv_sec: timeout.as_secs().min(i64::MAX as u64) as libc::time_t,
            tv_nsec: libc::c_long::from(timeout.subsec_nanos() as i32),
        };
        // SAFETY: one valid pollfd, a valid timespec, no signal mask.
        let r = unsafe { libc::ppoll(&mut pfd, 1, &ts, core::ptr::null()) };
        if r < 0 {
            let e = io::Error::last_os_error();
            return if e.kind() == io::ErrorKind::Interrupted {
                Ok(None)
            } else {
                Err(e)
            };
        }
        if r == 0 {
            return Ok(None);
        }
        // SAFETY: `buf` is writable for its length.
        let n = unsafe {
            libc::recv(
                self.fd.as_raw_fd(),
                buf.as_mut_ptr().cast(),
                buf.len(),
                libc::MSG_DONTWAIT,
            )
        };
        if n < 0 {
            let e = io::Error::last_os_error();
            return match e.kind() {
                io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted => Ok(None),
                _ => Err(e),
            };
        }
        Ok(Some(n as usize))
    }

    /// Sends one frame (Ethernet header first).
    pub fn send(&self, frame: &[u8]) -> io::Result<()> {
        // SAFETY: `frame` is readable for its length.
        let n = unsafe { libc::send(self.fd.as_raw_fd(), frame.as_ptr().cast(), frame.len(), 0) };
        if n < 0 {
            return Err(io::Error::last_os_error());
        }
        if n as usize != frame.len() {
            return Err(io::Error::other(format!(
                "sent {n} of {} bytes on {}",
                frame.len(),
                self.iface
            )));
        }
        Ok(())
    }
}
